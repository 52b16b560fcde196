"""Vendor function code 0x42 end to end: the real ``ModbusTransport`` reads the skin60
simulator over Modbus TCP, RTU over TCP and RTU on a socat pty pair, switches its output mode
and zero with function 6, and the simulator's request log shows exactly what was sent."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

import numpy as np
import pytest
from test_gateway_tcp import array_device

from gateway.config import BusConfig, bus_config_for
from gateway.errors import DeviceExceptionResponse
from gateway.modbus.backends import open_transport
from gateway.modbus.vendor_fc import VendorRead
from sim_device.array import SimArray
from sim_device.scenarios import Scenario
from sim_device.skin60 import (
    HR_DYNAMIC_ZERO,
    HR_OUTPUT_MODE,
    N_POINTS,
    Skin60Device,
    Skin60Request,
    serve_skin60_serial,
    serve_skin60_tcp,
    skin60_config,
)

SKIN = VendorRead(0x42)
BAUD = 115200
#: RTU on a pty, framed by pymodbus' client or by the direct one (``rtu_line``)
SERIAL_KINDS = ("rtu-pymodbus", "rtu-direct")


def loaded_skin(force_n: float = 3.0) -> Skin60Device:
    cfg = skin60_config(noise_lsb_rms=0.0)
    return Skin60Device(SimArray(cfg.with_changes(scenario=Scenario.constant(force_n, cfg.layout))))


@contextlib.asynccontextmanager
async def skin_bus(kind: str, skin: Skin60Device, pty: tuple[str, str] | None) -> AsyncIterator[BusConfig]:
    device = [array_device(skin.array, "skin", bench=False)]
    if kind in SERIAL_KINDS:
        assert pty is not None
        client = kind.removeprefix("rtu-")
        async with serve_skin60_serial(skin, pty[1], BAUD, line_timing=True, tick_s=None):
            yield bus_config_for(
                "line", "rtu", device, serial_port=pty[0], baudrate=BAUD, timeout_s=1.0, serial_client=client
            )
    else:
        framer = "rtu" if kind == "rtu-over-tcp" else "socket"
        async with serve_skin60_tcp(skin, framer=framer, tick_s=None) as server:
            yield bus_config_for("net", kind, device, host="127.0.0.1", port=server.port, timeout_s=1.0)


@pytest.fixture(params=["tcp", "rtu-over-tcp", "rtu-pymodbus", "rtu-direct"])
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def pty(kind: str, request: pytest.FixtureRequest) -> tuple[str, str] | None:
    return request.getfixturevalue("pty_pair") if kind in SERIAL_KINDS else None  # type: ignore[no-any-return]


async def test_reads_60_points_switches_to_mn_and_zeroes(kind: str, pty: tuple[str, str] | None) -> None:
    skin = loaded_skin(3.0)
    async with skin_bus(kind, skin, pty) as bus, open_transport(bus) as transport:
        counts = await transport.read_vendor(1, SKIN, 0, N_POINTS)
        # the sensors creep under the load: the device's counts move by a few between reads
        assert np.max(np.abs(np.array(counts) - skin.points())) <= 5
        assert all(300 < c < 4095 for c in counts), counts
        assert skin.requests == [Skin60Request(0x42, 0, N_POINTS)]

        await transport.write_register(1, HR_OUTPUT_MODE, 1, allow_write=True)
        force_mn = await transport.read_vendor(1, SKIN, 0, N_POINTS)
        expected = skin.force_mn(np.array(counts))  # each point's table at the counts read
        np.testing.assert_allclose(force_mn, expected, rtol=0.02)
        assert np.all(np.abs(np.array(force_mn) - counts) > 500), (force_mn, counts)
        assert await transport.read_holding_registers(1, HR_OUTPUT_MODE, 1) == [1]

        await transport.write_register(1, HR_DYNAMIC_ZERO, 1, allow_write=True)
        zeroed = await transport.read_vendor(1, SKIN, 0, N_POINTS)
        tail = await transport.read_vendor(1, SKIN, 50, 10)
        # loaded points of about 3000 mN now read 0 but for the creep since the zero (mN)
        assert max(zeroed) <= 30 and max(tail) <= 30 and min(force_mn) > 1000, (zeroed, tail)
    assert skin.requests == [
        Skin60Request(0x42, 0, N_POINTS),
        Skin60Request(6, HR_OUTPUT_MODE, 1, (1,)),
        Skin60Request(0x42, 0, N_POINTS),
        Skin60Request(3, HR_OUTPUT_MODE, 1),
        Skin60Request(6, HR_DYNAMIC_ZERO, 1, (1,)),
        Skin60Request(0x42, 0, N_POINTS),
        Skin60Request(0x42, 50, 10),
    ]


async def test_reads_write_nothing_and_exceptions_map(kind: str, pty: tuple[str, str] | None) -> None:
    skin = loaded_skin(2.0)
    async with skin_bus(kind, skin, pty) as bus, open_transport(bus) as transport:
        for _ in range(3):
            assert len(await transport.read_vendor(1, SKIN, 0, N_POINTS)) == N_POINTS
        with pytest.raises(DeviceExceptionResponse, match="exception 1 \\(illegal function\\)") as info:
            await transport.read_vendor(1, VendorRead(0x43), 0, N_POINTS)
        assert info.value.exception_code == 1
        with pytest.raises(DeviceExceptionResponse) as info:
            await transport.read_vendor(1, SKIN, 50, 20)
        assert info.value.exception_code == 2
        with pytest.raises(DeviceExceptionResponse) as info:
            await transport.read_holding_registers(1, HR_DYNAMIC_ZERO, 1)  # write-only
        assert info.value.exception_code == 2
        # the line is still usable after the exceptions
        assert len(await transport.read_vendor(1, SKIN, 0, N_POINTS)) == N_POINTS
    assert not any(r.is_write for r in skin.requests)
    assert [(r.function_code, r.address) for r in skin.requests] == [
        (0x42, 0),
        (0x42, 0),
        (0x42, 0),
        (0x43, 0),
        (0x42, 50),
        (3, HR_DYNAMIC_ZERO),
        (0x42, 0),
    ]
    assert skin.output_mode == 0 and skin.zero is None
