"""The transport interface: a Modbus bus as the poller sees it (after python-can's ``BusABC``).

``Transport`` owns what every backend shares, as template methods: one request at a time
(a serial line is half duplex), argument checks, the per-request timeout, checking what came
back, and turning every failure into the gateway's typed errors (``gateway.errors``):

* no answer in time -> ``DeviceTimeoutError``;
* a connection that cannot be made or is lost (``ConnectionError``, ``OSError``) ->
  ``DeviceConnectionError``;
* an exception response -> ``DeviceExceptionResponse`` with the Modbus exception code;
* an answer of the wrong size or with values outside 0..65535 -> ``DecodeError``;
* a vendor-defined read (``read_vendor``, a ``vendor_fc.VendorRead``) that the device does
  not know -> ``DeviceExceptionResponse`` with code 1 (illegal function);
* a write the device configuration does not allow -> ``WriteNotAllowedError``, before
  anything is sent.

On serial framing (RTU: no transaction id, so a late answer to an earlier request can look
like the answer), a device identification whose answer cannot be used is asked once more
after a short quiet time (``read_device_identification``).

Requests: functions 3 and 4 (``read_holding_registers``, ``read_input_registers``), 6
(``write_register``), 16 (``write_registers``), 43/14 (``read_device_identification``) and
vendor-defined reads (``read_vendor``).

A backend implements the primitives ``_connect``, ``_close``, ``_read``, ``_write`` and
``_read_device_identification``, and ``_write_single`` and ``_read_vendor`` if it can send
functions 6 and vendor reads (the defaults refuse with a ``GatewayError``), and the
properties ``target`` and ``connected``; it may raise the typed errors itself where it
knows better (a garbled frame, an exception code). The pymodbus backend is
``client.ModbusTransport``; ``virtual.VirtualTransport`` is an in-process bus for fast
tests of everything above it.
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
import logging
from collections.abc import Sequence
from typing import ClassVar

from ..errors import (
    DecodeError,
    DeviceConnectionError,
    DeviceTimeoutError,
    GatewayError,
    ShortAnswerError,
    WriteNotAllowedError,
)
from .plan import ReadRequest
from .register_map import MAX_READ_REGISTERS, MAX_WRITE_REGISTERS, RegisterKind
from .vendor_fc import VendorRead

log = logging.getLogger(__name__)


#: Modbus function codes the backends send (the reads: ``RegisterKind.read_function``).
FC_WRITE_SINGLE = 0x06
FC_WRITE_MULTIPLE = 0x10
FC_DEVICE_ID = 0x2B  # encapsulated interface (MEI); type 14: read device identification

#: Read Device Identification object ids (MEI type 14) by the names the backends report.
DEVICE_ID_OBJECTS: dict[int, str] = {
    0x00: "VendorName",
    0x01: "ProductCode",
    0x02: "MajorMinorRevision",
    0x03: "VendorUrl",
    0x04: "ProductName",
    0x05: "ModelName",
    0x06: "UserApplicationName",
}

EXCEPTION_NAMES: dict[int, str] = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}


def check_range(address: int, count: int, limit: int) -> None:
    """A register range a request may name: 1..``limit`` registers within 0..65535."""
    if not 1 <= count <= limit:
        raise GatewayError(f"register count {count} outside 1..{limit}")
    if not 0 <= address <= 0xFFFF or address + count > 0x10000:
        raise GatewayError(f"register range {address}..{address + count - 1} outside 0..65535")


class Transport(abc.ABC):
    """One Modbus bus (see the module docstring); ``timeout_s`` bounds one request (s)."""

    #: True when the backend bounds each request by ``timeout_s`` itself (and can then tell a
    #: garbled answer from none); the template method then adds no timer of its own.
    bounds_own_wait: ClassVar[bool] = False
    #: True when the backend can only return values 0..65535 (it decodes two bytes each);
    #: the template method then does not look at every value again.
    values_are_16_bit: ClassVar[bool] = False

    def __init__(self, name: str, timeout_s: float) -> None:
        self.name = name
        self.timeout_s = float(timeout_s)
        self._lock = asyncio.Lock()
        #: vendor reads already checked: (device id, read, address, count) -> their description
        self._vendor_reads: dict[tuple[int, VendorRead, int, int], str] = {}

    # ------------------------------------------------------------------ what a backend says
    @property
    @abc.abstractmethod
    def target(self) -> str:
        """Where the bus goes, for messages (``host:port (tcp)``, ``/dev/ttyUSB0 (19200 baud)``)."""

    @property
    @abc.abstractmethod
    def connected(self) -> bool:
        """Whether requests can be sent now."""

    @property
    def is_serial_framing(self) -> bool:
        """True when frames carry no transaction id (RTU): a late answer could be misread."""
        return False

    @property
    def quiet_after_send_s(self) -> float:
        """How long after a request is written no answer can be there yet (s)."""
        return 0.0

    @abc.abstractmethod
    async def _connect(self) -> None:
        """Open the connection; raise ``DeviceConnectionError`` (or ``OSError``) on failure."""

    @abc.abstractmethod
    async def _close(self) -> None:
        """Close the connection, if any."""

    @abc.abstractmethod
    async def _read(
        self, kind: RegisterKind, device_id: int, address: int, count: int, what: str
    ) -> Sequence[int]:
        """Function 4 (``kind`` input) or 3 (holding): the registers the device sent."""

    @abc.abstractmethod
    async def _write(self, device_id: int, address: int, values: list[int], what: str) -> None:
        """Function 16: write ``values`` from ``address``."""

    async def _write_single(self, device_id: int, address: int, value: int, what: str) -> None:
        """Function 6: write ``value`` to the holding register ``address`` (a backend that
        cannot send it keeps this default, which refuses before anything is sent)."""
        raise GatewayError(f"{what}: bus {self.name!r} ({type(self).__name__}) cannot send function 6")

    async def _read_vendor(
        self, read: VendorRead, device_id: int, address: int, count: int, what: str
    ) -> Sequence[int]:
        """The vendor-defined read ``read``: the 16-bit words of the answer (a backend that
        cannot send it keeps this default, which refuses before anything is sent)."""
        raise GatewayError(
            f"{what}: bus {self.name!r} ({type(self).__name__}) "
            f"cannot send function 0x{read.function_code:02X}"
        )

    @abc.abstractmethod
    async def _read_device_identification(self, device_id: int, what: str) -> dict[str, str]:
        """Function 43/14: identification objects by name (VendorName, ProductCode, ...)."""

    # ------------------------------------------------------------------ template methods
    async def connect(self) -> None:
        """Open the connection (or serial port); ``DeviceConnectionError`` on failure."""
        await self.close()
        try:
            await self._connect()
        except DeviceConnectionError:
            await self.close()
            raise
        except (OSError, ValueError) as exc:
            await self.close()
            raise DeviceConnectionError(f"bus {self.name!r}: cannot connect to {self.target}: {exc}") from exc
        # the poll loop says when it connects (not at every reconnect of a device that drops)
        log.debug("bus %s: connected to %s", self.name, self.target)

    async def close(self) -> None:
        """Close the connection; safe to call at any time and more than once."""
        with contextlib.suppress(Exception):
            await self._close()

    async def __aenter__(self) -> Transport:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def read(self, device_id: int, request: ReadRequest) -> list[int]:
        """One request of a poll's read plan (``plan.ReadRequest``), the 16-bit words it
        answers: function 4 or 3, a vendor-defined read, or a read behind a row select (the
        row's number is written to the select register first, function 6: a write the
        configuration names)."""
        if request.vendor is not None:
            return await self.read_vendor(device_id, request.vendor, request.address, request.count)
        if request.select is not None:
            select_address, row = request.select
            await self.write_register(device_id, select_address, row, allow_write=True)
        return await self._read_registers(request.table, device_id, request.address, request.count)

    async def read_input_registers(self, device_id: int, address: int, count: int) -> list[int]:
        """Function 4: ``count`` input registers from ``address`` (values 0..65535)."""
        return await self._read_registers(RegisterKind.INPUT, device_id, address, count)

    async def read_holding_registers(self, device_id: int, address: int, count: int) -> list[int]:
        """Function 3: ``count`` holding registers from ``address``."""
        return await self._read_registers(RegisterKind.HOLDING, device_id, address, count)

    async def read_registers(
        self, device_id: int, table: RegisterKind, address: int, count: int
    ) -> list[int]:
        """``count`` registers of ``table`` from ``address`` (function 4 or 3); a word that is
        not a ``RegisterKind`` is a ``ValueError``, never a read of the other table."""
        return await self._read_registers(RegisterKind(table), device_id, address, count)

    async def _read_registers(
        self, kind: RegisterKind, device_id: int, address: int, count: int
    ) -> list[int]:
        if not (1 <= count <= MAX_READ_REGISTERS and address >= 0 and address + count <= 0x10000):
            check_range(address, count, MAX_READ_REGISTERS)
        if not 0 <= device_id <= 247:
            self._check_device_id(device_id)
        what = f"read {kind} {address}+{count} of device {device_id} on {self.name!r}"
        async with self._lock:
            if not self.connected:
                self._check_connected()
            try:
                if self.bounds_own_wait:
                    registers = await self._read(kind, device_id, address, count, what)
                else:
                    async with asyncio.timeout(self.timeout_s):
                        registers = await self._read(kind, device_id, address, count, what)
            except GatewayError:
                raise
            except Exception as exc:
                raise self._map_error(what, exc) from exc
        if len(registers) != count:
            raise ShortAnswerError(
                f"{what}: asked for {count} registers, got {len(registers)}", count, len(registers)
            )
        if not self.values_are_16_bit and (min(registers) < 0 or max(registers) > 0xFFFF):
            raise DecodeError(f"{what}: a register value outside 0..65535")
        return registers if type(registers) is list else list(registers)

    async def read_vendor(self, device_id: int, read: VendorRead, address: int, count: int) -> list[int]:
        """The vendor-defined read ``read`` of ``count`` 16-bit words from ``address`` (values
        0..65535). ``count`` is 1..``read.max_count`` (125 words: a Modbus PDU holds at most 253
        bytes; 127 with a one-byte count field in bytes). An answer of another number of words
        is a ``DecodeError``; an exception answer a ``DeviceExceptionResponse`` (code 1,
        illegal function, from a device that does not know the function code)."""
        key = (device_id, read, address, count)
        what = self._vendor_reads.get(key)
        if what is None:  # checked once per request of a read plan, then only looked up
            if not 1 <= count <= read.max_count:
                raise GatewayError(
                    f"word count {count} outside 1..{read.max_count} for function 0x{read.function_code:02X}"
                )
            read.request_data(address, count)  # the fields must hold address and count
            self._check_device_id(device_id)
            fc = read.function_code
            what = f"read function 0x{fc:02X} {address}+{count} of device {device_id} on {self.name!r}"
            if len(self._vendor_reads) >= 256:
                self._vendor_reads.clear()
            self._vendor_reads[key] = what
        words = await self._call(what, self._read_vendor(read, device_id, address, count, what))
        assert isinstance(words, Sequence)
        if len(words) != count:
            raise DecodeError(f"{what}: asked for {count} words, got {len(words)}")
        if self.values_are_16_bit:
            return words if type(words) is list else list(words)
        if any(not 0 <= int(w) <= 0xFFFF for w in words):
            raise DecodeError(f"{what}: a word outside 0..65535")
        return [int(w) for w in words]

    async def write_register(self, device_id: int, address: int, value: int, allow_write: bool) -> None:
        """Function 6: write ``value`` (0..65535) to the holding register ``address``. Refused
        with ``WriteNotAllowedError`` before anything is sent unless the device's configuration
        allows writes."""
        if not allow_write:
            raise WriteNotAllowedError(
                f"write to register {address} of device {device_id} on bus {self.name!r} refused: "
                "the device configuration does not set allow_write = true"
            )
        check_range(address, 1, 1)
        if not 0 <= int(value) <= 0xFFFF:
            raise GatewayError(f"register value {value} outside 0..65535")
        self._check_device_id(device_id)
        what = f"write register {address} of device {device_id} on {self.name!r}"
        await self._call(what, self._write_single(device_id, address, int(value), what))

    async def write_registers(
        self, device_id: int, address: int, values: Sequence[int], allow_write: bool
    ) -> None:
        """Function 16. Refused with ``WriteNotAllowedError`` before anything is sent unless
        the device's configuration allows writes."""
        if not allow_write:
            raise WriteNotAllowedError(
                f"write to registers {address}.. of device {device_id} on bus {self.name!r} refused: "
                "the device configuration does not set allow_write = true"
            )
        regs = [int(v) for v in values]
        check_range(address, len(regs), MAX_WRITE_REGISTERS)
        if any(not 0 <= v <= 0xFFFF for v in regs):
            raise GatewayError("register values must be in 0..65535")
        self._check_device_id(device_id)
        what = f"write {address}+{len(regs)} of device {device_id} on {self.name!r}"
        await self._call(what, self._write(device_id, address, regs, what))

    async def read_device_identification(self, device_id: int) -> dict[str, str]:
        """Function 43/14 (regular objects): e.g. VendorName, ProductCode, ModelName.

        On serial framing (``is_serial_framing``) an answer that cannot be the one asked for
        (``DecodeError``: another function, a garbled frame) is most likely the late answer to
        an earlier request, which carries no transaction id to tell it apart: the line is
        left quiet for ``late_answer_drain_s`` so that the real answer, if it is still coming,
        arrives and is dropped, and the request is sent once more. A second failure raises.
        """
        self._check_device_id(device_id)
        what = f"read device identification of device {device_id} on {self.name!r}"
        async with self._lock:
            try:
                result = await self._request(what, self._read_device_identification(device_id, what))
            except DecodeError as exc:
                if not self.is_serial_framing:
                    raise
                log.info("%s; asking once more", exc)
                await asyncio.sleep(self.late_answer_drain_s)
                result = await self._request(what, self._read_device_identification(device_id, what))
        assert isinstance(result, dict)
        return result

    @property
    def late_answer_drain_s(self) -> float:
        """How long the line is left quiet before a request is repeated on serial framing (s):
        enough for a late answer to arrive and be dropped (as the poller waits before a retry)."""
        return min(0.5 * self.timeout_s, 0.2)

    async def _call(self, what: str, request: object) -> object:
        """Run one backend request (a coroutine) under the lock, the timeout and the mapping."""
        async with self._lock:
            return await self._request(what, request)

    async def _request(self, what: str, request: object) -> object:
        """``_call`` for a caller that holds the lock already."""
        assert asyncio.iscoroutine(request)
        try:
            self._check_connected()
            if self.bounds_own_wait:
                return await request
            async with asyncio.timeout(self.timeout_s):
                return await request
        except GatewayError:
            raise
        except Exception as exc:
            raise self._map_error(what, exc) from exc
        finally:
            request.close()  # never started (not connected): no "never awaited" warning

    # ------------------------------------------------------------------ helpers
    def _check_connected(self) -> None:
        if not self.connected:
            raise DeviceConnectionError(f"bus {self.name!r}: not connected to {self.target}")

    @staticmethod
    def _check_device_id(device_id: int) -> None:
        if not 0 <= device_id <= 247:
            raise GatewayError(f"device id {device_id} outside 0..247")

    def _map_error(self, what: str, exc: BaseException) -> GatewayError:
        """The typed error for what a backend raised."""
        if isinstance(exc, TimeoutError):  # before OSError: TimeoutError is one
            return DeviceTimeoutError(f"{what}: no answer from {self.target} within {self.timeout_s:g} s")
        if isinstance(exc, ConnectionError | OSError | EOFError):
            return DeviceConnectionError(f"{what}: connection to {self.target} lost: {exc}")
        return DecodeError(f"{what}: invalid response from {self.target}: {exc}")
