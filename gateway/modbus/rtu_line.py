"""The direct RTU backend: the gateway's own Modbus RTU framing on a serial port, for fast lines.

A ``transport.Transport`` (``serial_client = "direct"`` on a ``kind = "rtu"`` bus) that writes
each request's bytes straight to the port and reads the answer from it, with nothing between
the two but the framing the Modbus serial-line specification (V1.02) gives: address, PDU,
CRC-16/MODBUS (low byte first). It exists for lines polled thousands of times a second (a
60-point skin at 4,000,000 baud): there, pymodbus' client (``client.ModbusTransport``, the
default) spends more CPU between an answer and the next request than the line takes to
carry the frame, and the gateway falls well behind a vendor SDK's bare loop on the same
port. The template methods of ``Transport`` (the lock, the checks, the error mapping) are the
same for both; only the bytes are handled here.

How one request goes:

* whatever is waiting on the port is dropped first: RTU frames carry no transaction id, so
  a late answer to an earlier request (given up after its timeout) would otherwise be taken
  for this one's;
* the request (address, function code, data, CRC) is written at once (a serial line carries
  one request at a time);
* the answer is read as it arrives (``loop.add_reader``); its length follows from its first
  bytes (``answer_size``): an exception answer is 5 bytes; functions 3 and 4 (and vendor
  reads) state a byte count; 6 and 16 echo 8 bytes; 43/14 lists its objects with their
  lengths. Once complete it is checked: CRC, device address, function code, and what the
  function's answer must hold;
* no complete answer within ``timeout_s`` -> ``DeviceTimeoutError`` when nothing came back,
  ``DecodeError`` (garbled) when bytes came but no valid frame; a bad CRC or a wrong device
  address -> ``DecodeError`` at once; a device exception -> ``DeviceExceptionResponse``; the
  port failing -> ``DeviceConnectionError`` (and the bus reconnects).

Bytes that arrive when no request is outstanding are dropped. Functions: 3, 4, 6, 16, 43/14
and vendor-defined reads (``vendor_fc.VendorRead``). Pure stdlib and pyserial, which opens
and configures the port (baud rate, parity, stop bits); the reading and writing use the
file descriptor directly and never block the event loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import struct
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import serial

from ..errors import DecodeError, DeviceConnectionError, DeviceExceptionResponse, DeviceTimeoutError
from .endpoint import Endpoint
from .register_map import RegisterKind
from .transport import (
    DEVICE_ID_OBJECTS,
    EXCEPTION_NAMES,
    FC_DEVICE_ID,
    FC_WRITE_MULTIPLE,
    FC_WRITE_SINGLE,
    Transport,
)
from .vendor_fc import VendorRead

__all__ = ["RtuLineTransport", "adu", "answer_size", "crc16_modbus"]

log = logging.getLogger(__name__)

MEI_DEVICE_ID = 0x0E  # the MEI type of read device identification (function 43)

#: Readiness without data this many times in a row: the port is gone (pyserial's view too).
EMPTY_READS_LOST = 3


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS of ``data`` (polynomial 0x8005 reflected, initial 0xFFFF); on the wire
    low byte first. ``crc16_modbus(b"123456789") == 0x4B37`` (the catalogue's check value)."""
    crc = 0xFFFF
    table = _CRC_TABLE
    for b in data:
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def adu(device_id: int, pdu: bytes) -> bytes:
    """The RTU frame of ``pdu`` (function code and data) for ``device_id``: address, PDU, CRC."""
    body = bytes((device_id,)) + pdu
    return body + struct.pack("<H", crc16_modbus(body))


#: The answer's length after address and function code, from its first bytes, for a function.
SizeRule = Callable[[bytes], int | None]


def _byte_count_rule(data: bytes) -> int | None:
    """Functions 3 and 4: a 1-byte byte count, then that many bytes."""
    return None if not data else 1 + data[0]


def _echo_rule(data: bytes) -> int | None:
    """Functions 6 and 16: address and value (or count), 4 bytes."""
    return 4


def _device_id_rule(data: bytes) -> int | None:
    """Function 43/14: MEI type, read code, conformity, more follows, next id, object count,
    then per object its id, its length and that many bytes."""
    if len(data) < 6:
        return None
    size, objects = 6, data[5]
    for _ in range(objects):
        if len(data) < size + 2:
            return None
        size += 2 + data[size + 1]
    return size


def answer_size(function_code: int, rule: SizeRule, frame: bytes | bytearray) -> int | None:
    """The whole RTU answer's length (bytes, CRC included) from its first bytes ``frame``
    (address first), for a request of ``function_code`` whose normal answer's length after
    address and function code ``rule`` tells; None while too few bytes have come."""
    if len(frame) < 2:
        return None
    if frame[1] == function_code | 0x80:
        return 5  # address, function | 0x80, exception code, CRC
    rest = rule(bytes(frame[2:]))
    return None if rest is None else 2 + rest + 2


