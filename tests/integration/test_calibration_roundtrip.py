"""From a new sensor on the bench to forces within the paper's 0.1 N, through Modbus.

A simulated sensor whose parameters the gateway does not know (seeded part-to-part spread)
is recorded through the gateway while a bench protocol loads it; ``tactile-gateway
calibrate`` fits the record; the gateway, configured with the calibration file, then reads
a different load sequence on the same sensor, and its drift-corrected forces are compared
with the bench's reference force.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.cli import main
from gateway.cli.record_cmd import record_live
from gateway.cli.simulated import PacedClock
from gateway.config import load_config
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import VALUED_STATUSES, ChannelStatus, GatewaySnapshot
from sim_device import ArrayConfig, Scenario, SimArray, serve_tcp

BENCH_PROTOCOL = """
name = "bench-calibration"
[[load]]
channels = "all"
steps = [
  { hold_s = 20 },
  { hold_s = 60, force_n = 0.5 }, { hold_s = 60, force_n = 1.0 }, { hold_s = 60, force_n = 2.0 },
  { hold_s = 60, force_n = 3.0 }, { hold_s = 60, force_n = 4.0 }, { hold_s = 60, force_n = 5.0 },
  { hold_s = 120, force_n = 0.0 },
  { hold_s = 400, force_n = 1.0 }, { hold_s = 300, force_n = 0.0 },
  { hold_s = 400, force_n = 4.0 }, { hold_s = 300, force_n = 0.0 },
  { ramp_n = 5.0, rate_n_per_s = 0.1 }, { ramp_n = 0.0, rate_n_per_s = 0.1 }, { hold_s = 60 },
]
"""
SEED = 11
SPEED = 200.0


def _config_text(port: int, calibration: Path | None) -> str:
    cal = f'calibration = "{calibration}"\n' if calibration else ""
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
channels = 1
columns = 1
{cal}[bus.device.registers]
force_reference_address = 1000
"""


async def _record_bench(tmp_path: Path) -> Path:
    layout = ArrayConfig(channels=1, columns=1).layout
    scenario = Scenario.from_toml(BENCH_PROTOCOL, layout, source="bench.toml")
    array = SimArray(ArrayConfig(channels=1, columns=1, seed=SEED, scenario=scenario, speed=SPEED), 1)
    out = tmp_path / "bench.csv"
    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        cfg_path = tmp_path / "record.toml"
        cfg_path.write_text(_config_text(sim.port, None))
        cfg_path.chmod(0o600)
        end_s = scenario.duration_s or 0.0
        # until the device has played the protocol (a busy machine starts the poller late);
        # the wall time is a backstop
        await record_live(
            load_config(cfg_path),
            out,
            10.0 * end_s / SPEED,
            show_progress=False,
            until=lambda: array.last_sample_time_s >= end_s,
        )
    return out


