"""The direct RTU backend (``rtu_line.RtuLineTransport``, ``serial_client = "direct"``) against a
device the test plays itself on a socat pty pair, 115200 baud.

The test holds the device end of the line: it reads the request bytes the gateway wrote,
compares them with frames built by hand (address, PDU, CRC-16/MODBUS low byte first: the
CRC computed bit by bit here, or the well-known frames of the Modbus literature), and
writes crafted answers: right ones, a wrong CRC, another device's, an exception, none, half
of one, one in three pieces, a late one to an earlier request, wrong echoes, a vendor read
and a device identification. Each outcome is the value or the exact typed error.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import os
import select
import struct
import termios
import time
from collections.abc import AsyncIterator

import pytest
from waiting import until

from gateway.config import bus_config_for, device_config_for
from gateway.errors import DecodeError, DeviceExceptionResponse, DeviceTimeoutError
from gateway.modbus.backends import open_transport
from gateway.modbus.endpoint import Endpoint
from gateway.modbus.rtu_line import RtuLineTransport
from gateway.modbus.vendor_fc import VendorRead
from gateway.model import SensorParams

BAUD = 115200
#: How long a test waits for the gateway's request on the device end (a backstop, s).
REQUEST_WITHIN_S = 5.0


def crc(data: bytes) -> bytes:
    """CRC-16/MODBUS of ``data`` bit by bit (polynomial 0xA001 reflected, initial 0xFFFF), as
    it goes on the wire: low byte first."""
    value = 0xFFFF
    for byte in data:
        value ^= byte
        for _ in range(8):
            value = (value >> 1) ^ 0xA001 if value & 1 else value >> 1
    return value.to_bytes(2, "little")


def framed(hex_body: str) -> bytes:
    """The RTU frame of the address and PDU written in hex: the body and its CRC."""
    body = bytes.fromhex(hex_body)
    return body + crc(body)


def registers_answer(device_id: int, function_code: int, words: list[int]) -> bytes:
    body = bytes((device_id, function_code, 2 * len(words))) + b"".join(w.to_bytes(2, "big") for w in words)
    return body + crc(body)


class Device:
    """The device end of the line, played by the test: a non-blocking file descriptor."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

    def close(self) -> None:
        os.close(self.fd)

    async def receive(self, size: int) -> bytes:
        """What the gateway wrote, once at least ``size`` bytes are in (all that came)."""
        data = bytearray()
        deadline = time.monotonic() + REQUEST_WITHIN_S
        while len(data) < size:
            try:
                chunk = os.read(self.fd, 4096)
            except BlockingIOError:
                chunk = b""  # (a tty with VMIN = 0 reads b"" instead)
            if chunk:
                data += chunk
                continue
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no request of {size} bytes (got {data.hex()})")
            await self._readable(left)
        return bytes(data)

    async def _readable(self, timeout_s: float) -> None:
        """Until the device's end of the line has bytes to read (or ``timeout_s`` passes)."""
        loop = asyncio.get_running_loop()
        ready = asyncio.Event()
        loop.add_reader(self.fd, ready.set)
        try:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(ready.wait(), timeout_s)
        finally:
            loop.remove_reader(self.fd)

    def send(self, data: bytes) -> None:
        assert os.write(self.fd, data) == len(data)


@contextlib.asynccontextmanager
async def line(
    pty_pair: tuple[str, str], timeout_s: float, transport_class: type[RtuLineTransport] | None = None
) -> AsyncIterator[tuple[RtuLineTransport, Device]]:
    """The gateway's direct RTU transport on one end of the pty pair (connected), the test's
    device on the other."""
    gw_port, dev_port = pty_pair
    device_config = device_config_for("arr", 1, [SensorParams()] * 4, 2, 2.5, allow_write=True)
    bus = bus_config_for(
        "line",
        "rtu",
        [device_config],
        serial_port=gw_port,
        baudrate=BAUD,
        timeout_s=timeout_s,
        serial_client="direct",
    )
    transport = open_transport(bus) if transport_class is None else transport_class(bus)
    assert isinstance(transport, RtuLineTransport)  # serial_client = "direct"
    device = Device(dev_port)
    try:
        async with transport:
            yield transport, device
    finally:
        device.close()


def bytes_waiting(fd: int) -> int:
    """Bytes the kernel holds for ``fd`` (not yet read)."""
    return int(struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0])


# ---------------------------------------------------------------------------- reads


