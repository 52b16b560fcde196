"""``apply`` on a recorded file gives the same forces as the live gateway on the same samples.

The gateway, its device configured with a calibration file (one channel with the simulated
sensor's true parameters and a baseline, one read with a conductance line), polls the
simulated array over Modbus/TCP on an ephemeral loopback port. The polls are recorded as
``tactile-gateway record`` records them (``LiveRecorder`` on the poller's snapshots), and the
forces the live gateway computed on those same polls are kept beside. ``tactile-gateway apply``
with the same calibration then reads the recorded file, and its tracked force must be the live
gateway's on every row.

Tolerance: the record writes each resistance as the shortest text that reads back as the same
double, and each time rounded to 1 us of the device's millisecond clock, so ``apply`` is given
the very resistances and time steps the live gateway used; only the last bit of a time step
can differ (1 ms as 1e-3 s against 10^6 ns as 1e-9 s), a relative error of about 1e-16 in a
creep step. 1e-9 N (and 1e-9 relative) leaves a margin of several orders of magnitude and still
fails on any real difference (a state that is not carried, a time step that is not the
device's: those are 1e-4 N and more on these holds).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from dataclasses import fields
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from gateway.analysis.recorder import LiveRecorder
from gateway.analysis.records import read_record
from gateway.cli import main
from gateway.cli.simulated import gateway_params
from gateway.config import load_config
from gateway.model import SensorModel, SensorParams
from gateway.model.effects import PAPER_EFFECTS
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import GatewaySnapshot
from sim_device import ArrayConfig, SimArray, serve_tcp

SPEED = 100.0  # device seconds per wall second
#: Device time the recording must reach: 0 N to 10 s, 0.5 N to 130 s, 2 N from 130 s (``holds``).
END_DEVICE_S = 200.0
MIN_POLLS = 60
TOLERANCE_N = 1e-9


def _calibration(params: list[SensorParams]) -> str:
    """ch00: its true parameters and a baseline; ch01: a conductance line through the
    instantaneous curve at 0.5 and 5 N (the line a bench would give, more or less)."""
    defaults = SensorParams()
    lines = ['[channel."ch00"]', "baseline_ohm = 5e8"]
    for f in fields(SensorParams):
        value = getattr(params[0], f.name)
        if value != getattr(defaults, f.name):
            lines.append(f"{f.name} = {float(value)!r}")
    model = SensorModel(PAPER_EFFECTS, [params[1]])
    g = 1.0 / model.resistance(np.array([[0.5], [5.0]]))[:, 0]
    slope = float((g[1] - g[0]) / 4.5)
    intercept = float(g[0] - 0.5 * slope)
    low = max(0.05, 1.1 * -intercept / slope)
    lines += ['[line."ch01"]', f"slope_s_per_n = {slope!r}", f"intercept_s = {intercept!r}"]
    lines += [f"force_min_n = {low!r}", "force_max_n = 10.0"]
    return "\n".join(lines) + "\n"


def _config_text(port: int, calibration: Path) -> str:
    return f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = {port}
poll_interval_s = 0.01

[[bus.device]]
name = "sensor"
device_id = 1
profile = "tactile-sim"
channels = 2
columns = 2
calibration = "{calibration}"
[bus.device.registers]
force_reference_address = 1000
"""


LivePoll = tuple[float, tuple[str, ...], tuple[float, ...], tuple[float, ...]]


async def _record_live(
    tmp_path: Path, config_text: str | None = None, name: str = "live"
) -> tuple[Path, Path, list[LivePoll]]:
    """Record through the live gateway; the record, the calibration and, per poll, the device
    time, the channel names and the live tracked and static forces. ``config_text``: the
    gateway's configuration with ``{port}`` for the simulator's (default: ``_config_text``
    naming the hand-written ``_calibration``)."""
    array = SimArray(ArrayConfig(channels=2, columns=2, seed=5, scenario="holds", speed=SPEED), 1)
    cal = tmp_path / "cal.toml"
    if config_text is None:
        cal.write_text(_calibration(gateway_params(array.channel_params)))
    out = tmp_path / f"{name}.csv"
    polls: list[LivePoll] = []
    seen: set[float] = set()
    enough = asyncio.Event()
    loop = asyncio.get_running_loop()

    def take(snap: GatewaySnapshot) -> None:
        dev = snap.devices.get("sensor")
        if dev is None or not dev.up or dev.device_time_s is None or dev.last_success_timestamp_s is None:
            return
        if dev.last_success_timestamp_s in seen:  # not polled again (the recorder skips it too)
            return
        seen.add(dev.last_success_timestamp_s)
        polls.append(
            (
                dev.device_time_s,
                dev.channel_names,
                tuple(float(x) for x in dev.force_n),
                tuple(float(x) for x in dev.force_static_n),
            )
        )
        if dev.device_time_s >= END_DEVICE_S and len(polls) >= MIN_POLLS:
            loop.call_soon_threadsafe(enough.set)

    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        cfg_path = tmp_path / "gateway.toml"
        if config_text is None:
            cfg_path.write_text(_config_text(sim.port, cal))
        else:
            cfg_path.write_text(config_text.replace("{port}", str(sim.port)))
        cfg_path.chmod(0o600)
        config = load_config(cfg_path)
        holder = SnapshotHolder()
        with out.open("w", encoding="utf-8", newline="") as fh:
            # what `tactile-gateway record` does, and the live forces of the same polls beside it
            recorder = LiveRecorder(fh, config, metadata={"source": "tactile-gateway record"})
            holder.subscribe(recorder)
            holder.subscribe(take)
            async with Poller(config, holder):
                # until the device has played into the 2 N hold (not a fixed sleep: a busy
                # machine starts the poller late); the wall-time limit is a backstop
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(enough.wait(), timeout=60.0 * END_DEVICE_S / SPEED)
    return out, cal, polls


