"""``calibrate --model auto`` (the physical model and every curve x drift candidate) against
the single physical-model fit, on one emulated FSR record of 100,000 rows (sim_device's
independent FSR emulator): the ratio, and the absolute time the issue bounds (10 s).

Then a record with fast creep (time constant 0.5 s) at irregular ~0.02 s spacing, 12,000
rows, made here with numpy: on it the fits try time constants that decay 20 e-folds a row or
more (about 1 in 11 of the Kelvin series they simulate, measured), which ``bench_relax``
times against the former ``physics.relax_series`` (on a real FSR record such series took
that one most of a 3-minute calibration). Its ``calibrate --model auto`` against the single
fit on the same record, and against ``--model auto`` on its slow twin (the same record with
a 100 s time constant): the fast record should cost no more than the slow one."""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from gateway.analysis.calibration import calibrate
from gateway.analysis.candidates import rank_candidates
from gateway.analysis.discrepancy import decimate
from gateway.analysis.fitting import FitData
from gateway.analysis.records import read_record
from sim_device.fsr_emulator import FsrEmulator, FsrParams, calibration_run, write_record

ROWS = 100_000
FAST_ROWS = 12_000
FAST_TAU_S = 0.5
SLOW_TAU_S = 100.0


def creep_record(path: Path, tau_s: float, rows: int = FAST_ROWS, seed: int = 7) -> Path:
    """A synthetic FSR record: conductance G = (F^0.9 + 0.15 z) / 20 kohm (F in N), z a Kelvin
    element that follows the force with time constant ``tau_s``, 0.3 % resistance noise;
    holds at 25.5 N and 3.3 N with 1 s ramps, from a 0.1 N preload; rows every
    |N(0.02 s, 0.004 s)|, 2 % of them at the previous row's time."""
    rng = np.random.default_rng(seed)
    dt_s = np.abs(rng.normal(0.02, 0.004, rows))
    dt_s[rng.random(rows) < 0.02] = 0.0
    time_s = np.cumsum(dt_s)
    period_s = 25.0
    knots_s = np.arange(0.0, time_s[-1] + period_s, period_s / 2)
    levels_n = np.where(np.arange(knots_s.size) % 2 == 0, 25.5, 3.3)
    levels_n[0] = 0.1
    edges_s = np.repeat(knots_s, 2)[1:]
    edges_s[1::2] += 1.0
    force_n = np.interp(time_s, edges_s, np.repeat(levels_n, 2)[:-1])
    z_n = np.empty(rows)
    z = 0.1
    for k, (dt, f) in enumerate(zip(dt_s.tolist(), force_n.tolist(), strict=True)):
        z = f + (z - f) * math.exp(-dt / tau_s)
        z_n[k] = z
    resistance_ohm = 20e3 / (force_n**0.9 + 0.15 * z_n) * np.exp(rng.normal(0.0, 0.003, rows))
    lines = ["# sensor: synthetic FSR (bench/bench_calibrate.py)", "time_s,force_n,resistance_ohm"]
    lines += [f"{t:.4f},{f:.4f},{r:.2f}" for t, f, r in zip(time_s, force_n, resistance_ohm, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _time_calibrations(path: Path) -> tuple[float, float]:
    """(single physical-model fit, calibrate --model auto) seconds on one record."""
    channel = read_record(path, require_force=True).channel()
    t0 = time.perf_counter()
    calibrate(channel, objective="log_r", force_offset="none", try_hysteresis=False)
    single_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    calibrate(channel)
    return single_s, time.perf_counter() - t0


def fast_creep() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        fast = creep_record(Path(tmp) / "fast.csv", FAST_TAU_S)
        slow = creep_record(Path(tmp) / "slow.csv", SLOW_TAU_S)
        single_s, auto_s = _time_calibrations(fast)
        _, slow_auto_s = _time_calibrations(slow)
    print(
        f"fast creep (tau {FAST_TAU_S} s), {FAST_ROWS} rows at ~0.02 s: single physical-model fit "
        f"{single_s:.2f} s (baseline)"
    )
    print(
        f"  calibrate --model auto: {auto_s:.2f} s ({auto_s / single_s:.2f} x baseline; "
        f"{auto_s / slow_auto_s:.2f} x the slow twin's (tau {SLOW_TAU_S:g} s) {slow_auto_s:.2f} s)"
    )


def main() -> None:
    protocol = calibration_run()
    run = FsrEmulator(FsrParams(), seed=3).run(protocol, 0, sample_interval_s=protocol.duration_s / ROWS)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_record(Path(tmp) / "fsr.csv", [run])
        t0 = time.perf_counter()
        record = read_record(path, require_force=True)
        read_s = time.perf_counter() - t0
    channel = record.channel()
    t0 = time.perf_counter()
    single = calibrate(
        channel, metadata=record.metadata, objective="log_r", force_offset="none", try_hysteresis=False
    )
    single_s = time.perf_counter() - t0
    data = FitData.from_channel(decimate(channel))
    t0 = time.perf_counter()
    cands = rank_candidates(data)
    cand_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    auto = calibrate(channel, metadata=record.metadata)
    auto_s = time.perf_counter() - t0
    print(f"record: {run.n_samples} rows, read in {read_s:.2f} s")
    print(f"single physical-model fit (log-R, no hysteresis, no offset): {single_s:.2f} s (baseline)")
    print(
        f"the {len(cands)} curve x drift candidates alone: {cand_s:.2f} s "
        f"({cand_s / single_s:.2f} x baseline)"
    )
    print(
        f"calibrate --model auto (everything, best = {auto.best}): {auto_s:.2f} s "
        f"({auto_s / single_s:.2f} x baseline; + read {read_s:.2f} s = {auto_s + read_s:.2f} s, bound 10 s)"
    )
    print(f"single fit's best: {single.best}")
    fast_creep()