async def test_a_function_4_answer_gives_the_registers(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        request = await device.receive(8)
        # read 2 input registers from 0 of device 1: 01 04 0000 0002, CRC 0xCB71
        assert request == bytes.fromhex("01 04 00 00 00 02 71 CB")
        device.send(bytes.fromhex("01 04 04 00 0A 01 02") + crc(bytes.fromhex("01 04 04 00 0A 01 02")))
        assert await task == [10, 0x0102]


async def test_a_function_3_read_of_ten_holding_registers(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.read_holding_registers(1, 0, 10))
        assert await device.receive(8) == bytes.fromhex("01 03 00 00 00 0A C5 CD")
        words = [0, 1, 0xFFFF, 0x8000, 0x7FFF, 0x1234, 0xABCD, 2, 3, 65534]
        device.send(registers_answer(1, 3, words))
        assert await task == words


async def test_an_answer_with_a_wrong_crc_is_a_decode_error_at_once(pty_pair: tuple[str, str]) -> None:
    timeout_s = 3.0
    async with line(pty_pair, timeout_s=timeout_s) as (transport, device):
        task = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        answer = bytearray(registers_answer(1, 4, [10, 0x0102]))
        answer[-1] ^= 0x01  # the CRC's high byte, one bit off
        t0 = time.monotonic()
        device.send(bytes(answer))
        with pytest.raises(DecodeError, match="fails its CRC"):
            await task
        assert time.monotonic() - t0 < 0.5 * timeout_s, "the CRC error waited for the timeout"


async def test_an_answer_from_another_device_is_a_decode_error(pty_pair: tuple[str, str]) -> None:
    timeout_s = 3.0
    async with line(pty_pair, timeout_s=timeout_s) as (transport, device):
        task = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        t0 = time.monotonic()
        device.send(registers_answer(2, 4, [10, 0x0102]))  # a valid frame, but of device 2
        with pytest.raises(DecodeError, match="answer from device 2, expected 1"):
            await task
        assert time.monotonic() - t0 < 0.5 * timeout_s


async def test_an_answer_to_another_function_is_a_decode_error(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        device.send(registers_answer(1, 3, [10, 0x0102]))  # function 3's answer to function 4
        try:
            values = await task
        except DecodeError:
            return
        raise AssertionError(f"a function-3 answer was taken for the function-4 answer: {values}")


async def test_an_exception_answer_is_a_device_exception_with_its_code(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=3.0) as (transport, device):
        task = asyncio.create_task(transport.read_input_registers(1, 0x100, 2))
        assert await device.receive(8) == framed("010401000002")
        device.send(framed("018402"))  # function 4 | 0x80, exception 2
        with pytest.raises(DeviceExceptionResponse, match=r"exception 2 \(illegal data address\)") as info:
            await task
        assert info.value.exception_code == 2


async def test_no_answer_is_a_timeout(pty_pair: tuple[str, str]) -> None:
    timeout_s = 0.2
    async with line(pty_pair, timeout_s=timeout_s) as (transport, device):
        t0 = time.monotonic()
        task = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        with pytest.raises(DeviceTimeoutError, match=r"no answer from .* within 0\.2 s"):
            await task
        assert time.monotonic() - t0 >= timeout_s - 0.01


async def test_half_an_answer_then_silence_is_a_garbled_answer(pty_pair: tuple[str, str]) -> None:
    timeout_s = 0.2
    async with line(pty_pair, timeout_s=timeout_s) as (transport, device):
        t0 = time.monotonic()
        task = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        device.send(registers_answer(1, 4, [10, 0x0102])[:4])  # 4 of its 9 bytes
        with pytest.raises(DecodeError, match="garbled answer"):
            await task
        assert time.monotonic() - t0 >= timeout_s - 0.01


async def test_an_answer_in_three_pieces_is_read_whole(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=2.0) as (transport, device):
        task = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        answer = registers_answer(1, 4, [0xBEEF, 7])
        # each piece is in the gateway's buffer before the next goes out: three separate reads
        device.send(answer[:2])  # address and function: the length is not known yet
        await until(lambda: len(transport._buffer) == 2, 2.0, "the first 2 bytes", step_s=0.001)
        device.send(answer[2:5])  # byte count and the first data byte
        await until(lambda: len(transport._buffer) == 5, 2.0, "the next 3 bytes", step_s=0.001)
        assert not task.done()
        device.send(answer[5:])  # the rest and the CRC
        assert await task == [0xBEEF, 7]


class CountsDroppedBytes(RtuLineTransport):
    """The direct transport, counting the bytes its reader finds while no request is out
    (which it drops): the test knows when a late answer has come and gone."""

    def __init__(self, bus: Endpoint) -> None:
        super().__init__(bus)
        self.dropped = 0

    def _on_readable(self) -> None:
        if self._waiter is None and self._fd >= 0:
            self.dropped += bytes_waiting(self._fd)
        super()._on_readable()


async def time_out_a_read(transport: RtuLineTransport, device: Device) -> bytes:
    """A read of 2 input registers from 0 of device 1 that the device does not answer in time;
    the answer it should have had (0xDEAD, 0xBEEF), for the test to send late."""
    first = asyncio.create_task(transport.read_input_registers(1, 0, 2))
    assert await device.receive(8) == framed("010400000002")
    with pytest.raises(DeviceTimeoutError):
        await first
    return registers_answer(1, 4, [0xDEAD, 0xBEEF])


async def test_a_late_answer_between_requests_is_not_the_next_answer(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=0.2, transport_class=CountsDroppedBytes) as (transport, device):
        assert isinstance(transport, CountsDroppedBytes)
        late = await time_out_a_read(transport, device)
        device.send(late)  # the first request's answer, after its timeout
        await until(lambda: transport.dropped >= len(late), 5.0, "the late answer", step_s=0.001)
        assert transport.dropped == len(late)
        second = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        device.send(registers_answer(1, 4, [1, 2]))
        assert await second == [1, 2]


async def test_a_late_answer_waiting_in_the_port_as_the_next_request_starts_is_dropped(
    pty_pair: tuple[str, str],
) -> None:
    async with line(pty_pair, timeout_s=0.2) as (transport, device):
        late = await time_out_a_read(transport, device)
        device.send(late)
        # the late answer is in the gateway's port before the next request starts (the event
        # loop is held meanwhile: its reader cannot take the bytes first); the request's drain
        # must drop it
        deadline = time.monotonic() + REQUEST_WITHIN_S
        while bytes_waiting(transport._fd) < len(late):
            assert time.monotonic() < deadline, "the late answer did not reach the gateway's port"
            select.select([], [], [], 0.001)
        second = asyncio.create_task(transport.read_input_registers(1, 0, 2))
        assert await device.receive(8) == framed("010400000002")
        device.send(registers_answer(1, 4, [1, 2]))
        assert await second == [1, 2]


# ---------------------------------------------------------------------------- writes


async def test_a_function_6_write_with_its_echo(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.write_register(1, 1, 3, allow_write=True))
        request = await device.receive(8)
        assert request == bytes.fromhex("01 06 00 01 00 03 98 0B")  # write register 1 = 3
        device.send(request)  # the echo
        await task  # no error: the answer was the expected one


async def test_a_function_6_write_with_a_wrong_echo_is_a_decode_error(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.write_register(1, 1, 3, allow_write=True))
        assert await device.receive(8) == bytes.fromhex("01 06 00 01 00 03 98 0B")
        device.send(framed("010600010004"))  # a valid frame echoing the value 4
        with pytest.raises(DecodeError, match="the device echoed 0600010004, expected 0600010003"):
            await task


async def test_a_function_16_write(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.write_registers(1, 1, [3, 0x1234], allow_write=True))
        # address, 0x10, start 1, 2 registers, 4 bytes, the values, CRC: 13 bytes
        assert await device.receive(13) == framed("01 10 0001 0002 04 0003 1234")
        device.send(framed("01 10 0001 0002"))  # start and count confirmed
        await task  # no error: the answer was the expected one


async def test_a_function_16_confirmation_of_another_count_is_a_decode_error(
    pty_pair: tuple[str, str],
) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.write_registers(1, 1, [3, 0x1234], allow_write=True))
        assert await device.receive(13) == framed("01 10 0001 0002 04 0003 1234")
        device.send(framed("01 10 0001 0001"))
        with pytest.raises(DecodeError, match="confirmed 00010001, expected 00010002"):
            await task


# ---------------------------------------------------------------------------- vendor, identification


async def test_a_vendor_read_of_four_words(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.read_vendor(1, VendorRead(0x42), 0, 4))
        # function 0x42, start 0 (2 bytes), count 4 (2 bytes): CRC 0x0678
        assert await device.receive(8) == bytes.fromhex("01 42 00 00 00 04 78 06")
        device.send(framed("01 42 08 0001 0203 FFFF 8000"))
        assert await task == [1, 0x0203, 0xFFFF, 0x8000]


async def test_device_identification_with_two_objects(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.read_device_identification(1))
        # 43/14, read code 2 (regular), from object 0: CRC 0x8770
        assert await device.receive(7) == bytes.fromhex("01 2B 0E 02 00 70 87")
        body = bytes.fromhex("01 2B 0E 02 01 00 00 02") + b"\x00\x04ACME" + b"\x01\x06AT-6x6"
        device.send(body + crc(body))
        assert await task == {"VendorName": "ACME", "ProductCode": "AT-6x6"}


async def test_device_identification_that_says_more_follows(pty_pair: tuple[str, str]) -> None:
    async with line(pty_pair, timeout_s=1.0) as (transport, device):
        task = asyncio.create_task(transport.read_device_identification(1))
        assert await device.receive(7) == framed("01 2B 0E 02 00")
        # more follows (0xFF), next object 1
        body = bytes.fromhex("01 2B 0E 02 01 FF 01 01") + b"\x00\x04ACME"
        device.send(body + crc(body))
        assert await device.receive(7) == framed("01 2B 0E 02 01")  # asks from object 1
        body = bytes.fromhex("01 2B 0E 02 01 00 00 01") + b"\x01\x06AT-6x6"
        device.send(body + crc(body))
        assert await task == {"VendorName": "ACME", "ProductCode": "AT-6x6"}