class RtuLineTransport(Transport):
    """Modbus RTU on a serial port with the gateway's own framing (see the module docstring)."""

    bounds_own_wait: ClassVar[bool] = True
    values_are_16_bit: ClassVar[bool] = True

    def __init__(self, bus: Endpoint, *, serial_factory: Callable[..., Any] = serial.Serial) -> None:
        super().__init__(bus.name, bus.timeout_s)
        self.bus = bus
        self._serial_factory = serial_factory
        self._port: Any = None
        self._fd = -1
        self._buffer = bytearray()
        self._waiter: asyncio.Future[bytes] | None = None
        self._expect: tuple[int, int, SizeRule] | None = None  # device id, function, size rule
        self._loop: asyncio.AbstractEventLoop | None = None
        self._vendor_requests: dict[tuple[VendorRead, int, int], tuple[bytes, SizeRule]] = {}
        self._empty_reads = 0
        #: request frames already built (a poll repeats the same few): (device id, PDU) -> frame
        self._frames: dict[tuple[int, bytes], bytes] = {}

    # ------------------------------------------------------------------ connection
    @property
    def target(self) -> str:
        return f"{self.bus.serial_port} ({self.bus.baudrate} baud)"

    @property
    def connected(self) -> bool:
        return self._port is not None

    @property
    def is_serial_framing(self) -> bool:
        return True

    @property
    def quiet_after_send_s(self) -> float:
        """The request's own time on the wire (8 bytes and 3.5 characters of silence) (s)."""
        b = self.bus
        bits_per_char = 1 + int(b.bytesize) + (0 if str(b.parity) == "N" else 1) + int(b.stopbits)
        return (8 + 3.5) * bits_per_char / float(b.baudrate)

    async def _connect(self) -> None:
        b = self.bus
        try:
            port = self._serial_factory(
                str(b.serial_port),
                baudrate=int(b.baudrate),
                bytesize=int(b.bytesize),
                parity=str(b.parity),
                stopbits=int(b.stopbits),
                timeout=0,
                write_timeout=0,
                exclusive=True,
            )
        except (OSError, ValueError) as exc:  # pyserial's SerialException is an OSError
            raise DeviceConnectionError(f"bus {self.name!r}: cannot open {self.target}: {exc}") from exc
        self._port = port
        self._fd = int(port.fileno())
        self._loop = asyncio.get_running_loop()
        with contextlib.suppress(OSError, ValueError):
            port.reset_input_buffer()  # a late answer to an earlier connection's request
        self._buffer.clear()
        self._empty_reads = 0
        self._loop.add_reader(self._fd, self._on_readable)

    async def _close(self) -> None:
        port, self._port = self._port, None
        if port is None:
            return
        if self._loop is not None and self._fd >= 0:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._fd)
        self._fd = -1
        self._fail(DeviceConnectionError(f"bus {self.name!r}: connection to {self.target} closed"))
        with contextlib.suppress(Exception):
            port.close()

    # ------------------------------------------------------------------ the line
    def _on_readable(self) -> None:
        try:
            data = os.read(self._fd, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            self._lost(exc)
            return
        if not data:
            # once: the port was emptied (``_drain``) after the loop saw it readable; again and
            # again: the line is gone (a tty hung up reads as end of file)
            self._empty_reads += 1
            if self._empty_reads > EMPTY_READS_LOST:
                self._lost(EOFError("the port reports readiness but returns no data"))
            return
        self._empty_reads = 0
        waiter = self._waiter
        if waiter is None or waiter.done():
            return  # nobody asked: a late answer, dropped
        buffer = self._buffer
        buffer += data
        expect = self._expect
        assert expect is not None
        size = answer_size(expect[1], expect[2], buffer)
        if size is not None and len(buffer) >= size:
            frame = bytes(buffer[:size])
            buffer.clear()
            waiter.set_result(frame)

    def _lost(self, exc: BaseException) -> None:
        """The port failed: fail the outstanding request, stop reading, mark the bus down."""
        if self._loop is not None and self._fd >= 0:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._fd)
        port, self._port, self._fd = self._port, None, -1
        self._fail(DeviceConnectionError(f"connection to {self.target} lost: {exc}"))
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()

    def _fail(self, exc: BaseException) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_exception(exc)

    def _drain(self) -> None:
        """Drop what waits on the port now (a late answer to a request given up)."""
        self._buffer.clear()
        with contextlib.suppress(BlockingIOError):
            while len(os.read(self._fd, 4096)) == 4096:
                pass

    async def _transact(self, device_id: int, pdu: bytes, rule: SizeRule, what: str) -> bytes:
        """Send ``pdu`` to ``device_id`` and return the checked answer's PDU (function code
        and data); a device exception raises ``DeviceExceptionResponse``."""
        if self._port is None or self._loop is None:
            raise DeviceConnectionError(f"{what}: not connected to {self.target}")
        function_code = pdu[0]
        loop = self._loop
        try:
            self._drain()
            waiter: asyncio.Future[bytes] = loop.create_future()
            self._waiter, self._expect = waiter, (device_id, function_code, rule)
            request = self._frames.get((device_id, pdu))
            if request is None:
                if len(self._frames) >= 256:
                    self._frames.clear()
                request = self._frames[(device_id, pdu)] = adu(device_id, pdu)
            written = os.write(self._fd, request)
            if written != len(request):  # a serial driver takes a short request at once
                raise DeviceConnectionError(f"{what}: wrote {written} of {len(request)} bytes")
        except OSError as exc:
            self._lost(exc)
            raise DeviceConnectionError(f"{what}: {self.target}: {exc}") from exc
        timer = loop.call_later(self.timeout_s, self._time_out, waiter, what)
        try:
            frame = await waiter
        finally:
            timer.cancel()
            self._waiter = self._expect = None
        return self._check(frame, device_id, function_code, what)

    def _time_out(self, waiter: asyncio.Future[bytes], what: str) -> None:
        if waiter.done():
            return
        if self._buffer:
            self._buffer.clear()
            waiter.set_exception(
                DecodeError(f"{what}: garbled answer from {self.target} (bytes but no valid frame)")
            )
        else:
            waiter.set_exception(
                DeviceTimeoutError(f"{what}: no answer from {self.target} within {self.timeout_s:g} s")
            )

    def _check(self, frame: bytes, device_id: int, function_code: int, what: str) -> bytes:
        body, crc = frame[:-2], frame[-2] | frame[-1] << 8
        if crc16_modbus(body) != crc:
            raise DecodeError(f"{what}: answer from {self.target} fails its CRC")
        if body[0] != device_id:
            raise DecodeError(f"{what}: answer from device {body[0]}, expected {device_id}")
        if body[1] == function_code | 0x80:
            code = body[2]
            name = EXCEPTION_NAMES.get(code, "unknown exception")
            raise DeviceExceptionResponse(f"{what}: device answered exception {code} ({name})", code)
        if body[1] != function_code:
            raise DecodeError(f"{what}: answer has function {body[1]}, expected {function_code}")
        return body[1:]

    # ------------------------------------------------------------------ requests
    async def _read(
        self, kind: RegisterKind, device_id: int, address: int, count: int, what: str
    ) -> Sequence[int]:
        fc = kind.read_function
        pdu = await self._transact(device_id, struct.pack(">BHH", fc, address, count), _byte_count_rule, what)
        if pdu[1] != len(pdu) - 2 or pdu[1] != 2 * count:
            raise DecodeError(f"{what}: answer of {pdu[1]} bytes, expected {2 * count}")
        return struct.unpack_from(f">{count}H", pdu, 2)

    async def _write(self, device_id: int, address: int, values: list[int], what: str) -> None:
        n = len(values)
        request = struct.pack(f">BHHB{n}H", FC_WRITE_MULTIPLE, address, n, 2 * n, *values)
        pdu = await self._transact(device_id, request, _echo_rule, what)
        if pdu[1:5] != request[1:5]:
            raise DecodeError(f"{what}: the device confirmed {pdu[1:5].hex()}, expected {request[1:5].hex()}")

    async def _write_single(self, device_id: int, address: int, value: int, what: str) -> None:
        request = struct.pack(">BHH", FC_WRITE_SINGLE, address, value)
        pdu = await self._transact(device_id, request, _echo_rule, what)
        if pdu != request:
            raise DecodeError(f"{what}: the device echoed {pdu.hex()}, expected {request.hex()}")

    async def _read_vendor(
        self, read: VendorRead, device_id: int, address: int, count: int, what: str
    ) -> Sequence[int]:
        key = (read, address, count)
        known = self._vendor_requests.get(key)
        if known is None:
            pdu = bytes((read.function_code,)) + read.request_data(address, count)
            known = self._vendor_requests[key] = (pdu, read.response_size)
        request, rule = known
        pdu = await self._transact(device_id, request, rule, what)
        try:
            return read.registers(pdu[1:], count)
        except DecodeError as exc:
            raise DecodeError(f"{what}: invalid answer from {self.target}: {exc}") from exc

    async def _read_device_identification(self, device_id: int, what: str) -> dict[str, str]:
        info: dict[str, str] = {}
        object_id = 0
        for _ in range(8):  # "more follows" continuation, bounded
            request = bytes((FC_DEVICE_ID, MEI_DEVICE_ID, 0x02, object_id))
            pdu = await self._transact(device_id, request, _device_id_rule, what)
            if pdu[1] != MEI_DEVICE_ID:
                raise DecodeError(f"{what}: answer has MEI type {pdu[1]}")
            more, next_id, objects = pdu[4], pdu[5], pdu[6]
            at = 7
            for _ in range(objects):
                key, length = pdu[at], pdu[at + 1]
                value = pdu[at + 2 : at + 2 + length]
                name = DEVICE_ID_OBJECTS.get(key, f"object_{key:#04x}")
                info[name] = value.decode("utf-8", errors="replace")
                at += 2 + length
            if not more:
                break
            object_id = next_id
        return info
