"""The transport template methods: checks, timeouts and error mapping, on the virtual bus
and on minimal backends that fail in the ways real ones do."""

from __future__ import annotations

import asyncio
import re
from collections.abc import Sequence

import pytest

from gateway.errors import (
    DecodeError,
    DeviceConnectionError,
    DeviceExceptionResponse,
    DeviceTimeoutError,
    GatewayError,
    WriteNotAllowedError,
)
from gateway.modbus.transport import Transport
from gateway.modbus.virtual import VirtualDevice, VirtualTransport


def bus() -> VirtualTransport:
    device = VirtualDevice(identification={"VendorName": "ACME"})
    device.set_input(100, [10, 20, 30, 40])
    device.set_holding(0, [16])
    return VirtualTransport("line", {1: device}, timeout_s=0.2)


async def test_reads_answer_the_image_and_are_logged() -> None:
    vt = bus()
    async with vt:
        assert await vt.read_input_registers(1, 100, 4) == [10, 20, 30, 40]
        assert await vt.read_holding_registers(1, 0, 1) == [16]
        assert await vt.read_device_identification(1) == {"VendorName": "ACME"}
    assert vt.requests == [("input", 1, 100, 4), ("holding", 1, 0, 1), ("identification", 1, 0, 0)]
    assert not vt.connected


@pytest.mark.parametrize(
    ("fault", "error", "message"),
    [
        ("timeout", DeviceTimeoutError, "no answer from virtual bus 'line' within 0.2 s"),
        ("garbled", DecodeError, "garbled answer"),
        ("short", DecodeError, "asked for 4 registers, got 3"),
        (("exception", 6), DeviceExceptionResponse, "exception 6 (server device busy)"),
        ("disconnect", DeviceConnectionError, "connection to virtual bus 'line' lost"),
    ],
)
async def test_each_fault_becomes_its_typed_error(
    fault: object, error: type[Exception], message: str
) -> None:
    vt = bus()
    async with vt:
        vt.fail_next(fault)  # type: ignore[arg-type]
        with pytest.raises(error, match=re.escape(message)):
            await vt.read_input_registers(1, 100, 4)
        if fault == "disconnect":
            with pytest.raises(DeviceConnectionError, match="not connected"):
                await vt.read_input_registers(1, 100, 4)
        else:
            assert await vt.read_input_registers(1, 100, 4) == [10, 20, 30, 40]  # one request only


async def test_an_unmapped_address_is_exception_2_and_an_absent_device_times_out() -> None:
    vt = bus()
    async with vt:
        with pytest.raises(DeviceExceptionResponse, match="illegal data address") as info:
            await vt.read_input_registers(1, 102, 4)
        assert info.value.exception_code == 2
        with pytest.raises(DeviceTimeoutError):
            await vt.read_input_registers(7, 100, 1)


@pytest.mark.parametrize(
    ("device_id", "address", "count", "message"),
    [
        (1, 100, 0, "register count 0 outside 1..125"),
        (1, 100, 126, "register count 126 outside 1..125"),
        (1, 65535, 2, "register range 65535..65536 outside 0..65535"),
        (248, 100, 1, "device id 248 outside 0..247"),
    ],
)
async def test_requests_outside_the_protocol_are_refused_before_sending(
    device_id: int, address: int, count: int, message: str
) -> None:
    vt = bus()
    async with vt:
        with pytest.raises(GatewayError, match=re.escape(message)):
            await vt.read_input_registers(device_id, address, count)
    assert vt.requests == []


async def test_a_write_is_refused_unless_allowed_and_nothing_is_sent() -> None:
    vt = bus()
    async with vt:
        with pytest.raises(WriteNotAllowedError, match="allow_write = true"):
            await vt.write_registers(1, 0, [5], allow_write=False)
        assert vt.requests == []
        with pytest.raises(GatewayError, match=re.escape("0..65535")):
            await vt.write_registers(1, 0, [70000], allow_write=True)
        await vt.write_registers(1, 0, [5], allow_write=True)
    assert vt.devices[1].holding[0] == 5


async def test_a_refused_connection_is_a_connection_error() -> None:
    vt = bus()
    vt.refuse_connects = 1
    with pytest.raises(
        DeviceConnectionError, match=re.escape("cannot connect to virtual bus 'line': connection refused")
    ):
        await vt.connect()
    assert not vt.connected
    await vt.connect()
    assert vt.connected and vt.connects == 2
    await vt.close()


class Raising(Transport):
    """A backend whose reads raise ``exc`` (or hang when it is None)."""

    def __init__(self, exc: BaseException | None, registers: Sequence[int] = ()) -> None:
        super().__init__("raw", timeout_s=0.05)
        self.exc, self.registers, self._up = exc, list(registers), False

    @property
    def target(self) -> str:
        return "raw target"

    @property
    def connected(self) -> bool:
        return self._up

    async def _connect(self) -> None:
        self._up = True

    async def _close(self) -> None:
        self._up = False

    async def _read(self, kind: str, device_id: int, address: int, count: int, what: str) -> Sequence[int]:
        if self.exc is None and not self.registers:
            await asyncio.Event().wait()  # never answers: the template's timer must end it
        if self.exc is not None:
            raise self.exc
        return self.registers

    async def _write(self, device_id: int, address: int, values: list[int], what: str) -> None:
        raise NotImplementedError

    async def _read_device_identification(self, device_id: int, what: str) -> dict[str, str]:
        raise NotImplementedError


@pytest.mark.parametrize(
    ("backend", "error", "message"),
    [
        (Raising(None), DeviceTimeoutError, "no answer from raw target within 0.05 s"),
        (Raising(ConnectionResetError("reset by peer")), DeviceConnectionError, "lost: reset by peer"),
        (Raising(OSError("bad file descriptor")), DeviceConnectionError, "lost: bad file descriptor"),
        (
            Raising(ValueError("frame too short")),
            DecodeError,
            "invalid response from raw target: frame too short",
        ),
        (Raising(None, [1, 70000]), DecodeError, "a register value outside 0..65535"),
        (Raising(None, [1, 2, 3]), DecodeError, "asked for 2 registers, got 3"),
    ],
)
async def test_the_template_maps_what_any_backend_raises(
    backend: Raising, error: type[Exception], message: str
) -> None:
    async with backend:
        with pytest.raises(error, match=re.escape(message)):
            await backend.read_input_registers(1, 0, 2)
