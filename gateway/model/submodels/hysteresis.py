"""``hysteresis``: loading and unloading follow different curves at the same force.

The strain is offset by -h d, h = ``hysteresis_strain``, with d in [-1, 1] the load
direction: +1 after loading, -1 after unloading. d follows the force through a narrow play
(backlash) operator, p <- clip(p, F - w, F + w) with w = 0.1 F_h, so that noise does not
wander it, and then approaches the sign of each play move exponentially in the force
travelled (a Duhem / Bouc-Wen form): d <- sign(dp) + (d - sign(dp)) exp(-|dp| / F_h),
F_h = ``hysteresis_force_n`` (N). Rate independent: time alone changes nothing. State:
``play_n`` and ``direction``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..physics import play_series, relax_series
from ..state import ModelState
from .base import FloatArray, StateChanges, StrainState

#: Dead band of the play operator, as a fraction of ``hysteresis_force_n``.
HYSTERESIS_DEAD_BAND = 0.1


class Hysteresis(StrainState):
    effect: ClassVar[str] = "hysteresis"
    description: ClassVar[str] = "loading and unloading follow different curves at the same force"
    parameters: ClassVar[tuple[str, ...]] = ("hysteresis_strain", "hysteresis_force_n")
    fields: ClassVar[tuple[str, ...]] = ("play_n", "direction")
    term: ClassVar[str] = "hysteresis_strain"
    series_parameters: ClassVar[tuple[str, ...]] = ("hysteresis_force_n",)

    def strain(self, state: ModelState) -> FloatArray | None:
        return np.asarray(-self.params.hysteresis_strain * state.direction)

    def record(self, state: ModelState, force_n: FloatArray) -> StateChanges:
        f_h = self.params.hysteresis_force_n
        w = HYSTERESIS_DEAD_BAND * f_h
        new_play = np.clip(state.play_n, force_n - w, force_n + w)
        move = new_play - state.play_n
        a = np.exp(-np.abs(move) / f_h)
        direction = np.sign(move) * (1.0 - a) + state.direction * a
        return {"play_n": np.asarray(new_play), "direction": np.asarray(direction)}

    def state_series(
        self, force_n: FloatArray, held_n: FloatArray, dt_s: FloatArray, state0: ModelState
    ) -> tuple[FloatArray | None, StateChanges]:
        """The direction before each sample (it depends on F_h, not on h)."""
        f_h = self.params.hysteresis_force_n
        play = play_series(force_n, HYSTERESIS_DEAD_BAND * f_h, state0.play_n)  # after recording F[k]
        move = np.diff(np.vstack([state0.play_n[None, :], play]), axis=0)
        after, _ = relax_series(-np.abs(move) / f_h, np.sign(move), state0.direction)
        before = np.vstack([state0.direction[None, :], after[:-1]])
        return before, {"play_n": play[-1], "direction": after[-1]}

    def path_strain(self, path: FloatArray) -> FloatArray:
        return np.asarray(-self.params.hysteresis_strain * path)

    def held_step(self, force_n: FloatArray, time_s: FloatArray) -> FloatArray | None:
        p = self.params
        # recorded from rest: the play moves by max(0, F - w)
        travel = np.maximum(force_n - HYSTERESIS_DEAD_BAND * p.hysteresis_force_n, 0.0)
        direction = np.where(time_s > 0.0, -np.expm1(-travel / p.hysteresis_force_n), 0.0)
        return np.asarray(-p.hysteresis_strain * direction)


class NoHysteresis(StrainState):
    """``hysteresis`` switched off: ``StrainState``'s defaults, no strain and no state (a sibling
    of ``Hysteresis``)."""

    effect: ClassVar[str] = Hysteresis.effect
    active: ClassVar[bool] = False
    description: ClassVar[str] = Hysteresis.description
    parameters: ClassVar[tuple[str, ...]] = Hysteresis.parameters
    term: ClassVar[str] = Hysteresis.term
