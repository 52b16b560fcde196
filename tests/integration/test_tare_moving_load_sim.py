"""``tactile-gateway tare --moving-load`` (a real process) against the simulator's rawgrid board
(docs/register-map-rawgrid.md: 12-bit counts, a low-side divider, 195 kohm of board leakage,
so an empty cell reads about 3895 counts) served in this process over loopback Modbus TCP,
under a load that moves and never leaves the array.

The load: a bar of 2 N per cell, three columns wide, sweeping the 6 x 6 grid with a period of
60 device s (column g loaded over ``[10 g, 10 g + 30)`` mod 60 s), and 1 N resting on one cell
throughout. The simulator runs ``SPEED`` times faster than the wall clock, so every cell is
loaded 3 s and unloaded 3 s of every 6 s of wall time, whenever the tare starts. A plain tare
refuses (loaded) at any moment; the moving-load tare zeroes every cell but the resting one at
its own rest value and names that one."""

from __future__ import annotations

import asyncio
import re
import sys
import time
from pathlib import Path

import pytest

from gateway.config import load_config
from sim_device import ArrayConfig, Scenario, SimArray, serve_tcp
from sim_device.profiles import Profile, ProfileBuilder
from sim_device.scenarios import UniformLoad

pytestmark = pytest.mark.slow

CLI = Path(sys.executable).parent / "tactile-gateway"
SPEED = 10.0
PERIOD_S = 60.0  # device s
BAR_N = 2.0
RESTING = 14  # physical channel with 1 N throughout
REST_COUNTS = 3895  # the empty cell, docs/register-map-rawgrid.md


def column_profile(g: int) -> Profile:
    """2 N over [10 g, 10 g + 30) device s of every 60, else 0 N."""
    a, b = 10.0 * g, 10.0 * g + 30.0
    if a == 0.0:
        return ProfileBuilder(BAR_N).hold(30.0).step(0.0).hold(30.0).build(repeat=True)
    if b <= PERIOD_S:
        builder = ProfileBuilder(0.0).hold(a).step(BAR_N).hold(30.0).step(0.0)
        return (builder.hold(PERIOD_S - b) if b < PERIOD_S else builder).build(repeat=True)
    wrap = b - PERIOD_S
    return (
        ProfileBuilder(BAR_N)
        .hold(wrap)
        .step(0.0)
        .hold(a - wrap)
        .step(BAR_N)
        .hold(PERIOD_S - a)
        .build(repeat=True)
    )


def board() -> SimArray:
    config = ArrayConfig(
        register_map="rawgrid", channels=36, columns=6, pitch_mm=5.0, param_spread=False, speed=SPEED, seed=5
    )
    loads = [UniformLoad(column_profile(g), channels=tuple(range(g, 36, 6))) for g in range(6)]
    loads.append(UniformLoad(ProfileBuilder(1.0).hold(PERIOD_S).build(repeat=True), channels=(RESTING,)))
    scenario = Scenario("moving-bar", config.layout, loads=loads)
    return SimArray(config.with_changes(scenario=scenario), clock=time.monotonic)


async def run_tare(config: Path, *options: str) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        str(CLI), "tare", "-c", str(config), *options,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    try:
        out, err = await asyncio.wait_for(proc.communicate(), timeout=120.0)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


async def test_a_moving_load_on_the_simulated_board_is_zeroed_cell_by_cell(tmp_path: Path) -> None:
    array = board()
    order = [int(p) for p in array.register_channels()]  # gateway channel k holds physical order[k]
    resting = order.index(RESTING)
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        path = tmp_path / "gateway.toml"
        path.write_text(
            f'# the jaw\n[[bus]]\nname = "lab"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {server.port}\n'
            'poll_interval_s = 0.05\ntimeout_s = 1.0\n\n[[bus.device]]\nname = "jaw"\ndevice_id = 1\n'
            'profile = "acme-at6x6"\n',
            encoding="utf-8",
        )
        before = path.read_bytes()
        code, out, err = await run_tare(path, "--seconds", "1")
        assert code == 2 and "the array is loaded over the 1 s sampled" in err, (out, err)
        assert path.read_bytes() == before

        # 8 s of wall time: 80 device s, more than one sweep
        code, out, err = await run_tare(path, "--moving-load", "--seconds", "8")
        assert code == 0, (out, err)
    assert "baseline_ohm written for 35 of 36 channels, each from its own still, unloaded stretch" in out
    assert f"not zeroed: ch{resting:02d} (loaded throughout the 8 s sampled: at its least loaded" in out
    spans = dict(re.findall(r"^  (ch\d\d): .* at ([\d.]+-[\d.]+ s \(\d+ polls\))$", out, re.M))
    assert len(spans) == 35 and f"ch{resting:02d}" not in spans, out
    for name, span in spans.items():
        a, b, n = (float(x) for x in re.findall(r"[\d.]+", span))
        # within one unloaded interval (3 s of wall time), of at least 10 polls
        assert n >= 10 and 0.0 <= a < b <= 8.5 and b - a <= 3.05, (name, span)
    channels = load_config(path).buses[0].devices[0].channels
    assert channels[resting].baseline_ohm is None
    rest_ohm = 10_000.0 * REST_COUNTS / (4095 - REST_COUNTS)  # 194750 ohm
    for ch in channels:
        if ch.index != resting:
            # 3895 +- 3 counts: 191724..197970 ohm
            assert ch.baseline_ohm == pytest.approx(rest_ohm, rel=0.017), (ch.name, ch.baseline_ohm)
    assert "# the jaw" in path.read_text(encoding="utf-8")
