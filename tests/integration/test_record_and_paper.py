"""``tactile-gateway record`` and ``paper`` against the simulated array over real sockets."""

from __future__ import annotations

import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from netutil import free_port
from numpy.typing import NDArray

from gateway.analysis.discrepancy import run_discrepancy
from gateway.analysis.records import ChannelRecord, read_record
from sim_device import ArrayConfig, record_offline

BIN = Path(sys.executable).parent


def _wait_port(port: int, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise AssertionError(f"nothing listens on port {port}")


def _config(path: Path, port: int, channels: int, poll_interval_s: float = 0.02) -> Path:
    path.write_text(
        f"""
[[bus]]
name = "sim"
kind = "tcp"
host = "127.0.0.1"
port = {port}
timeout_s = 0.5
poll_interval_s = {poll_interval_s}

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = {channels}
columns = 1
[bus.device.registers]
force_reference_address = 1000
temperature_address = 1600
"""
    )
    path.chmod(0o600)
    return path


@pytest.fixture
def sim(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[int]:
    port = free_port()
    args: list[str] = request.param
    proc = subprocess.Popen(
        [str(BIN / "tactile-sim"), "run", "--tcp", f"127.0.0.1:{port}", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_port(port)
        yield port
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.parametrize("sim", [["--channels", "2", "--scenario", "holds", "--speed", "60"]], indirect=True)
def test_record_writes_a_spec_record_with_reference_force(tmp_path: Path, sim: int) -> None:
    config = _config(tmp_path / "gw.toml", sim, 2)
    out = tmp_path / "rec.csv"
    result = subprocess.run(
        [str(BIN / "tactile-gateway"), "record", "-c", str(config), "--duration", "3", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert re.search(r"wrote \d+ samples from \d+ polls", result.stdout), result.stdout
    rec = read_record(out, require_force=True)
    assert rec.metadata["source"] == "tactile-gateway record"
    assert sorted(rec.channels) == ["ch00", "ch01"]
    ch = rec.channel("ch00")
    assert ch.n_samples > 50
    assert np.all(np.diff(ch.time_s) >= 0) and ch.time_s[-1] > 60.0  # device clock at 60x
    assert ch.force_n is not None and set(np.round(np.unique(ch.force_n), 3)) <= {0.0, 0.5, 2.0, 5.0}
    assert ch.temperature_c is not None and np.allclose(ch.temperature_c, 25.0)
    loaded = ch.force_n > 0
    assert np.isfinite(ch.resistance_ohm[loaded]).all()


@pytest.mark.parametrize("sim", [["--channels", "1", "--scenario", "holds", "--speed", "20"]], indirect=True)
def test_an_interrupted_recording_is_a_valid_record(tmp_path: Path, sim: int) -> None:
    config = _config(tmp_path / "gw.toml", sim, 1)
    out = tmp_path / "rec.csv"
    proc = subprocess.Popen(
        [str(BIN / "tactile-gateway"), "record", "-c", str(config), "--duration", "120", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )

    # interrupt once rows are on disk (the file is flushed as it goes), not after a fixed sleep:
    # on a busy machine 3 s may not even cover the start-up
    def data_rows() -> int:
        if not out.exists():
            return 0
        lines = out.read_text().splitlines()
        return sum(1 for line in lines if line and not line.startswith("#")) - 1

    deadline = time.monotonic() + 60.0
    while data_rows() <= 25 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the recording ended before it was interrupted"
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    rec = read_record(out, require_force=True)
    assert rec.channel().n_samples > 20


def test_record_refuses_bad_arguments(tmp_path: Path) -> None:
    config = _config(tmp_path / "gw.toml", 5020, 1)
    bad = subprocess.run(
        [str(BIN / "tactile-gateway"), "record", "-c", str(config), "--duration", "1", "--out", str(tmp_path),
         "--channels", "ch00"],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert bad.returncode == 2 and "is a directory" in bad.stderr
    bad = subprocess.run(
        [str(BIN / "tactile-gateway"), "record", "-c", str(config), "--duration", "1",
         "--out", str(tmp_path / "r.csv"), "--channels", "tip"],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert bad.returncode == 2 and "no channel 'tip'" in bad.stderr


@pytest.mark.parametrize(
    "sim",
    [
        [
            "--channels", "1", "--scenario", "discrepancy", "--speed", "100", "--seed", "3",
            "--world-effects", "temperature", "--sensor-noise", "0.01",
        ]
    ],
    indirect=True,
)  # fmt: skip
def test_a_record_through_modbus_gives_the_same_verdict_as_the_direct_record(
    tmp_path: Path, sim: int
) -> None:
    # The simulator's clock runs from its start, the record's from its first poll: the record
    # covers a window that starts a few hundred device seconds in (the CLI's start-up at 100x;
    # measured 299-497 s under load) and samples it as densely as the gateway keeps up (median
    # 2.0-2.4 s, gaps up to 9.7 s). The direct record is therefore taken at the same device
    # instants, so that both see the same window and sampling and differ only in the noise draw.
    config = _config(tmp_path / "gw.toml", sim, 1, poll_interval_s=0.02)
    out = tmp_path / "modbus.csv"
    duration = 4760.0 / 100.0
    result = subprocess.run(
        [
            str(BIN / "tactile-gateway"),
            "record",
            "-c",
            str(config),
            "--duration",
            f"{duration:.1f}",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert result.returncode == 0, result.stderr
    modbus = read_record(out, require_force=True).channel()
    direct_cfg = ArrayConfig(
        channels=1,
        columns=1,
        seed=3,
        scenario="discrepancy",
        world_effects=("temperature",),
        sensor_noise_rel=0.01,
    )
    every_sample = tmp_path / "direct.csv"
    # the scenario (4760 s) and the record's late start: 1500 s of margin
    period_s = direct_cfg.sample_period_s
    record_offline(direct_cfg, duration_s=6300.0, path=every_sample, record_period_s=period_s)
    truth = read_record(every_sample).channel()
    rows = _same_instants(modbus, truth)
    direct = _rows(truth, rows, modbus.time_s)
    assert modbus.force_n is not None and direct.force_n is not None
    assert modbus.temperature_c is not None and direct.temperature_c is not None
    # every row's reference force and temperature are the simulator's at that instant (float32
    # registers; its own record prints 6 digits): the clock and the values of a poll belong together
    np.testing.assert_allclose(modbus.force_n, direct.force_n, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(modbus.temperature_c, direct.temperature_c, rtol=1e-5)
    # the resistances differ by two independent 1 % noise draws only: no bias (4 standard
    # errors), a spread of sqrt(2) x 1 % (its standard error is 2 % at ~1500 rows)
    loaded = np.isfinite(modbus.resistance_ohm) & np.isfinite(direct.resistance_ohm) & (direct.force_n > 0.1)
    log_ratio = np.log(modbus.resistance_ohm[loaded] / direct.resistance_ohm[loaded])
    spread = float(np.std(log_ratio))
    assert loaded.sum() > 500, loaded.sum()
    assert abs(float(np.mean(log_ratio))) < 4.0 * spread / math.sqrt(loaded.sum()), np.mean(log_ratio)
    assert 0.85 < spread / (math.sqrt(2.0) * 0.01) < 1.15, spread
    baseline = ("tunneling", "contact", "creep")
    through_modbus, same_instants = run_discrepancy(modbus, baseline), run_discrepancy(direct, baseline)
    print(
        f"\nstart {truth.time_s[rows[0]]:.2f} s, {modbus.n_samples} rows; verdicts: "
        f"through Modbus {through_modbus.added}, direct {same_instants.added}"
    )
    # The hidden effect is named first on both. A second, small addition (creep2 once, score
    # -4276 -> -4314, log-R 0.0112 -> 0.0106) can go either way with the noise draw.
    assert through_modbus.added[:1] == same_instants.added[:1] == ["temperature"]


def _same_instants(record: ChannelRecord, truth: ChannelRecord) -> NDArray[np.intp]:
    """The rows of ``truth`` (every sample) at the record's device instants: the record starts
    at an unknown device time s, found as the one for which every row's reference force is the
    simulator's at t + s (the profile's many steps and ramps leave one such s)."""
    assert record.force_n is not None and truth.force_n is not None
    first = np.flatnonzero(np.isclose(truth.force_n, record.force_n[0], rtol=1e-5, atol=1e-9))
    for c in first:
        rows = np.searchsorted(truth.time_s, record.time_s + truth.time_s[c] - 1e-6)
        if rows[-1] >= truth.n_samples:
            break
        if np.allclose(truth.force_n[rows], record.force_n, rtol=1e-5, atol=1e-9):
            return rows
    raise AssertionError("no device time at which the recorded forces are the simulator's")


def _rows(truth: ChannelRecord, rows: NDArray[np.intp], time_s: NDArray[np.float64]) -> ChannelRecord:
    def pick(values: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
        return None if values is None else values[rows]

    return replace(
        truth,
        time_s=time_s,
        resistance_ohm=truth.resistance_ohm[rows],
        force_n=pick(truth.force_n),
        temperature_c=pick(truth.temperature_c),
        line=truth.line[rows],
    )


def test_paper_replay_through_modbus(tmp_path: Path) -> None:
    # The test's tolerance is each coefficient's own standard error: on a busy machine the
    # gateway polls less often in device time, the load step's onset is known only within a
    # wider gap, and E1 and mu1 are pinned down less tightly (2.6 % at 12 s sampling against
    # 1.2 % at 4 s, measured on synthetic records); a fixed 5 % failed 4 of 5 stress rounds.
    out = tmp_path / "paper"
    env = {**os.environ, "MPLBACKEND": "Agg"}
    result = subprocess.run(
        [str(BIN / "tactile-gateway"), "paper", "--out", str(out), "--speed", "150"],
        capture_output=True,
        text=True,
        timeout=180,
        env=env,
    )
    assert result.returncode == 0, result.stderr
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "creep_tests.csv",
        "fig10_surface.png",
        "fig5_force_resistance_conductance.png",
        "fig6b_viscoelastic_coefficients.png",
        "fig9b_creep_model_vs_record.png",
        "staircase.csv",
        "summary.md",
    ]
    summary = (out / "summary.md").read_text()
    number = r" ([\d.]+) \|"
    rows = re.findall(r"^\| (\d) \|" + number * 10 + "$", summary, re.M)
    assert [r[0] for r in rows] == ["2", "4", "6", "8"]
    for row in rows:
        e0, e0_true, e1, e1_true, mu1, mu1_true, _, *sigma_pct = (float(v) for v in row[1:])
        # the record pins the moduli down (a gateway that lost samples or times would not) ...
        assert sigma_pct[0] < 1.0 and sigma_pct[1] < 8.0 and sigma_pct[2] < 8.0, row
        # ... and the truth lies within 4 standard errors (12 checks: a false alarm < 1e-3)
        # (0.01 %: the summary prints sigma to two decimals)
        checks = ((e0, e0_true, sigma_pct[0]), (e1, e1_true, sigma_pct[1]), (mu1, mu1_true, sigma_pct[2]))
        for fitted, true, pct in checks:
            assert abs(math.log(fitted / true)) <= 4 * max(pct, 0.01) / 100, row


def test_paper_stopped_by_sigterm_exits_at_once_and_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "paper"
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.Popen(
        [str(BIN / "tactile-gateway"), "paper", "--out", str(out), "--speed", "10"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        # signal once both recordings are under way (their temporary files exist), not after a sleep
        deadline = time.monotonic() + 60.0
        while proc.poll() is None and time.monotonic() < deadline:
            if out.is_dir() and len(list(out.rglob(".*.csv.*.tmp"))) == 2:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "paper ended before it was signalled"
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "Traceback" not in stderr
    assert stderr.strip() == "paper: stopped by SIGTERM; nothing written", stderr
    assert not out.exists() or sorted(p.name for p in out.iterdir()) == []
