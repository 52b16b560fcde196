"""``calibrate --model auto`` (the physical model and every curve x drift candidate) against
the single physical-model fit, on one emulated FSR record of 100,000 rows (sim_device's
independent FSR emulator): the ratio, and the absolute time the issue bounds (10 s)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from gateway.analysis.calibration import calibrate
from gateway.analysis.candidates import rank_candidates
from gateway.analysis.discrepancy import decimate
from gateway.analysis.fitting import FitData
from gateway.analysis.records import read_record
from sim_device.fsr_emulator import FsrEmulator, FsrParams, calibration_run, write_record

ROWS = 100_000


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
