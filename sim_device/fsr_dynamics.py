"""The FSR emulator's mechanics: creep, flow and hysteresis along a load protocol.

The equations (sections 2 and 3 of ``sim_device.fsr_emulator``) are integrated exactly on
each linear piece of the protocol: the states at the samples do not depend on the sampling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from .fsr_params import CreepElement, FloatArray, FsrParams
from .fsr_protocol import Protocol


@dataclass(frozen=True, eq=False)
class Dynamics:
    """The mechanical state at each sample, and the protocol's number of loading cycles."""

    force_n: FloatArray  # applied force F
    effective_force_n: FloatArray  # F_eff, N
    hysteresis: FloatArray  # H, dimensionless
    slope_n_per_s: FloatArray  # dF/dt of the protocol's piece
    cycle_no: NDArray[np.int64]  # loading cycle the sample is in (0 before the first)
    cycles: int


@dataclass
class _Kelvin:
    a: float
    tau_s: float
    x: float = 0.0


def dynamics(p: FsrParams, protocol: Protocol, t: FloatArray) -> Dynamics:
    """The sensor's state at the sample times ``t`` (s, increasing, within the protocol)."""
    knot_t, knot_f = _with_threshold_crossings(*protocol.knots(), p.threshold_n)
    n = t.size
    force = np.empty(n)
    creep = np.zeros(n)
    slope = np.zeros(n)
    cycle_no = np.zeros(n, dtype=np.int64)
    widths = np.asarray(p.hysteresis_widths_n, dtype=np.float64)
    play = np.zeros(widths.size)
    plays = np.zeros((n, widths.size))
    kelvins = [_Kelvin(a, tau) for a, tau in ((p.a_fast, p.tau_fast_s), (p.a_slow, p.tau_slow_s)) if a > 0]
    flow = 0.0
    cycles = 0
    was_loaded = False
    bounds = np.searchsorted(t, knot_t, side="left")
    bounds[-1] = n
    if knot_t.size == 1:  # an empty protocol: 0 N throughout
        force[:] = 0.0
        plays[:] = play
    for j in range(knot_t.size - 1):
        t0, t1, f0, f1 = knot_t[j], knot_t[j + 1], knot_f[j], knot_f[j + 1]
        length = t1 - t0
        s = (f1 - f0) / length
        loaded = 0.5 * (f0 + f1) > p.threshold_n
        if loaded and not was_loaded:
            cycles += 1
        was_loaded = loaded
        n_sub = max(1, math.ceil(length / p.internal_step_s - 1e-9))
        h = length / n_sub
        f_nodes = f0 + s * h * np.arange(n_sub + 1)
        f_nodes[-1] = f1
        lo, hi = int(bounds[j]), int(bounds[j + 1])
        ts = t[lo:hi] - t0
        k = np.clip(np.floor(ts / h).astype(np.int64), 0, n_sub - 1)
        delta = ts - k * h
        fs = f0 + s * ts
        force[lo:hi] = fs
        slope[lo:hi] = s
        cycle_no[lo:hi] = cycles
        fk = f_nodes[k]
        # Kelvin elements: exact exponential updates on the nodes, then to the samples
        for kv in kelvins:
            c = math.exp(-h / kv.tau_s)
            u = kv.a * (f_nodes[1:] - c * f_nodes[:-1] + kv.tau_s * s * math.expm1(-h / kv.tau_s))
            x_nodes = np.empty(n_sub + 1)
            x_nodes[0] = kv.x
            x_nodes[1:] = lfilter([1.0], [1.0, -c], u, zi=[c * kv.x])[0]
            e = np.exp(-delta / kv.tau_s)
            creep[lo:hi] += e * x_nodes[k] + kv.a * (fs - e * fk + kv.tau_s * s * np.expm1(-delta / kv.tau_s))
            kv.x = float(x_nodes[-1])
        # the dashpot's flow: grows while loaded, recovers while unloaded
        if loaded:
            inc = h * (f_nodes[:-1] + f_nodes[1:]) / (2.0 * p.eta_flow_s)
            phi_nodes = flow + np.concatenate(([0.0], np.cumsum(inc)))
            creep[lo:hi] += phi_nodes[k] + delta * (fk + fs) / (2.0 * p.eta_flow_s)
        else:
            phi_nodes = flow * np.exp(-h * np.arange(n_sub + 1) / p.tau_recovery_s)
            creep[lo:hi] += phi_nodes[k] * np.exp(-delta / p.tau_recovery_s)
        flow = float(phi_nodes[-1])
        # play operators: exact on a monotone segment
        if s > 0:
            plays[lo:hi] = np.maximum(fs[:, None] - widths, play)
            play = np.maximum(f1 - widths, play)
        elif s < 0:
            plays[lo:hi] = np.minimum(fs[:, None] + widths, play)
            play = np.minimum(f1 + widths, play)
        else:
            plays[lo:hi] = play
    states = (force[:, None] - plays) / widths
    hyst = -p.hysteresis_amplitude * (states @ p.weights())
    for element in p.creep_chain:
        creep += chain_element_states(element, knot_t, knot_f, t, bounds)
    return Dynamics(force, force + creep, hyst, slope, cycle_no, cycles)


