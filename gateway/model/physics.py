"""The paper's equations as vectorized numpy functions (SI units throughout).

Arrays broadcast over channels on the last axis: a parameter array of shape (N,) pairs with
a force array of shape (N,) or (T, N).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import constants

FloatArray = NDArray[np.float64]


def tunneling_decay_per_m(barrier_height_ev: ArrayLike) -> FloatArray:
    """Eq. 4: gamma = (4 pi / h) sqrt(2 m phi), in 1/m, for a barrier height in eV."""
    phi_j = np.asarray(barrier_height_ev, dtype=np.float64) * constants.e
    return np.asarray(4.0 * np.pi / constants.h * np.sqrt(2.0 * constants.m_e * phi_j))


def interparticle_separation_m(particle_diameter_m: ArrayLike, volume_fraction: ArrayLike) -> FloatArray:
    """Eq. 8 (Wu): s0 = D [(pi / (6 phi))^(1/3) - 1], in metres."""
    d = np.asarray(particle_diameter_m, dtype=np.float64)
    phi = np.asarray(volume_fraction, dtype=np.float64)
    return np.asarray(d * (np.cbrt(np.pi / (6.0 * phi)) - 1.0))


def polymer_resistance_ohm(r0_ohm: ArrayLike, strain: ArrayLike, gamma_s0: ArrayLike) -> FloatArray:
    """Eq. 9/16: R_pol = R0 (1 - eps) exp(-gamma s0 eps) for a compressive strain eps."""
    eps = np.asarray(strain, dtype=np.float64)
    return np.asarray(np.asarray(r0_ohm) * (1.0 - eps) * np.exp(-np.asarray(gamma_s0) * eps))


def contact_coefficient_ohm_sqrt_n(
    rho1_ohm_m: ArrayLike, rho2_ohm_m: ArrayLike, hardness_pa: ArrayLike
) -> FloatArray:
    """Coefficient k of both electrode contacts: 2 R_con = k / sqrt(F) (eq. 12, times 2)."""
    rho = np.asarray(rho1_ohm_m, dtype=np.float64) + np.asarray(rho2_ohm_m, dtype=np.float64)
    return np.asarray(rho / 2.0 * np.sqrt(np.pi * np.asarray(hardness_pa, dtype=np.float64)))


def contact_resistance_ohm(
    rho1_ohm_m: ArrayLike, rho2_ohm_m: ArrayLike, hardness_pa: ArrayLike, force_n: ArrayLike
) -> FloatArray:
    """Eq. 12 (Holm): one electrode contact, R_con = (rho1 + rho2)/4 sqrt(pi H / F).

    The contact is open at rest: F <= 0 gives +inf, never NaN.
    """
    f = np.asarray(force_n, dtype=np.float64)
    k = contact_coefficient_ohm_sqrt_n(rho1_ohm_m, rho2_ohm_m, hardness_pa) / 2.0
    with np.errstate(divide="ignore", invalid="ignore"):
        r = k / np.sqrt(np.where(f > 0.0, f, 0.0))
    return np.asarray(np.where(f > 0.0, r, np.inf))


def linear_in_force(intercept: ArrayLike, slope: ArrayLike, force_n: ArrayLike) -> FloatArray:
    """Paper eq. 19 form of E0, E1 and mu1: value(F) = intercept + slope * F."""
    return np.asarray(np.asarray(intercept) + np.asarray(slope) * np.asarray(force_n))


def step_strain(
    force_n: ArrayLike,
    time_s: ArrayLike,
    area_m2: ArrayLike,
    e0_pa: ArrayLike,
    e1_pa: ArrayLike,
    mu1_pa_s: ArrayLike,
) -> FloatArray:
    """Eq. 15: strain of the standard linear solid under a force step held from t = 0.

    eps(t) = F/(A E0) + F/(A E1) (1 - exp(-E1 t / mu1)).
    """
    f = np.asarray(force_n, dtype=np.float64)
    a = np.asarray(area_m2)
    e1 = np.asarray(e1_pa)
    decay = np.exp(-e1 * np.asarray(time_s) / np.asarray(mu1_pa_s))
    return np.asarray(f / (a * np.asarray(e0_pa)) + f / (a * e1) * (1.0 - decay))


def kelvin_step(
    strain: ArrayLike,
    stress_pa: ArrayLike,
    modulus_pa: ArrayLike,
    viscosity_pa_s: ArrayLike,
    dt_s: ArrayLike,
) -> FloatArray:
    """Exact update of one Kelvin element under constant stress over dt (eq. 14 state form).

    mu de/dt + E e = sigma  =>  e <- sigma/E + (e - sigma/E) exp(-E dt / mu).
    """
    e = np.asarray(modulus_pa)
    target = np.asarray(stress_pa) / e
    decay = np.exp(-e * np.asarray(dt_s) / np.asarray(viscosity_pa_s))
    return np.asarray(target + (np.asarray(strain) - target) * decay)
