"""The paper's equations as vectorized numpy functions (SI units throughout).

Arrays broadcast over channels on the last axis: a parameter array of shape (N,) pairs with
a force array of shape (N,) or (T, N). The submodels (``submodels/``) and the resistance
evaluator are built from these.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import constants

FloatArray = NDArray[np.float64]

#: exp(-36) ~ 2e-16: a smaller decay factor is zero in double precision.
MIN_LOG_DECAY = -36.0
_RECURRENCE_WINDOW = 65536  # bounds the rounding of the running sums


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
    """Coefficient k of both electrode contacts: 2 R_con = k / sqrt(F) (eq. 12, times 2).

    One contact is R_con = (rho1 + rho2)/4 sqrt(pi H / F), so k = (rho1 + rho2)/2 sqrt(pi H).
    """
    rho = np.asarray(rho1_ohm_m, dtype=np.float64) + np.asarray(rho2_ohm_m, dtype=np.float64)
    return np.asarray(rho / 2.0 * np.sqrt(np.pi * np.asarray(hardness_pa, dtype=np.float64)))


def linear_in_force(intercept: ArrayLike, slope: ArrayLike, force_n: ArrayLike) -> FloatArray:
    """Paper eq. 19 form of E0, E1 and mu1: value(F) = intercept + slope * F."""
    return np.asarray(np.asarray(intercept) + np.asarray(slope) * np.asarray(force_n))


def kelvin_held_strain(
    force_n: ArrayLike,
    time_s: ArrayLike,
    area_m2: ArrayLike,
    modulus_pa: ArrayLike,
    viscosity_pa_s: ArrayLike,
) -> FloatArray:
    """Eq. 15, second term: strain of one Kelvin element under a force step held from t = 0,
    F / (A E) (1 - exp(-E t / mu))."""
    e = np.asarray(modulus_pa)
    decay = np.exp(-e * np.asarray(time_s) / np.asarray(viscosity_pa_s))
    return np.asarray(np.asarray(force_n) / (np.asarray(area_m2) * e) * (1.0 - decay))


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


def relax_series(log_a: FloatArray, target: FloatArray, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Solve x[k] = target[k] + (x[k-1] - target[k]) a[k] for k = 0..T-1 from x[-1] = x0.

    The Kelvin update of ``kelvin_step`` over a series, a = exp(log_a). Returns (x, x[T-1]).
    Vectorized in chunks in which the cumulative log decay stays within the exponent range of
    a double; the sum is carried in scaled form.
    """
    n_t = log_a.shape[0]
    out = np.empty(np.broadcast_shapes(log_a.shape, target.shape))
    log_a = np.broadcast_to(np.maximum(log_a, MIN_LOG_DECAY), out.shape)
    target = np.broadcast_to(target, out.shape)
    b = target * (-np.expm1(log_a))  # x[k] = a x[k-1] + (1 - a) target
    x = np.asarray(x0, dtype=np.float64)
    start = 0
    while start < n_t:
        window = min(n_t - start, _RECURRENCE_WINDOW)
        cum = np.cumsum(log_a[start : start + window], axis=0)
        over = np.nonzero(np.max(-cum, axis=tuple(range(1, cum.ndim))) > 600.0)[0]
        chunk = max(1, int(over[0])) if over.size else window
        seg = slice(start, start + chunk)
        lc = cum[:chunk]
        scaled = np.cumsum(b[seg] * np.exp(-lc), axis=0)
        out[seg] = np.exp(lc) * (x + scaled)
        x = out[start + chunk - 1]
        start += chunk
    return out, np.asarray(x)


def play_series(force_n: FloatArray, radius_n: FloatArray, p0_n: FloatArray) -> FloatArray:
    """Play (backlash) operator over a series, p[k] = clip(p[k-1], F[k] - r, F[k] + r), (T, N).

    Each step is a clamp, and clamps compose into clamps:
    clip(clip(x, a1, b1), a2, b2) = clip(x, clip(a1, a2, b2), clip(b1, a2, b2)); an inclusive
    prefix scan over the clamp bounds (log2 T vectorized passes) gives every p[k] exactly.
    """
    lo = force_n - radius_n
    hi = force_n + radius_n
    shift = 1
    while shift < force_n.shape[0]:
        lo_new = np.clip(lo[:-shift], lo[shift:], hi[shift:])
        hi_new = np.clip(hi[:-shift], lo[shift:], hi[shift:])
        lo[shift:], hi[shift:] = lo_new, hi_new
        shift *= 2
    return np.asarray(np.clip(p0_n, lo, hi))