async def _read_with_calibration(
    tmp_path: Path, cal: Path
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    # the device clock may not run more than 1 device second ahead between two register reads
    # (a paced clock; a poll makes 3 reads): a busy machine that polls late slows the device
    # down instead of leaving a 120 s hold with a handful of samples. Unloaded, the gateway
    # reads more often than that, and the clock is the wall clock.
    paced = PacedClock(max_step_s=1.0 / (SPEED / 2))
    array = SimArray(
        ArrayConfig(channels=1, columns=1, seed=SEED, scenario="holds", speed=SPEED / 2), 1, clock=paced
    )
    rows: list[tuple[float, float, float, int]] = []
    end_s = array.scenario.duration_s or 0.0
    played = asyncio.Event()

    def take(snap: GatewaySnapshot) -> None:
        dev = snap.devices.get("sensor")
        if dev is not None and dev.up and dev.device_time_s is not None:
            rows.append(
                (
                    dev.device_time_s,
                    float(dev.force_n[0]),
                    float(dev.reference_force_n[0]),
                    int(dev.status[0]),
                )
            )
            if dev.device_time_s >= end_s:
                played.set()

    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        cfg_path = tmp_path / "calibrated.toml"
        cfg_path.write_text(_config_text(sim.port, cal))
        cfg_path.chmod(0o600)
        holder = SnapshotHolder()
        holder.subscribe(take)
        async with Poller(load_config(cfg_path), holder):
            # until the gateway has read the scenario to its end (not a fixed sleep: a busy
            # machine starts the poller late, and the device clock runs from its creation)
            backstop_s = 30.0 * end_s / (SPEED / 2)
            try:
                await asyncio.wait_for(played.wait(), timeout=backstop_s)
            except TimeoutError:
                last = max((r[0] for r in rows), default=float("nan"))
                pytest.fail(
                    f"the read-back did not reach the scenario's end ({end_s:g} device s) in "
                    f"{backstop_s:g} s: last device time {last:g} s, {len(rows)} snapshots up"
                )
    data = np.array(sorted(set(rows)))
    return data[:, 0], data[:, 1], data[:, 2], data[:, 3].astype(int)


def _assert_every_hold_read(
    reference_n: np.ndarray, levels: tuple[float, ...] = (0.5, 2.0, 5.0), *, read: tuple[np.ndarray, ...] = ()
) -> None:
    """At least 20 samples at each of these levels of the ``holds`` scenario. ``read``: the
    whole read-back (device time, reference, status), described in the message of a failure."""
    for level in levels:
        n = int(np.count_nonzero(np.isclose(reference_n, level)))
        detail = ""
        if read:
            t, reference, status = read
            at = np.isclose(reference, level)
            codes, counts = np.unique(status[at], return_counts=True)
            kinds = {int(c): int(k) for c, k in zip(codes, counts, strict=True)}
            span = f"{t[at].min():g}-{t[at].max():g} s" if at.any() else "none"
            detail = f" (read at {level} N: {int(at.sum())} samples, device time {span}, statuses {kinds})"
        assert n >= 20, f"only {n} settled samples at {level} N{detail}"


def test_calibrated_gateway_reads_within_a_tenth_of_a_newton(tmp_path: Path) -> None:
    record = asyncio.run(_record_bench(tmp_path))
    cal = tmp_path / "cal.toml"
    result = CliRunner().invoke(main, ["calibrate", str(record), "--out", str(cal)])
    assert result.exit_code == 0, result.output
    assert '[channel."ch00"]' in cal.read_text()

    t, force, reference, status = asyncio.run(_read_with_calibration(tmp_path, cal))
    steps = t[np.flatnonzero(np.diff(reference) != 0) + 1]
    since_step = t - np.array([steps[steps <= x].max(initial=t[0]) for x in t])
    settled = (since_step >= 2.0) & (reference > 0) & (status == int(ChannelStatus.OK))
    err = np.abs(force[settled] - reference[settled])
    within = float(np.mean(err <= 0.1))
    print(
        f"\ncalibrated gateway: {100 * within:.1f} % of {settled.sum()} settled samples within 0.1 N "
        f"(mean error {err.mean():.3f} N, max {err.max():.3f} N)"
    )
    # every hold of the read-back (0.5, 2 and 5 N) is read, whatever the machine's load (a count
    # of samples over all was a timing assumption: a busy machine polls less often)
    _assert_every_hold_read(reference[settled], read=(t, reference, status))
    assert within >= 0.95

    # the same sensor read with the default parameters is measurably worse
    empty = tmp_path / "defaults.toml"
    empty.write_text("# no channel tables: every parameter keeps its default\n")
    _, force2, reference2, status2 = asyncio.run(_read_with_calibration(tmp_path, empty))
    ok2 = (reference2 > 0) & (status2 == int(ChannelStatus.OK))
    err2 = np.abs(force2[ok2] - reference2[ok2])
    print(f"default parameters: mean error {err2.mean():.3f} N")
    assert err2.mean() > 2 * err.mean()


def test_a_line_calibration_is_read_by_the_gateway(tmp_path: Path) -> None:
    """``calibrate --model line``: the gateway reads the channel with the line, not the model."""
    record = asyncio.run(_record_bench(tmp_path))
    cal = tmp_path / "line.toml"
    result = CliRunner().invoke(main, ["calibrate", str(record), "--model", "line", "--out", str(cal)])
    assert result.exit_code == 0, result.output
    assert '[line."ch00"]' in cal.read_text()
    config_path = tmp_path / "line-config.toml"
    config_path.write_text(_config_text(5020, cal))
    ((_, device),) = load_config(config_path).devices()
    assert device.channels[0].conversion is not None

    t, force, reference, status = asyncio.run(_read_with_calibration(tmp_path, cal))
    valued = {int(s) for s in VALUED_STATUSES}  # ok, no_contact, saturated, extrapolated
    assert set(status.tolist()) <= valued
    steps = t[np.flatnonzero(np.diff(reference) != 0) + 1]
    since_step = t - np.array([steps[steps <= x].max(initial=t[0]) for x in t])
    loaded = (since_step >= 2.0) & (reference > 0) & (status == int(ChannelStatus.OK))
    err = np.abs(force[loaded] - reference[loaded])
    print(f"\nline calibration: mean error {err.mean():.3f} N over {loaded.sum()} settled samples")
    # 5 N is the top of the bench record: the line reads beyond it along itself, flagged
    # extrapolated (not counted here)
    _assert_every_hold_read(reference[loaded], levels=(0.5, 2.0))
    assert err.mean() < 0.5  # the line has no creep correction: coarser than the model, but a reading
