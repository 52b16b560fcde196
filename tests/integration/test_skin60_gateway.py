"""The 60-point skin read by configuration alone: the gateway, given only a shipped profile
(``skin60-counts`` or ``skin60-mn``) and a bus, reads the skin60 simulator's vendor function
0x42 over RTU on a socat pty pair, RTU over TCP and Modbus TCP, in raw and calibrated modes;
the dynamic zero is triggered from the command line (``tare --device-zero``); and the
simulator's request log shows that nothing is written but the profile's set-up writes and the
action asked for."""

from __future__ import annotations

import asyncio
import contextlib
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from gateway.config import parse_config
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus
from sim_device.array import SimArray
from sim_device.scenarios import Scenario
from sim_device.skin60 import (
    HR_AD_MASK,
    HR_AUTO_ZERO_AT_POWER_ON,
    HR_DYNAMIC_ZERO,
    HR_OUTPUT_MODE,
    N_POINTS,
    Skin60Device,
    Skin60Request,
    serve_skin60_serial,
    serve_skin60_tcp,
    skin60_config,
)

BAUD = 115200
GATEWAY = str(Path(sys.executable).with_name("tactile-gateway"))


def loaded_skin(force_n: float) -> Skin60Device:
    cfg = skin60_config(noise_lsb_rms=0.0)
    return Skin60Device(SimArray(cfg.with_changes(scenario=Scenario.constant(force_n, cfg.layout))))


@contextlib.asynccontextmanager
async def skin_config(
    kind: str, skin: Skin60Device, pty: tuple[str, str] | None, profile: str
) -> AsyncIterator[str]:
    """A configuration file's text naming only the bus and the profile."""
    device = f'\n[[bus.device]]\nname = "palm"\ndevice_id = 1\nprofile = "{profile}"\n'
    if kind == "rtu":
        assert pty is not None
        async with serve_skin60_serial(skin, pty[1], BAUD, line_timing=True, tick_s=None):
            yield (
                f'[[bus]]\nname = "line"\nkind = "rtu"\nserial_port = "{pty[0]}"\n'
                f'baudrate = {BAUD}\nparity = "N"\ntimeout_s = 1.0\n{device}'
            )
    else:
        framer = "rtu" if kind == "rtu-over-tcp" else "socket"
        async with serve_skin60_tcp(skin, framer=framer, tick_s=None) as server:
            yield (
                f'[[bus]]\nname = "net"\nkind = "{kind}"\nhost = "127.0.0.1"\nport = {server.port}\n'
                f"timeout_s = 1.0\n{device}"
            )


@pytest.fixture(params=["rtu", "rtu-over-tcp", "tcp"])
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def pty(kind: str, request: pytest.FixtureRequest) -> tuple[str, str] | None:
    return request.getfixturevalue("pty_pair") if kind == "rtu" else None  # type: ignore[no-any-return]


SETUP_WRITES = {
    "skin60-mn": [Skin60Request(6, HR_OUTPUT_MODE, 1, (1,)), Skin60Request(6, HR_AD_MASK, 1, (0,))],
    "skin60-counts": [
        Skin60Request(6, HR_OUTPUT_MODE, 1, (0,)),
        Skin60Request(6, HR_AD_MASK, 1, (0,)),
        Skin60Request(6, HR_AUTO_ZERO_AT_POWER_ON, 1, (0,)),
    ],
}


async def test_the_calibrated_mode_reads_the_devices_own_force_and_zeroes_from_the_cli(
    kind: str, pty: tuple[str, str] | None, tmp_path: Path
) -> None:
    skin = loaded_skin(3.0)
    async with skin_config(kind, skin, pty, "skin60-mn") as text:
        snap = (await Poller(parse_config(text)).poll_once()).devices["palm"]
        served_mn = np.array(skin.points())  # the device is in mN mode now, and its sensors creep
        cfg = tmp_path / "skin.toml"
        cfg.write_text(text)
        proc = await asyncio.create_subprocess_exec(
            GATEWAY, "tare", "-c", str(cfg), "--device-zero",
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        out, err = await asyncio.wait_for(proc.communicate(), timeout=60)
        assert proc.returncode == 0, err.decode()
        assert "dynamic zero: holding 3 <- 1" in out.decode() and out.decode().endswith("done\n")
        zeroed = (await Poller(parse_config(text)).poll_once()).devices["palm"]
    assert snap.up, snap.error
    assert snap.n_channels == N_POINTS and set(snap.status.tolist()) == {ChannelStatus.OK}
    # the gateway's force is the device's mN / 1000, within the creep between the two reads
    np.testing.assert_allclose(snap.force_n, served_mn / 1000.0, rtol=0.02)
    assert 2.5 < float(np.median(snap.force_n)) < 3.5  # the device's tables read about the load
    # zeroed under the load: the points read (almost) nothing, but for the creep since the zero
    assert zeroed.up and float(np.max(zeroed.force_n)) < 0.05, zeroed.force_n
    writes = [r for r in skin.requests if r.is_write]
    assert writes == [
        *SETUP_WRITES["skin60-mn"],  # the first poll's connect
        # the command line: the set-up, as at every connect (the device zeroes itself as
        # configured), then the action, and nothing else
        *SETUP_WRITES["skin60-mn"],
        Skin60Request(6, HR_DYNAMIC_ZERO, 1, (1,)),
        *SETUP_WRITES["skin60-mn"],  # the second poll's connect
    ]
    # a poll reads the checks, reads the set-up back and reads the frame once by function 0x42
    reads = [(r.function_code, r.address) for r in skin.requests if not r.is_write]
    assert reads[:5] == [(3, 0), (3, 1), (3, HR_OUTPUT_MODE), (3, HR_AD_MASK), (0x42, 0)]


async def test_the_raw_mode_reads_counts_through_the_model(kind: str, pty: tuple[str, str] | None) -> None:
    skin = loaded_skin(2.0)
    async with skin_config(kind, skin, pty, "skin60-counts") as text:
        snap = (await Poller(parse_config(text)).poll_once()).devices["palm"]
        counts = np.array(skin.points())  # raw mode: the device's counts now
    assert snap.up, snap.error
    assert set(snap.status.tolist()) == {ChannelStatus.OK}
    # eq. 18 by hand with the profile's divider (5 V, 10 kohm, 12 bit): R = R_ref (FS / c - 1)
    expected_ohm = 10_000.0 * (4095.0 / counts - 1.0)
    np.testing.assert_allclose(snap.resistance_ohm, expected_ohm, rtol=0.02)
    assert np.all(snap.force_n > 0.5)
    assert [r for r in skin.requests if r.is_write] == SETUP_WRITES["skin60-counts"]
