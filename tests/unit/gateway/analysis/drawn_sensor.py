"""A sensor drawn around the spec's defaults, as the analysis tests' simulated records use it."""

from __future__ import annotations

import numpy as np

from sim_device import SimSensorParams


def drawn_sensor(seed: int, **fixed: float) -> SimSensorParams:
    """R0 within +-15 %, E0, E1, mu1 and rho2 within +-10 % of the spec's values (seeded);
    ``fixed`` sets further parameters (e.g. slopes, series and leakage resistances)."""
    rng = np.random.default_rng(seed)
    return SimSensorParams(
        r0_ohm=200e3 * rng.uniform(0.85, 1.15),
        e0_pa=15e6 * rng.uniform(0.9, 1.1),
        e1_pa=150e6 * rng.uniform(0.9, 1.1),
        mu1_pa_s=1.5e10 * rng.uniform(0.9, 1.1),
        rho2_ohm_m=rng.uniform(0.9, 1.1),
        **fixed,
    )
