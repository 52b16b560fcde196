"""Vendor reads and single-register writes on the virtual bus, and the template methods' checks."""

from __future__ import annotations

import pytest

from gateway.errors import DecodeError, DeviceExceptionResponse, GatewayError, WriteNotAllowedError
from gateway.modbus.vendor_fc import VendorRead
from gateway.modbus.virtual import VirtualDevice, VirtualTransport

SKIN = VendorRead(0x42)


def bus() -> tuple[VirtualTransport, VirtualDevice]:
    device = VirtualDevice()
    device.set_vendor_image(0x42, list(range(100, 160)))
    device.set_holding(0, [0x5360, 60, 0])
    return VirtualTransport("line", {1: device}, timeout_s=0.2), device


async def test_vendor_read_answers_the_image_and_is_logged() -> None:
    vt, _ = bus()
    async with vt:
        assert await vt.read_vendor(1, SKIN, 0, 60) == list(range(100, 160))
        assert await vt.read_vendor(1, SKIN, 58, 2) == [158, 159]
    assert vt.requests == [("vendor 0x42", 1, 0, 60), ("vendor 0x42", 1, 58, 2)]
    assert vt.writes == []


async def test_unknown_code_is_exception_1_and_out_of_range_exception_2() -> None:
    vt, _ = bus()
    async with vt:
        with pytest.raises(DeviceExceptionResponse, match="illegal function") as info:
            await vt.read_vendor(1, VendorRead(0x43), 0, 60)
        assert info.value.exception_code == 1
        with pytest.raises(DeviceExceptionResponse, match="illegal data address") as info:
            await vt.read_vendor(1, SKIN, 50, 20)
        assert info.value.exception_code == 2
    assert vt.requests == [("vendor 0x43", 1, 0, 60), ("vendor 0x42", 1, 50, 20)]


async def test_a_handler_decides_the_answer() -> None:
    vt, device = bus()
    device.vendor[0x64] = lambda address, count: [address] * count
    async with vt:
        assert await vt.read_vendor(1, VendorRead(0x64), 7, 3) == [7, 7, 7]


async def test_short_answer_and_scripted_faults_map_as_for_register_reads() -> None:
    vt, _ = bus()
    async with vt:
        vt.fail_next("short")
        with pytest.raises(DecodeError, match="asked for 60 words, got 59"):
            await vt.read_vendor(1, SKIN, 0, 60)
        vt.fail_next(("exception", 4))
        with pytest.raises(DeviceExceptionResponse) as info:
            await vt.read_vendor(1, SKIN, 0, 60)
        assert info.value.exception_code == 4


async def test_argument_checks_send_nothing() -> None:
    vt, _ = bus()
    async with vt:
        with pytest.raises(GatewayError, match=r"word count 126 outside 1..125"):
            await vt.read_vendor(1, SKIN, 0, 126)
        with pytest.raises(GatewayError, match="does not fit"):
            await vt.read_vendor(1, VendorRead(0x42, address_bytes=1), 300, 1)
        with pytest.raises(GatewayError, match="device id 248"):
            await vt.read_vendor(248, SKIN, 0, 1)
    assert vt.requests == []


async def test_write_register_is_function_6_and_logged_with_its_value() -> None:
    vt, device = bus()
    async with vt:
        await vt.write_register(1, 2, 1, allow_write=True)
        assert await vt.read_holding_registers(1, 2, 1) == [1]
    assert device.holding[2] == 1
    assert vt.requests == [("write_single", 1, 2, 1), ("holding", 1, 2, 1)]
    assert vt.writes == [(1, 2, (1,))]


async def test_write_register_refused_sends_nothing() -> None:
    vt, device = bus()
    async with vt:
        with pytest.raises(WriteNotAllowedError, match="allow_write"):
            await vt.write_register(1, 2, 1, allow_write=False)
        with pytest.raises(GatewayError, match=r"outside 0\.\.65535"):
            await vt.write_register(1, 2, 65536, allow_write=True)
    assert vt.requests == [] and vt.writes == []
    assert device.holding[2] == 0


async def test_write_registers_are_logged_with_values() -> None:
    vt, _ = bus()
    async with vt:
        await vt.write_registers(1, 0, [5, 6], allow_write=True)
    assert vt.writes == [(1, 0, (5, 6))]
