"""Model benchmark: drift-corrected inversion against a per-sample brentq loop.

Both sides solve the same problem (the same samples, the same creep-state update); the
baseline is what a hand-rolled implementation would write: scalar model, brentq per
sample. It is timed on a subset and reported per sample, in the same run.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import brentq

from gateway.model import ModelState, SensorModel, SensorParams

CHANNELS = 64
SAMPLES_PER_CHANNEL = 15_625  # 64 x 15,625 = 1e6 samples
RATE_HZ = 10.0


def _load(n_t: int, n_ch: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n_t) / RATE_HZ
    phase = rng.uniform(0, 2 * np.pi, n_ch)
    period = rng.uniform(30, 300, n_ch)
    return 2.5 + 2.0 * np.sin(2 * np.pi * t[:, None] / period + phase)


def _brentq_track(model: SensorModel, r: np.ndarray, dt_s: float) -> np.ndarray:
    """Per-sample, per-channel brentq with the same relax/record state update."""
    p = model.params
    n_t, n_ch = r.shape
    out = np.empty_like(r)
    for ch in range(n_ch):
        one = SensorModel(model.effects, p.channel(ch))
        state = one.initial_state()
        for k in range(n_t):
            state = one.relax(state, dt_s if k else 0.0)
            target = r[k, ch]

            def gap(
                f: float, state: ModelState = state, target: float = target, one: SensorModel = one
            ) -> float:
                return float(one.resistance(np.array([f]), state)[0]) - target

            f = brentq(gap, p.force_min_n[ch], p.force_max_n[ch], xtol=1e-12, rtol=1e-12)
            out[k, ch] = f
            state = one.record(state, np.array([f]))
    return out


def _best_of(fn: object, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        best = min(best, time.perf_counter() - t0)
    return float(best)


def main() -> None:
    model = SensorModel("tunneling,contact,creep", [SensorParams()] * CHANNELS)
    t = np.arange(SAMPLES_PER_CHANNEL) / RATE_HZ
    force = _load(SAMPLES_PER_CHANNEL, CHANNELS)
    measured, _ = model.simulate(force, t)
    r = measured.total_ohm

    bulk_s = _best_of(lambda: model.track_series(r, t), repeat=3)
    inv, _ = model.track_series(r, t)
    bulk_error = float(np.abs(inv.force_n - force).max())

    sub_t, sub_ch = 200, 4
    sub = r[:sub_t, :sub_ch]
    sub_model = SensorModel(model.effects, [SensorParams()] * sub_ch)
    base_s = _best_of(lambda: _brentq_track(sub_model, sub, 1.0 / RATE_HZ), repeat=2)
    base_error = float(np.abs(_brentq_track(sub_model, sub, 1.0 / RATE_HZ) - force[:sub_t, :sub_ch]).max())
    per_sample_base = base_s / sub.size
    per_sample_bulk = bulk_s / r.size

    print(f"drift-corrected inversion, {r.size:.0e} samples ({CHANNELS} channels x {SAMPLES_PER_CHANNEL}):")
    print(
        f"  vectorized track_series : {bulk_s:8.3f} s  {1e9 * per_sample_bulk:9.1f} ns/sample"
        f"  max error {bulk_error:.1e} N"
    )
    print(
        f"  brentq loop (on {sub.size} samples): {1e6 * per_sample_base:9.1f} us/sample"
        f"  max error {base_error:.1e} N"
    )
    print(f"  ratio: {per_sample_base / per_sample_bulk:8.0f}x the brentq loop (goal >= 100x)")

    # one poll: 64 channels, one sample each, online
    state = model.initial_state()
    polls = 2000
    t0 = time.perf_counter()
    for k in range(polls):
        _, state = model.track(r[k], state, 0.1)
    poll_s = (time.perf_counter() - t0) / polls
    one_poll_base = per_sample_base * CHANNELS
    print(
        f"one 64-channel poll (track): {1e6 * poll_s:8.1f} us  (brentq loop: {1e6 * one_poll_base:8.1f} us,"
    )
    print(f"  ratio {one_poll_base / poll_s:6.0f}x; a loopback Modbus TCP round trip is ~200 us)")


if __name__ == "__main__":
    main()
