"""``calibrate --scheduler ADDRESS`` on a Dask ``LocalCluster`` of two worker processes: the
calibration of a record and the files of a batch are the same to the byte as the local run's,
and an address with no scheduler is one line and exit status 2."""

from __future__ import annotations

from collections.abc import Iterator
from multiprocessing import resource_tracker
from pathlib import Path

import pytest
from click.testing import CliRunner
from distributed import LocalCluster

from gateway.cli import main
from sim_device import ArrayConfig, record_offline

pytestmark = pytest.mark.slow  # starts a scheduler and two worker processes

SHORT = ["--model", "auto", "--objective", "log-r", "--force-offset", "none", "--no-progress"]


def array_record(path: Path, channels: int, seed: int) -> Path:
    """A simulated array under load ramps, 190 rows per channel, channels taxel0... (as
    tests/unit/gateway/cli/array_records.py)."""
    config = ArrayConfig(
        channels=channels, columns=channels, seed=seed, scenario="ramps", sensor_noise_rel=0.01
    )
    record = record_offline(config, record_period_s=1.0)
    record.channel = [f"taxel{c}" for c in record.channel]
    record.write_csv(path)
    return path


@pytest.fixture(scope="module")
def process_wide_helpers() -> None:
    """Start the two helpers that live as long as this Python process, before the shared fixture
    takes its list of the test's threads and processes (a module fixture is set up before it):
    distributed's one offload thread (``distributed.utils._offload_executor``, made at import,
    its thread started at first use and never ended) and multiprocessing's resource tracker (one
    per process, started by the cluster's worker processes). Neither belongs to a test; the
    cluster's own threads and processes are still checked, and must be gone after each test."""
    from distributed.utils import _offload_executor

    _offload_executor.submit(int).result(timeout=30)
    resource_tracker.ensure_running()


@pytest.fixture
def scheduler(process_wide_helpers: None) -> Iterator[str]:
    """Two worker processes of one thread each on loopback, closed when the test ends."""
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        yield cluster.scheduler_address


def _calibrate(*args: str) -> str:
    result = CliRunner().invoke(main, ["calibrate", *args, *SHORT])
    return f"{result.exit_code}\n{result.output}"


def test_a_record_and_a_batch_on_the_cluster_equal_the_local_run(tmp_path: Path, scheduler: str) -> None:
    record = array_record(tmp_path / "array.csv", channels=3, seed=5)
    local, remote = tmp_path / "local.toml", tmp_path / "remote.toml"
    assert _calibrate(str(record), "--out", str(local), "--jobs", "1").startswith("0\n")
    assert _calibrate(str(record), "--out", str(remote), "--scheduler", scheduler).startswith("0\n")
    assert local.read_bytes() == remote.read_bytes()

    folder = tmp_path / "records"
    folder.mkdir()
    for seed in (11, 12):
        array_record(folder / f"array{seed}.csv", channels=2, seed=seed)
    (folder / "broken.csv").write_text("time_s,resistance_ohm\n0,1\n", encoding="utf-8")
    outs = {}
    for name, where in (("local", ["--jobs", "1"]), ("cluster", ["--scheduler", scheduler])):
        printed = _calibrate(str(folder), "--out", str(tmp_path / name), *where)
        assert printed.startswith("1\n"), printed  # broken.csv failed, the others were written
        outs[name] = {p.name: p.read_bytes() for p in sorted((tmp_path / name).iterdir())}
    assert sorted(outs["local"]) == ["array11.toml", "array12.toml", "summary.csv", "summary.json"]
    for file, local_bytes in outs["local"].items():
        # the summaries name the files written, each in its own folder
        assert local_bytes.replace(b"/local", b"/cluster") == outs["cluster"][file], file


def test_an_address_with_no_scheduler_is_one_line_and_exit_2(tmp_path: Path) -> None:
    record = array_record(tmp_path / "array.csv", channels=2, seed=5)
    for address in ("tcp://127.0.0.1:1", "no-port-here"):
        result = CliRunner().invoke(
            main, ["calibrate", str(record), "--scheduler", address, "--out", str(tmp_path / "c.toml")]
        )
        assert result.exit_code == 2, result.output
        assert f"--scheduler {address!r}: no Dask scheduler reached" in result.output
        assert "Traceback" not in result.output and not (tmp_path / "c.toml").exists()
