"""``tunneling``: the polymer's resistance from inter-particle tunneling (eq. 2-9), always on.

R_pol = T R0 (1 - eps) exp(-gamma s0 eps) with gamma (eq. 4) from the barrier height, s0
(eq. 8) from the particle diameter and volume fraction, and the instantaneous strain
eps0 = F / (A E0(F)), E0(F) = E0 + E0' F (eq. 15's first term, eq. 19's form). T is the
temperature factor (1 without the ``temperature`` effect); other strains add to eps.
"""

from __future__ import annotations

from functools import lru_cache
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..params import ChannelParams
from ..physics import interparticle_separation_m, tunneling_decay_per_m
from .base import FloatArray, Submodel


class Tunneling(Submodel):
    """The baseline every model has; it has no null variant."""

    effect: ClassVar[str] = "tunneling"
    description: ClassVar[str] = "polymer resistance from inter-particle tunneling (eq. 2-9), always on"
    parameters: ClassVar[tuple[str, ...]] = ("r0_ohm", "e0_pa", "e0_slope_pa_per_n")

    def __init__(self, params: ChannelParams) -> None:
        super().__init__(params)
        self.gamma_s0: FloatArray = _gamma_s0(
            tuple(params.barrier_height_ev.tolist()),
            tuple(params.particle_diameter_m.tolist()),
            tuple(params.volume_fraction.tolist()),
        ).copy()
        #: A E0 and A E0' (N): the instantaneous strain is F / (a_e0 + a_e0_slope F)
        self.a_e0: FloatArray = params.area_m2 * params.e0_pa
        self.a_e0_slope: FloatArray = params.area_m2 * params.e0_slope_pa_per_n

    def elastic_strain(self, force_n: ArrayLike) -> FloatArray:
        """F / (A E0(F)) for F >= 0 (negative forces count as 0)."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        return np.asarray(f / (self.a_e0 + self.a_e0_slope * f))


@lru_cache(maxsize=16)
def _gamma_s0(
    barrier_height_ev: tuple[float, ...],
    particle_diameter_m: tuple[float, ...],
    volume_fraction: tuple[float, ...],
) -> FloatArray:
    """gamma s0 per channel (eq. 4 and 8), kept for the last few parameter values: a fit builds
    a model for every residual, and these three are never fitted."""
    return tunneling_decay_per_m(np.array(barrier_height_ev)) * interparticle_separation_m(
        np.array(particle_diameter_m), np.array(volume_fraction)
    )
