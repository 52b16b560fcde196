"""``creep``: standard-linear-solid creep, one Kelvin element (eq. 14-16, 19).

The Kelvin strain e obeys mu1 de/dt + E1 e = sigma, sigma = F / A, with E1(F) = E1 + E1' F
and mu1(F) = mu1 + mu1' F evaluated at the held force, as the paper does. Over a step of
constant force the update is exact: e <- sigma/E1 + (e - sigma/E1) exp(-E1 dt / mu1); a step
held from t = 0 gives F/(A E1) (1 - exp(-E1 t / mu1)) (eq. 15). State: ``kv1_strain``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..physics import kelvin_held_strain, relax_series
from ..state import ModelState
from .base import FloatArray, StateChanges, StrainState


class Creep(StrainState):
    effect: ClassVar[str] = "creep"
    description: ClassVar[str] = "standard-linear-solid creep, one Kelvin element (eq. 14-16, 19)"
    parameters: ClassVar[tuple[str, ...]] = ("e1_pa", "e1_slope_pa_per_n", "mu1_pa_s", "mu1_slope_pa_s_per_n")
    fields: ClassVar[tuple[str, ...]] = ("kv1_strain",)
    term: ClassVar[str] = "kv1_strain"
    series_parameters: ClassVar[tuple[str, ...]] = ("area_m2", *parameters)

    def _log_decay(self, held_n: FloatArray, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """log of the per-step decay factor, -E1 dt / mu1, and the target strain sigma / E1."""
        p = self.params
        e1 = p.e1_pa + p.e1_slope_pa_per_n * held_n
        mu1 = p.mu1_pa_s + p.mu1_slope_pa_s_per_n * held_n
        neg_dt = -dt_s if isinstance(dt_s, float) else -np.asarray(dt_s, dtype=np.float64)
        return np.asarray(e1 * neg_dt / mu1), np.asarray(held_n / (p.area_m2 * e1))

    def strain(self, state: ModelState) -> FloatArray | None:
        return state.kv1_strain

    def relax(self, state: ModelState, held_n: FloatArray, dt_s: ArrayLike) -> StateChanges:
        log_a, target = self._log_decay(held_n, dt_s)
        return {"kv1_strain": np.asarray(target + (state.kv1_strain - target) * np.exp(log_a))}

    def state_series(
        self, force_n: FloatArray, held_n: FloatArray, dt_s: FloatArray, state0: ModelState
    ) -> tuple[FloatArray | None, StateChanges]:
        log_a, target = self._log_decay(held_n, dt_s)
        kv1, end = relax_series(log_a, target, state0.kv1_strain)
        return kv1, {"kv1_strain": end}

    def held_step(self, force_n: FloatArray, time_s: FloatArray) -> FloatArray | None:
        p = self.params
        e1 = p.e1_pa + p.e1_slope_pa_per_n * force_n
        mu1 = p.mu1_pa_s + p.mu1_slope_pa_s_per_n * force_n
        return kelvin_held_strain(force_n, time_s, p.area_m2, e1, mu1)


class NoCreep(StrainState):
    """``creep`` switched off: ``StrainState``'s defaults, no strain and no state (a sibling
    of ``Creep``)."""

    effect: ClassVar[str] = Creep.effect
    active: ClassVar[bool] = False
    description: ClassVar[str] = Creep.description
    parameters: ClassVar[tuple[str, ...]] = Creep.parameters
    term: ClassVar[str] = Creep.term
