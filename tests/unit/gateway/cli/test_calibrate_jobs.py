"""``calibrate --jobs N``: the channels of a record (and of every record of a batch) are fitted
side by side, whole, on N processes, and the files written are the same to the byte as a serial
run's: the physical model, every curve x drift candidate and the choice among them
(``--model auto``), and the batch's summary."""

from __future__ import annotations

import multiprocessing
import os
import threading
from pathlib import Path

import pytest
from array_records import array_record
from click.testing import CliRunner

from gateway.cli import main
from gateway.cli.calibrate_pool import open_pool

pytestmark = pytest.mark.slow  # a few dozen calibrations of simulated channels

#: A short fit: the log-R objective, no zero offset; every candidate is still fitted and ranked.
SHORT = ["--model", "auto", "--objective", "log-r", "--force-offset", "none"]


#: Set before the pool forks its workers, which inherit it (a barrier cannot be pickled).
_BARRIER: list[threading.Barrier] = []


def _wait_for_each_other() -> int:
    _BARRIER[0].wait()
    return os.getpid()


def test_two_jobs_run_two_channels_at_once_in_other_processes() -> None:
    """Two tasks that each wait for the other finish only if both run at the same time: the
    pool of --jobs 2 has two worker processes (the caller only waits), not one."""
    _BARRIER[:] = [multiprocessing.get_context("fork").Barrier(2, timeout=60)]
    try:
        with open_pool(2, None) as pool:
            futures = [pool.submit(_wait_for_each_other) for _ in range(2)]
            pids = {f.result(timeout=120) for f in futures}
    finally:
        _BARRIER.clear()
    assert len(pids) == 2 and os.getpid() not in pids


def test_a_parallel_run_writes_the_serial_runs_calibration_byte_for_byte(tmp_path: Path) -> None:
    record = array_record(tmp_path / "array.csv", channels=3, seed=5)
    written = {}
    for jobs in ("1", "2"):
        out = tmp_path / f"jobs{jobs}.toml"
        result = CliRunner().invoke(
            main, ["calibrate", str(record), "--out", str(out), "--jobs", jobs, "--no-progress", *SHORT]
        )
        assert result.exit_code == 0, result.output
        written[jobs] = out.read_bytes()
    assert written["1"] == written["2"]
    text = written["1"].decode()
    assert all(f'[channel."taxel{c}"]' in text for c in range(3))


def test_a_parallel_batch_writes_the_serial_batchs_files_byte_for_byte(tmp_path: Path) -> None:
    folder = tmp_path / "records"
    folder.mkdir()
    for seed in (11, 12):
        array_record(folder / f"array{seed}.csv", channels=2, seed=seed)
    (folder / "broken.csv").write_text("time_s,resistance_ohm\n0,1\n", encoding="utf-8")
    outs = {}
    for jobs in ("1", "2"):
        out = tmp_path / f"cals{jobs}"
        result = CliRunner().invoke(
            main, ["calibrate", str(folder), "--out", str(out), "--jobs", jobs, "--no-progress", *SHORT]
        )
        assert result.exit_code == 1, result.output  # broken.csv failed, the others were written
        outs[jobs] = {p.name: p.read_bytes() for p in sorted(out.iterdir())}
    assert sorted(outs["1"]) == ["array11.toml", "array12.toml", "summary.csv", "summary.json"]
    for name in ("array11.toml", "array12.toml"):
        assert outs["1"][name] == outs["2"][name], name
    # the summaries name the files written, in their own folders; the rest is the same
    for name in ("summary.csv", "summary.json"):
        assert outs["1"][name].replace(b"cals1", b"cals2") == outs["2"][name], name
    assert outs["1"]["summary.csv"].count(b",ok,") == 4  # two channels of each good record
