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
from pathlib import Path

import numpy as np
import pytest
from netutil import free_port

from gateway.analysis.discrepancy import run_discrepancy
from gateway.analysis.records import read_record
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
    # 100x clock: a poll every 20 ms is a sample every 2 s of device time, as in the direct
    # record, and the few ms between a poll's requests stay well below a second of device time
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
    through_modbus = run_discrepancy(
        read_record(out, require_force=True).channel(), ("tunneling", "contact", "creep")
    )
    direct_cfg = ArrayConfig(
        channels=1,
        columns=1,
        seed=3,
        scenario="discrepancy",
        world_effects=("temperature",),
        sensor_noise_rel=0.01,
    )
    direct_path = tmp_path / "direct.csv"
    record_offline(direct_cfg, path=direct_path, record_period_s=2.0)
    direct = run_discrepancy(read_record(direct_path).channel(), ("tunneling", "contact", "creep"))
    print(f"\nverdicts: through Modbus {through_modbus.added}, direct {direct.added}")
    assert through_modbus.added == direct.added == ["temperature"]


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