def _with_threshold_crossings(
    knot_t: FloatArray, knot_f: FloatArray, threshold_n: float
) -> tuple[FloatArray, FloatArray]:
    """The knots with a knot added wherever a ramp crosses ``threshold_n``."""
    fa, fb = knot_f[:-1], knot_f[1:]
    cross = (np.minimum(fa, fb) < threshold_n) & (np.maximum(fa, fb) > threshold_n)
    if not cross.any():
        return knot_t, knot_f
    ta, tb = knot_t[:-1][cross], knot_t[1:][cross]
    tc = ta + (threshold_n - fa[cross]) / (fb[cross] - fa[cross]) * (tb - ta)
    times = np.concatenate((knot_t, tc))
    forces = np.concatenate((knot_f, np.full(tc.size, threshold_n)))
    order = np.argsort(times, kind="stable")
    return times[order], forces[order]


def chain_element_states(
    element: CreepElement, knot_t: FloatArray, knot_f: FloatArray, t: FloatArray, bounds: NDArray[np.intp]
) -> FloatArray:
    """The state x (N) of one creep-chain element at the samples ``t``, exactly.

    On a piece of the protocol with slope s the gap ``d = a F - x`` obeys
    ``dd/dt = a s - d / tau``, so with one time constant ``d(u) = d0 e^(-u/tau) + a s tau
    (1 - e^(-u/tau))`` after u seconds on the piece. It charges (tau = tau_load) while
    ``sign(a) d > 0`` and recovers (tau = tau_recovery) while ``sign(a) d < 0``; d is monotone
    on a piece, so it changes regime at most once, where d = 0:
    ``u* = tau ln(1 - d0 / (a s tau))``, and goes on from 0 with the other time constant.
    ``bounds[j]`` is the first sample at or after knot j (the last bound is ``t.size``).
    """
    a = element.amplitude
    out = np.zeros(t.size)
    if a == 0.0:
        return out
    sign = 1.0 if a > 0 else -1.0
    x = 0.0
    for j in range(knot_t.size - 1):
        t0, f0, f1 = knot_t[j], knot_f[j], knot_f[j + 1]
        length = knot_t[j + 1] - t0
        s = (f1 - f0) / length
        d0 = a * f0 - x
        charging = sign * d0 > 0.0 or (d0 == 0.0 and s > 0.0)
        tau = element.tau_load_s if charging else element.tau_recovery_s
        other = element.tau_recovery_s if charging else element.tau_load_s
        drift = a * s * tau  # d tends to a s tau on this piece
        switch = math.inf
        if d0 != 0.0 and drift != 0.0 and (d0 > 0.0) != (drift > 0.0):
            switch = tau * math.log1p(-d0 / drift)
        lo, hi = int(bounds[j]), int(bounds[j + 1])
        u = np.append(t[lo:hi] - t0, length)
        d = _gap(u, d0, a * s, tau, other, switch)
        out[lo:hi] = a * (f0 + s * u[:-1]) - d[:-1]
        x = a * f1 - float(d[-1])
    return out


def _gap(u: FloatArray, d0: float, drive: float, tau: float, other: float, switch: float) -> FloatArray:
    """``d = a F - x`` after u seconds on a piece (``drive`` = a s, N/s): time constant
    ``tau`` up to ``switch``, then ``other`` from d = 0."""
    before = d0 * np.exp(-u / tau) - drive * tau * np.expm1(-u / tau)
    after = -drive * other * np.expm1(-np.maximum(u - switch, 0.0) / other)
    return np.asarray(np.where(u < switch, before, after))
