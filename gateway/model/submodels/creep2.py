"""``creep2``: a second, slower Kelvin element (a Prony series of two), beyond the paper.

mu2 de2/dt + E2 e2 = sigma with constant E2 = ``e2_pa`` and mu2 = ``mu2_pa_s`` (tau2 = mu2/E2,
1000 s by default); the same exact step and held-step forms as ``creep``. State:
``kv2_strain``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..physics import kelvin_held_strain, relax_series
from ..state import ModelState
from .base import FloatArray, StateChanges, StrainState


class Creep2(StrainState):
    effect: ClassVar[str] = "creep2"
    description: ClassVar[str] = "a second, slower Kelvin element (Prony series)"
    parameters: ClassVar[tuple[str, ...]] = ("e2_pa", "mu2_pa_s")
    fields: ClassVar[tuple[str, ...]] = ("kv2_strain",)
    term: ClassVar[str] = "kv2_strain"
    series_parameters: ClassVar[tuple[str, ...]] = ("area_m2", *parameters)

    def strain(self, state: ModelState) -> FloatArray | None:
        return state.kv2_strain

    def relax(self, state: ModelState, held_n: FloatArray, dt_s: ArrayLike) -> StateChanges:
        p = self.params
        target = held_n / (p.area_m2 * p.e2_pa)
        decay = np.exp(-p.e2_pa * np.asarray(dt_s) / p.mu2_pa_s)
        return {"kv2_strain": np.asarray(target + (state.kv2_strain - target) * decay)}

    def state_series(
        self, force_n: FloatArray, held_n: FloatArray, dt_s: FloatArray, state0: ModelState
    ) -> tuple[FloatArray | None, StateChanges]:
        p = self.params
        log_a = np.broadcast_to(-p.e2_pa * dt_s / p.mu2_pa_s, force_n.shape)
        kv2, end = relax_series(log_a, held_n / (p.area_m2 * p.e2_pa), state0.kv2_strain)
        return kv2, {"kv2_strain": end}

    def held_step(self, force_n: FloatArray, time_s: FloatArray) -> FloatArray | None:
        p = self.params
        return kelvin_held_strain(force_n, time_s, p.area_m2, p.e2_pa, p.mu2_pa_s)


class NoCreep2(StrainState):
    """``creep2`` switched off: ``StrainState``'s defaults, no strain and no state (a sibling
    of ``Creep2``)."""

    effect: ClassVar[str] = Creep2.effect
    active: ClassVar[bool] = False
    description: ClassVar[str] = Creep2.description
    parameters: ClassVar[tuple[str, ...]] = Creep2.parameters
    term: ClassVar[str] = Creep2.term
