"""``physics.relax_series`` (the Kelvin recurrence over a series) against its former
implementation, kept here as the baseline: series of 10,000 and 100,000 rows at irregular
~0.02 s spacing, time constants from 0.05 s to 1000 s, one channel and 16, and 0.5 ms (a
fit exploring creep faster than the sampling: ~40 e-folds a row, clamped at 36) on the
10,000-row series only (the baseline takes minutes on the longer one). Prints each case's
time ratio (old / new, both measured in this run) and the largest difference between the
two, relative to the series' scale.

The former implementation cut the series into chunks over which the decay spans at most 600
e-folds and re-ran a cumulative sum over a 65,536-row window for each chunk: O(rows x window
/ chunk), where fast creep (tens of e-folds a row) makes chunks of a few rows."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from gateway.model.physics import MIN_LOG_DECAY, FloatArray, relax_series

_OLD_WINDOW = 65536
TAUS_S = (0.0005, 0.05, 0.3, 1.0, 1000.0)
CLAMPED_MAX_ROWS = 10_000  # the time constants below 0.01 s run on series up to this long
ROWS = (10_000, 100_000)
CHANNELS = (1, 16)

Relax = Callable[[FloatArray, FloatArray, FloatArray], tuple[FloatArray, FloatArray]]


def old_relax_series(log_a: FloatArray, target: FloatArray, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``relax_series`` before issue 32 (the baseline)."""
    n_t = log_a.shape[0]
    out = np.empty(np.broadcast_shapes(log_a.shape, target.shape))
    log_a = np.broadcast_to(np.maximum(log_a, MIN_LOG_DECAY), out.shape)
    target = np.broadcast_to(target, out.shape)
    b = target * (-np.expm1(log_a))
    x = np.asarray(x0, dtype=np.float64)
    start = 0
    while start < n_t:
        window = min(n_t - start, _OLD_WINDOW)
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


def _best_s(fn: Relax, args: tuple[FloatArray, FloatArray, FloatArray], budget_s: float = 2.0) -> float:
    """Best of up to 5 calls, fewer when they take longer than ``budget_s`` together."""
    times: list[float] = []
    spent = 0.0
    while len(times) < 5 and (spent < budget_s or not times):
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
        spent += times[-1]
    return min(times)


def main() -> None:
    rng = np.random.default_rng(11)
    print("rows    ch   tau_s   new ms    old ms   old/new   max |new-old| / scale")
    for rows in ROWS:
        dt_s = np.abs(rng.normal(0.02, 0.005, rows))
        dt_s[rng.random(rows) < 0.02] = 0.0
        for channels in CHANNELS:
            target = rng.uniform(0.5, 5.0, (rows, channels))
            spread = np.linspace(1.0, 2.0, channels)  # the channels' time constants: tau_s to 2 tau_s
            for tau_s in TAUS_S:
                if tau_s < 0.01 and rows > CLAMPED_MAX_ROWS:
                    continue
                args = (-dt_s[:, None] / (tau_s * spread), target, np.zeros(channels))
                new_s = _best_s(relax_series, args)
                old_s = _best_s(old_relax_series, args)
                diff = float(np.max(np.abs(relax_series(*args)[0] - old_relax_series(*args)[0])))
                print(
                    f"{rows:6d} {channels:4d} {tau_s:7g} {1e3 * new_s:8.2f} {1e3 * old_s:9.2f} "
                    f"{old_s / new_s:8.1f}   {diff / float(np.max(np.abs(target))):.1e}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
