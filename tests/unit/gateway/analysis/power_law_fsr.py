"""A power-law FSR record generated here with numpy (no simulator, no shared data).

The sensor: conductance G = k x^n of an apparent force x = F + z, z a Kelvin creep element
that rises towards a F with one time constant and recovers with the same one (symmetric creep,
nothing else): over an interval dt with the force F_prev held, z <- a F_prev + (z - a F_prev)
exp(-dt / tau). Readings carry log-normal noise; the unloaded sensor reads open (+inf).

The protocol (``protocol``): cycles of holds at 2-20 N joined by 4 N/s ramps, each cycle
ending at rest, the hold order changing from cycle to cycle; every sample every ``dt_s``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gateway.analysis.records import ChannelRecord, format_record, parse_record

FloatArray = NDArray[np.float64]

K_S = 2e-5  # S at 1 N^n: 50 kohm at 1 N
EXPONENT = 1.2
CREEP_FRACTION = 0.15
CREEP_TAU_S = 20.0
NOISE = 0.01
#: the holds of each cycle (N), in order; 60 s each, 30 s at rest between cycles
CYCLES = ((2.0, 8.0, 20.0, 5.0, 12.0), (12.0, 3.0, 16.0, 6.0), (5.0, 20.0, 2.0, 10.0), (8.0, 4.0, 14.0))
HOLD_S = 60.0
REST_S = 30.0
RAMP_N_PER_S = 4.0


def protocol(dt_s: float = 0.5, start_n: float = 0.0) -> tuple[FloatArray, FloatArray]:
    """Time (s) and reference force (N) of the protocol; ``start_n``: a first hold at that load
    before the first cycle (the record then starts loaded)."""
    knots: list[tuple[float, float]] = [(0.0, start_n)]

    def go(force: float, hold_s: float) -> None:
        t = knots[-1][0] + abs(force - knots[-1][1]) / RAMP_N_PER_S
        knots.extend([(t, force), (t + hold_s, force)])

    if start_n > 0.0:
        go(start_n, HOLD_S)
    for cycle in CYCLES:
        go(0.0, REST_S)
        for level in cycle:
            go(level, HOLD_S)
    go(0.0, REST_S)
    kt, kf = np.array([k[0] for k in knots]), np.array([k[1] for k in knots])
    t = np.arange(0.0, kt[-1], dt_s)
    return t, np.interp(t, kt, kf)


def apparent_force(
    t: FloatArray,
    f: FloatArray,
    fraction: float = CREEP_FRACTION,
    tau_s: float = CREEP_TAU_S,
    z0: float = 0.0,
) -> FloatArray:
    """x = F + z, the Kelvin element z driven by the force held over each interval (from z0)."""
    z = np.empty(t.size)
    state = z0
    for k in range(t.size):
        if k:
            e = np.exp(-(t[k] - t[k - 1]) / tau_s)
            target = fraction * f[k - 1]
            state = target + (state - target) * e
        z[k] = state
    return np.asarray(f + z)


def resistance(x: FloatArray, seed: int, noise: float = NOISE) -> FloatArray:
    """R = 1 / (k x^n) with log-normal noise; open (+inf) where x is 0."""
    rng = np.random.default_rng(seed)
    with np.errstate(divide="ignore"):
        r = 1.0 / (K_S * np.power(np.maximum(x, 0.0), EXPONENT))
    return np.asarray(np.where(x > 1e-6, r * np.exp(noise * rng.standard_normal(x.size)), np.inf))


def record(
    t: FloatArray, f: FloatArray, r: FloatArray, metadata: dict[str, str] | None = None
) -> tuple[ChannelRecord, dict[str, str]]:
    """One channel read back through the strict record reader, and its metadata."""
    meta = {"sensor": "generated power-law FSR", "time": "s since the start", **(metadata or {})}
    text = format_record(meta, ["0"], t, r[:, None], f[:, None])
    rec = parse_record(text)
    return rec.channel("0"), rec.metadata


def clean_record(seed: int = 1) -> tuple[ChannelRecord, dict[str, str]]:
    """The power-law FSR with symmetric creep only, from rest."""
    t, f = protocol()
    return record(t, f, resistance(apparent_force(t, f), seed))