def test_apply_on_a_recorded_file_gives_the_live_gateways_forces(tmp_path: Path) -> None:
    record_path, cal, polls = asyncio.run(_record_live(tmp_path))
    _check_apply_equals_live(tmp_path, record_path, cal, polls)


def test_calibrate_install_then_live_reads_what_apply_reads(tmp_path: Path) -> None:
    """The README's path without a manual step: a record, ``calibrate --model curve --install``
    into the gateway's configuration, the live gateway with it, and ``apply`` of the same
    calibration to what it recorded: the same forces, to 1e-9 N."""
    first, _, _ = asyncio.run(_record_live(tmp_path))
    config = tmp_path / "installed.toml"
    config.write_text(_config_text(65535, Path("none.toml")).replace('calibration = "none.toml"\n', ""))
    cal = tmp_path / "written.toml"
    args = ["calibrate", str(first), "--model", "curve", "--out", str(cal), "--install", str(config)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    text = config.read_text()
    assert 'calibration = "written.toml"' in text and "[curve." in cal.read_text()
    live_text = text.replace("port = 65535", "port = {port}")
    record_path, _, polls = asyncio.run(_record_live(tmp_path, live_text, "installed-live"))
    _check_apply_equals_live(tmp_path, record_path, cal, polls, creeps=False)


def _check_apply_equals_live(
    tmp_path: Path, record_path: Path, cal: Path, polls: list[LivePoll], creeps: bool = True
) -> None:
    assert len(polls) >= MIN_POLLS, f"only {len(polls)} polls recorded"
    assert polls[-1][0] >= END_DEVICE_S, f"the device reached only {polls[-1][0]} s"

    out = tmp_path / "applied.csv"
    result = CliRunner().invoke(main, ["apply", str(cal), str(record_path), "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output

    # the live forces by (record time, channel): the recorder's time is the device clock from
    # its first row, rounded to 1 us
    t0 = polls[0][0]
    live: dict[tuple[float, str], tuple[float, float]] = {}
    for device_time_s, names, forces, statics in polls:
        for name, force, static in zip(names, forces, statics, strict=True):
            live[(round(device_time_s - t0, 6), name)] = (force, static)

    rows = [line.split(",") for line in out.read_text().splitlines() if not line.startswith("#")]
    header, body = rows[0], rows[1:]
    col = {name: i for i, name in enumerate(header)}
    assert len(body) == read_record(record_path).channel("ch00").n_samples * 2
    applied_n, live_n, static_applied, static_live, reference = [], [], [], [], []
    for row in body:
        key = (float(row[col["time_s"]]), row[col["channel"]])
        assert key in live, f"row {key} is not a poll of the live gateway"
        tracked = row[col["force_tracked_n"]]
        applied_n.append(float(tracked) if tracked else math.nan)
        live_n.append(live[key][0])
        static = row[col["force_static_n"]]
        static_applied.append(float(static) if static else math.nan)
        static_live.append(live[key][1])
        reference.append(float(row[col["force_n"]]))
    np.testing.assert_allclose(applied_n, live_n, rtol=TOLERANCE_N, atol=TOLERANCE_N, equal_nan=True)
    np.testing.assert_allclose(
        static_applied, static_live, rtol=TOLERANCE_N, atol=TOLERANCE_N, equal_nan=True
    )

    # not a trivial agreement: the record holds a load long enough for the creep state to matter
    # (the tracked and the static force of ch00 part by more than 0.01 N), and both channels read
    a, s, ref = np.array(applied_n), np.array(static_applied), np.array(reference)
    channel = np.array([row[col["channel"]] for row in body])
    ch00 = channel == "ch00"
    assert np.count_nonzero(ch00 & (ref == 0.5)) >= 10
    if creeps:
        assert float(np.nanmax(np.abs(a[ch00] - s[ch00]))) > 0.01
    assert np.isfinite(a[~ch00 & (ref > 0)]).all()
