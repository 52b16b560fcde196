"""The paper's equations as vectorized numpy functions (SI units throughout).

Arrays broadcast over channels on the last axis: a parameter array of shape (N,) pairs with
a force array of shape (N,) or (T, N). The submodels (``submodels/``) and the resistance
evaluator are built from these.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import constants

FloatArray = NDArray[np.float64]

#: exp(-36) ~ 2e-16: a smaller decay factor is zero in double precision.
MIN_LOG_DECAY = -36.0
#: Most e-folds of decay one block of ``relax_series`` spans: exp(600) ~ 4e260 keeps its
#: scaled sums finite for targets up to ~1e47.
_BLOCK_LOG_DECAY = 600.0
_BLOCK_ROWS = 65536  # bounds the rounding of a block's running sums (to ~1e-14 of x, measured)


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

    The Kelvin update of ``kelvin_step`` over a series, a = exp(log_a) with log a clamped at
    ``MIN_LOG_DECAY``; ``log_a`` and ``target`` broadcast to (T, ...), ``x0`` to its trailing
    shape. Returns (x, x[T-1]).

    In scaled form x[k] = D[k] (x0 + sum_j<=k (1 - a[j]) target[j] / D[j]), D the running
    product of the decays, which a double holds while the decay spans at most
    ``_BLOCK_LOG_DECAY`` e-folds: one pass when the whole series does. Otherwise still one
    pass, whatever the time constant: the rows are cut into equal blocks that span no more than
    that in any channel, every block is solved from a zero start at once, and the blocks' end
    states follow from a doubling scan of their maps x -> A x + B (``_compose_affine``),
    which only multiplies by decays and adds.
    """
    log_a = np.maximum(log_a, MIN_LOG_DECAY, dtype=np.float64)
    minus_b = np.multiply(target, np.expm1(log_a))  # -(1 - a) target, broadcast to (T, ...)
    n_t = minus_b.shape[0]
    x0 = np.asarray(x0, dtype=np.float64)
    if n_t == 0:
        return minus_b, x0
    cum = np.cumsum(log_a, axis=0)
    if n_t <= _BLOCK_ROWS and cum.min() >= -_BLOCK_LOG_DECAY and cum.max() <= _BLOCK_LOG_DECAY:
        decay = np.exp(cum, out=cum)  # one block: the whole series
        x = np.cumsum(np.divide(minus_b, decay, out=minus_b), axis=0, out=minus_b)
        np.subtract(x0, x, out=x)
        np.multiply(x, decay, out=x)
        return x, np.asarray(x[-1])
    low, high = float(log_a.min()), float(log_a.max())
    peak = max(-low, high)
    if math.isnan(low + high):  # a NaN spoils its own channel only: size the blocks on the rest
        peak = float(np.fmax.reduce(np.abs(log_a), axis=None))
    rows = min(_BLOCK_ROWS, n_t)
    if peak > 0.0:
        rows = max(1, int(min(_BLOCK_LOG_DECAY // peak, rows)))
    rows = -(-n_t // -(-n_t // rows))  # as many blocks, of equal size: the least padding
    full = log_a if log_a.shape == minus_b.shape else np.broadcast_to(log_a, minus_b.shape)
    out = _relax_blocks(full, minus_b, x0, rows)
    return out, np.asarray(out[-1])


def _relax_blocks(log_a: FloatArray, minus_b: FloatArray, x0: FloatArray, rows: int) -> FloatArray:
    """``relax_series`` over blocks of ``rows`` rows (the last one padded with a = 1, b = 0,
    which leave x as it is), each in scaled form from a zero start, then joined."""
    shape = minus_b.shape
    n_t, n_ch = shape[0], math.prod(shape[1:])
    n_blocks = -(-n_t // rows)
    cum = np.zeros((n_blocks * rows, n_ch))
    cum[:n_t] = log_a.reshape(n_t, n_ch)
    x = np.zeros((n_blocks * rows, n_ch))
    x[:n_t] = minus_b.reshape(n_t, n_ch)
    cum, x = cum.reshape(n_blocks, rows, n_ch), x.reshape(n_blocks, rows, n_ch)
    np.cumsum(cum, axis=1, out=cum)
    decay = np.exp(cum, out=cum)  # since the block's start, >= exp(-_BLOCK_LOG_DECAY)
    np.divide(x, decay, out=x)
    np.cumsum(x, axis=1, out=x)
    block_decay = decay[:, -1].copy()
    block_end = np.multiply(decay[:, -1], x[:, -1])  # minus the end state from a zero start
    _compose_affine(block_decay, block_end)
    x0_ch = (x0 if x0.shape == shape[1:] else np.broadcast_to(x0, shape[1:])).reshape(n_ch)
    start = np.empty((n_blocks, 1, n_ch))
    start[0, 0] = x0_ch
    np.subtract(np.multiply(block_decay[:-1], x0_ch), block_end[:-1], out=start[1:, 0])
    np.subtract(start, x, out=x)
    np.multiply(x, decay, out=x)
    return np.asarray(x.reshape(n_blocks * rows, n_ch)[:n_t].reshape(shape))


def _compose_affine(scale: FloatArray, offset: FloatArray) -> None:
    """Inclusive prefix composition along axis 0 of the maps x -> scale[i] x + offset[i], in
    place: afterwards row i maps the state before row 0 to the state after row i. log2(rows)
    vectorized passes (Hillis-Steele); with 0 <= scale <= 1 nothing grows, so it cannot
    overflow however fast the decay."""
    shift = 1
    n = scale.shape[0]
    carried = np.empty_like(offset)
    while shift < n:
        part = np.multiply(scale[shift:], offset[:-shift], out=carried[: n - shift])
        np.add(offset[shift:], part, out=offset[shift:])
        np.multiply(scale[shift:], scale[:-shift], out=scale[shift:])
        shift *= 2


def play_series(force_n: FloatArray, radius_n: FloatArray, p0_n: FloatArray) -> FloatArray:
    """Play (backlash) operator over a series, p[k] = clip(p[k-1], F[k] - r, F[k] + r), (T, N).

    Each step is a clamp, and clamps compose into clamps:
    clip(clip(x, a1, b1), a2, b2) = clip(x, clip(a1, a2, b2), clip(b1, a2, b2)); an inclusive
    prefix scan over the clamp bounds (log2 T vectorized passes) gives every p[k] exactly.
    """
    lo = force_n - radius_n
    hi = force_n + radius_n
    n = force_n.shape[0]
    lo_new, hi_new = np.empty_like(lo), np.empty_like(hi)
    shift = 1
    while shift < n:
        _clip(lo[:-shift], lo[shift:], hi[shift:], out=lo_new[: n - shift])
        _clip(hi[:-shift], lo[shift:], hi[shift:], out=hi_new[: n - shift])
        lo[shift:], hi[shift:] = lo_new[: n - shift], hi_new[: n - shift]
        shift *= 2
    return _clip(np.asarray(p0_n, dtype=np.float64), lo, hi)


def _clip(x: FloatArray, low: FloatArray, high: FloatArray, out: FloatArray | None = None) -> FloatArray:
    """np.clip(x, low, high) of floats, min(max(x, low), high), without np.clip's Python-level
    overhead (measurable on the many short scans of a fit). On a tie (0.0 and -0.0) np.maximum
    and np.minimum keep their second argument, which is the bound, as np.clip does."""
    out = np.maximum(x, low, out=out)
    return np.asarray(np.minimum(out, high, out=out))
