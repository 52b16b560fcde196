"""The pymodbus backend of the transport interface: the only gateway module that imports pymodbus.

One ``ModbusTransport`` per bus (TCP, RTU on a serial line, RTU framing over TCP, or Modbus
TCP over TLS), a ``transport.Transport`` whose template methods own the lock, the checks
and the error mapping. Here: building the pymodbus client for the bus kind, and what only
pymodbus' outcomes tell:

* an exception response -> ``DeviceExceptionResponse`` (with the Modbus exception code);
* no answer in ``timeout_s`` -> ``DeviceTimeoutError``; bytes came back but no valid frame
  (bad CRC, garbage) -> ``DecodeError`` (pymodbus bounds each wait itself, so it can tell);
* the wrong function in the answer -> ``DecodeError``; so is a frame pymodbus' framer cannot
  decode (an MBAP length that does not match what follows), which pymodbus would otherwise let
  escape from its protocol callback (asyncio logs a traceback and drops the connection);
* a connection that cannot be made or is lost -> ``DeviceConnectionError``.

Vendor-defined reads (``vendor_fc.VendorRead``): each read format becomes a pymodbus PDU
class (``vendor_pdu_class``, built once and cached) whose ``encode`` writes the request
fields, whose ``decode`` keeps the answer bytes (``VendorRead.registers`` checks them) and
whose ``calculateRtuFrameSize`` tells pymodbus' RTU framer where the answer ends (address,
function code, the byte-count field and that many bytes, CRC: ``VendorRead.response_size``).
It is registered with the decoder of each client (one per connection) before its first use;
over TCP the MBAP length field frames the answer, so the same class serves every bus kind.
An exception answer (function code | 0x80) is pymodbus' own ``ExceptionResponse``.

An RTU serial port that has just been opened is emptied first: what waits there is a late
answer to a request of an earlier connection (RTU frames carry no transaction id).

pymodbus' own retries and automatic reconnection are switched off: the poller retries and
reconnects with its own bounded, jittered back-off.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import ssl
from collections.abc import Awaitable, Callable
from typing import Any, ClassVar

from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient, AsyncModbusTlsClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType
from pymodbus.pdu import ModbusPDU

from ..errors import (
    DecodeError,
    DeviceConnectionError,
    DeviceError,
    DeviceExceptionResponse,
    DeviceTimeoutError,
    GatewayError,
)
from .endpoint import BusKind, Endpoint, TlsSettings
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

log = logging.getLogger(__name__)


class VendorPDU(ModbusPDU):
    """Base of the PDU classes of vendor-defined reads (one subclass per ``VendorRead``).

    The same class is the request (``encode``: the start and count fields of ``address``
    and ``count`` words) and the answer (``decode``: the bytes after the function code,
    kept in ``payload``); pymodbus' decoder registers one class for both.
    """

    vendor: ClassVar[VendorRead]

    def __init__(self, address: int = 0, count: int = 0, dev_id: int = 0, transaction_id: int = 0) -> None:
        super().__init__(dev_id=dev_id, transaction_id=transaction_id, address=address, count=count)
        self.payload = b""

    def encode(self) -> bytes:
        return self.vendor.request_data(self.address, self.count)

    def decode(self, data: bytes) -> None:
        self.payload = bytes(data)

    @classmethod
    def calculateRtuFrameSize(cls, data: bytes) -> int:
        """RTU frame length of an answer from its first bytes (``data`` starts at the device
        address): address, function code, byte count + data, CRC; 0 while unknown."""
        size = cls.vendor.response_size(bytes(data[2:]))
        return 0 if size is None else 2 + size + 2


_VENDOR_PDUS: dict[VendorRead, type[VendorPDU]] = {}


def vendor_pdu_class(read: VendorRead) -> type[VendorPDU]:
    """The pymodbus PDU class of ``read`` (built once per read format, then cached)."""
    cls = _VENDOR_PDUS.get(read)
    if cls is None:
        name = f"VendorRead0x{read.function_code:02X}"
        cls = type(name, (VendorPDU,), {"function_code": read.function_code, "vendor": read})
        _VENDOR_PDUS[read] = cls
    return cls


def _fail_quietly(future: asyncio.Future[Any], exc: BaseException) -> None:
    """Fail pymodbus' outstanding request with ``exc``. Its awaiter, if any, gets the error;
    a request already given up (a cancelled poll: the connection is closed under it) has no
    awaiter, and asyncio would log "Future exception was never retrieved" with a traceback
    when the future is collected, so the exception is marked as seen here."""
    future.set_exception(exc)
    future.exception()


def build_ssl_context(tls: TlsSettings) -> ssl.SSLContext:
    """Client TLS context: trust ``ca_file``, present ``cert_file``/``key_file`` if given.

    Certificate and host-name verification are on unless the config sets ``verify = false``.
    """
    ctx = ssl.create_default_context(
        ssl.Purpose.SERVER_AUTH, cafile=str(tls.ca_file) if tls.ca_file else None
    )
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    if tls.cert_file:
        ctx.load_cert_chain(str(tls.cert_file), str(tls.key_file) if tls.key_file else None)
    if not tls.verify:
        log.warning("TLS certificate verification is switched off by the configuration")
        ctx.check_hostname = False
        ctx.verify_mode = ssl.CERT_NONE
    return ctx


class ModbusTransport(Transport):
    """Asynchronous pymodbus client of one bus (see the module docstring)."""

    bounds_own_wait: ClassVar[bool] = True
    values_are_16_bit: ClassVar[bool] = True

    def __init__(self, bus: Endpoint) -> None:
        super().__init__(bus.name, bus.timeout_s)
        self.bus = bus
        self._client: AsyncModbusTcpClient | AsyncModbusSerialClient | None = None
        self._rx_seen = False
        self._connect_error: BaseException | None = None
        self._ssl_context: ssl.SSLContext | None = None
        #: function code -> read format registered with the current client's decoder
        self._vendor_registered: dict[int, VendorRead] = {}
        if bus.kind is BusKind.TLS:
            if bus.tls is None:
                raise GatewayError(f"bus {bus.name!r}: kind 'tls' needs a [tls] table")
            self._ssl_context = build_ssl_context(bus.tls)

    @classmethod
    def from_bus(cls, bus: Endpoint) -> ModbusTransport:
        return cls(bus)

    # ------------------------------------------------------------------ connection
    @property
    def target(self) -> str:
        b = self.bus
        if b.kind is BusKind.RTU:
            return f"{b.serial_port} ({b.baudrate} baud)"
        return f"{b.host}:{b.port} ({b.kind})"

    @property
    def connected(self) -> bool:
        return self._client is not None and bool(self._client.connected)

    @property
    def is_serial_framing(self) -> bool:
        """True when frames carry no transaction id (RTU): a late answer could be misread."""
        return self.bus.kind in (BusKind.RTU, BusKind.RTU_OVER_TCP)

    @property
    def quiet_after_send_s(self) -> float:
        """How long after a request is written no answer can be there yet (s): on a serial
        line the request itself takes (8 bytes + 3.5 characters of silence) x bits per
        character / baud to go out; over a network, no time at all."""
        b = self.bus
        if b.kind is not BusKind.RTU:
            return 0.0
        bits_per_char = 1 + int(b.bytesize) + (0 if str(b.parity) == "N" else 1) + int(b.stopbits)
        return (8 + 3.5) * bits_per_char / float(b.baudrate)

    def _make_client(self) -> AsyncModbusTcpClient | AsyncModbusSerialClient:
        b = self.bus
        common: dict[str, Any] = {
            "name": b.name,
            "reconnect_delay": 0,  # no automatic reconnection: the poller does it
            "timeout": self.timeout_s,
            "retries": 0,  # no library retries: the poller does them
            "trace_packet": self._trace_packet,
            "trace_connect": self._trace_connect,
        }
        client: AsyncModbusTcpClient | AsyncModbusSerialClient
        port = int(b.port or (802 if b.kind is BusKind.TLS else 502))
        if b.kind is BusKind.TCP:
            client = AsyncModbusTcpClient(
                str(b.host),
                port=port,
                framer=FramerType.SOCKET,
                **common,
            )
        elif b.kind is BusKind.RTU_OVER_TCP:
            client = AsyncModbusTcpClient(
                str(b.host),
                port=port,
                framer=FramerType.RTU,
                **common,
            )
        elif b.kind is BusKind.TLS:
            assert self._ssl_context is not None
            client = AsyncModbusTlsClient(
                str(b.host),
                port=port,
                sslctx=self._ssl_context,
                **common,
            )
            tls = b.tls
            if tls is not None and tls.server_hostname:
                # pymodbus verifies against ``host``; the config may name another identity
                create_tls: Any = client.ctx.call_create
                client.ctx.call_create = functools.partial(create_tls, server_hostname=tls.server_hostname)
        elif b.kind is BusKind.RTU:
            client = AsyncModbusSerialClient(
                str(b.serial_port),
                framer=FramerType.RTU,
                baudrate=int(b.baudrate),
                bytesize=int(b.bytesize),
                parity=str(b.parity),
                stopbits=int(b.stopbits),
                **common,
            )
        else:
            raise GatewayError(f"bus {b.name!r}: unknown kind {b.kind!r}")
        inner: Callable[[], Awaitable[Any]] = client.ctx.call_create

        async def create() -> Any:
            try:
                return await inner()
            except BaseException as exc:
                self._connect_error = exc
                raise

        client.ctx.call_create = create
        self._guard_frames(client)
        return client

    @staticmethod
    def _guard_frames(client: Any) -> None:
        """Make an undecodable answer fail its request instead of the connection.

        pymodbus (3.16) raises ``ModbusIOException`` out of its ``data_received`` callback when
        a frame cannot be decoded, e.g. a Modbus/TCP answer whose MBAP length is shorter than
        its contents: asyncio logs that with a traceback and closes the connection, and the
        request fails as a lost connection, on every poll. Here the received bytes are dropped
        and the outstanding request fails with the decode error instead. Left as is when the
        client is not the one expected."""
        ctx: Any = getattr(client, "ctx", None)
        inner = getattr(ctx, "callback_data", None)
        if not callable(inner):
            return

        def callback_data(data: bytes, addr: tuple[Any, ...] | None = None) -> int:
            try:
                used: int = inner(data, addr=addr)
            except ModbusIOException:
                future = getattr(ctx, "response_future", None)
                if isinstance(future, asyncio.Future) and not future.done():
                    _fail_quietly(future, ModbusIOException("undecodable answer"))
                return len(data)
            return used

        ctx.callback_data = callback_data

    async def _connect(self) -> None:
        self._connect_error = None
        try:
            client = self._make_client()
        except (OSError, ValueError) as exc:
            raise DeviceConnectionError(f"bus {self.name!r}: cannot open {self.target}: {exc}") from exc
        self._client = client
        self._vendor_registered = {}
        try:
            ok = await client.connect()
            if ok and self.bus.kind is BusKind.RTU:
                # the serial transport finishes its set-up on the next loop iterations
                for _ in range(3):
                    await asyncio.sleep(0)
                ok = bool(client.connected)
        except (OSError, ModbusException) as exc:
            self._connect_error = exc
            ok = False
        if not ok or not client.connected:
            reason = self._connect_error or "no connection"
            raise DeviceConnectionError(f"bus {self.name!r}: cannot connect to {self.target}: {reason}")
        if self.bus.kind is BusKind.RTU:
            self._write_requests_at_once(client)
            self._discard_waiting_input(client)

    @staticmethod
    def _write_requests_at_once(client: Any) -> None:
        """pymodbus' serial transport (3.16) buffers a frame and writes it when the event
        loop next finds the port writable, one pass later; the line (and the device's
        answer) waits for that. Write at once instead: a serial line carries one request
        at a time, so the port is writable. Left as is when the transport is not the one
        expected."""
        transport: Any = getattr(client.ctx, "transport", None)
        write, write_ready = getattr(transport, "write", None), getattr(transport, "intern_write_ready", None)
        if transport is None or not (callable(write) and callable(write_ready)):
            return

        def write_at_once(data: bytes) -> None:
            write(data)
            write_ready()

        transport.write = write_at_once

    @staticmethod
    def _discard_waiting_input(client: Any) -> None:
        """Drop what is waiting on a serial port just opened. RTU frames carry no transaction
        id: the late answer to a request of an earlier connection on this line (given up when
        that connection was closed, e.g. a cancelled poll) would be taken for the answer to
        the next request to the same device. pyserial empties the port's input when it opens
        it, but bytes can still arrive while pymodbus finishes its set-up: empty pyserial's
        input buffer and pymodbus' receive buffer once more now. Skipped where the transport
        (pymodbus 3.16's serial transport) is not the one expected."""
        ctx: Any = getattr(client, "ctx", None)
        port: Any = getattr(getattr(ctx, "transport", None), "sync_serial", None)
        reset_input = getattr(port, "reset_input_buffer", None)
        if callable(reset_input):
            try:
                reset_input()
            except (OSError, ValueError) as exc:  # pyserial's SerialException is an OSError
                log.debug("could not discard the input waiting on %s: %s", getattr(port, "port", "?"), exc)
        if isinstance(getattr(ctx, "recv_buffer", None), bytes):
            ctx.recv_buffer = b""

    async def _close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(Exception):
                client.close()
            await asyncio.sleep(0)  # let the transport's close callbacks run

    # ------------------------------------------------------------------ hooks
    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if not sending and data:
            self._rx_seen = True
        return data

    def _trace_connect(self, connected: bool) -> None:
        if connected:
            return
        client = self._client
        future = getattr(getattr(client, "ctx", None), "response_future", None)
        if isinstance(future, asyncio.Future) and not future.done():
            # fail the outstanding request now instead of waiting for its timeout
            _fail_quietly(future, ConnectionException(f"connection to {self.target} lost"))

    # ------------------------------------------------------------------ requests
    async def _execute(self, what: str, request: Awaitable[Any]) -> Any:
        """One pymodbus request (bounded by pymodbus' own ``timeout_s``), its outcome
        mapped to the gateway's errors; an exception response raises."""
        self._rx_seen = False
        try:
            response = await request
        except ConnectionException as exc:
            raise DeviceConnectionError(f"{what}: connection to {self.target} lost: {exc}") from exc
        except ModbusIOException as exc:
            raise self._classify_io(what, exc) from exc
        except TimeoutError as exc:
            raise self._timeout(what) from exc
        except OSError as exc:
            raise DeviceConnectionError(f"{what}: {self.target}: {exc}") from exc
        except ModbusException as exc:
            raise DecodeError(f"{what}: invalid response from {self.target}: {exc}") from exc
        if response is None:
            raise self._timeout(what)
        if response.isError():
            code = int(getattr(response, "exception_code", 0) or 0)
            name = EXCEPTION_NAMES.get(code, "unknown exception")
            raise DeviceExceptionResponse(f"{what}: device answered exception {code} ({name})", code)
        return response

    def _timeout(self, what: str) -> DeviceError:
        if self._rx_seen:
            return DecodeError(f"{what}: garbled answer from {self.target} (bytes but no valid frame)")
        return DeviceTimeoutError(f"{what}: no answer from {self.target} within {self.timeout_s:g} s")

    def _classify_io(self, what: str, exc: ModbusIOException) -> DeviceError:
        text = str(exc)
        if "No response" in text:
            return self._timeout(what)
        if not self.connected:
            return DeviceConnectionError(f"{what}: connection to {self.target} lost: {text}")
        return DecodeError(f"{what}: invalid response from {self.target}: {text}")

    def _live_client(self) -> AsyncModbusTcpClient | AsyncModbusSerialClient:
        client = self._client
        if client is None:
            raise DeviceConnectionError(f"bus {self.name!r}: not connected to {self.target}")
        return client

    async def _read(
        self, kind: RegisterKind, device_id: int, address: int, count: int, what: str
    ) -> list[int]:
        """The registers of a read answer; a wrong function is a ``DecodeError``.

        pymodbus decodes each register from two bytes, so values are always 0..65535.
        """
        client = self._live_client()
        # by the member: a word that is not a RegisterKind is a KeyError, not a holding read
        read = {
            RegisterKind.INPUT: client.read_input_registers,
            RegisterKind.HOLDING: client.read_holding_registers,
        }[kind]
        response = await self._execute(what, read(address, count=count, device_id=device_id))
        if response.function_code != kind.read_function:
            raise DecodeError(f"{what}: answer has function {response.function_code}")
        registers: list[int] = getattr(response, "registers", None) or []
        return registers

    async def _write(self, device_id: int, address: int, values: list[int], what: str) -> None:
        client = self._live_client()
        response = await self._execute(what, client.write_registers(address, values, device_id=device_id))
        if getattr(response, "function_code", None) != FC_WRITE_MULTIPLE:
            raise DecodeError(f"{what}: answer has function {getattr(response, 'function_code', None)}")

    async def _write_single(self, device_id: int, address: int, value: int, what: str) -> None:
        client = self._live_client()
        response = await self._execute(what, client.write_register(address, value, device_id=device_id))
        if getattr(response, "function_code", None) != FC_WRITE_SINGLE:
            raise DecodeError(f"{what}: answer has function {getattr(response, 'function_code', None)}")

    async def _read_vendor(
        self, read: VendorRead, device_id: int, address: int, count: int, what: str
    ) -> list[int]:
        """The words of a vendor-defined read; a wrong function or byte count is a ``DecodeError``."""
        client = self._live_client()
        pdu_class = vendor_pdu_class(read)
        if self._vendor_registered.get(read.function_code) != read:
            client.register(pdu_class)
            self._vendor_registered[read.function_code] = read
        request = pdu_class(address, count, dev_id=device_id)
        response = await self._execute(what, client.execute(False, request))
        function_code = getattr(response, "function_code", None)
        if function_code != read.function_code or not isinstance(response, VendorPDU):
            raise DecodeError(f"{what}: answer has function {function_code}")
        try:
            return read.registers(response.payload, count)
        except DecodeError as exc:
            raise DecodeError(f"{what}: invalid answer from {self.target}: {exc}") from exc

    async def _read_device_identification(self, device_id: int, what: str) -> dict[str, str]:
        client = self._live_client()
        info: dict[str, str] = {}
        object_id = 0
        for _ in range(8):  # "more follows" continuation, bounded
            response = await self._execute(
                what, client.read_device_information(read_code=0x02, object_id=object_id, device_id=device_id)
            )
            function_code = getattr(response, "function_code", None)
            if function_code != FC_DEVICE_ID:
                raise DecodeError(f"{what}: answer has function {function_code}")
            objects = getattr(response, "information", None)
            if not isinstance(objects, dict):
                raise DecodeError(f"{what}: answer carries no objects")
            for key, value in objects.items():
                name = DEVICE_ID_OBJECTS.get(int(key), f"object_{int(key):#04x}")
                raw = value if isinstance(value, bytes | bytearray) else str(value).encode()
                info[name] = bytes(raw).decode("utf-8", errors="replace")
            if not getattr(response, "more_follows", 0):
                break
            object_id = int(getattr(response, "next_object_id", 0))
        return info
