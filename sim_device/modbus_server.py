"""Modbus transports for simulated arrays (with ``pymodbus_device``, the only modules of
``sim_device`` importing pymodbus).

Each ``SimArray`` becomes a pymodbus ``SimDevice`` (``pymodbus_device``); the servers here
carry its requests and answers.

Transports: Modbus TCP (``serve_tcp``), RTU framing over TCP (``serve_tcp(framer="rtu")``),
Modbus/TCP over TLS (``serve_tls``) and RTU on a serial device (``serve_serial``, several
arrays with different device ids on one bus). A request for a device id that is not served
gets no answer on an RTU bus (nobody there) and exception 11 (gateway target failed to
respond) over Modbus/TCP.

Line timing (serial): a real RS-485 line needs time to carry the frames. With
``line_timing=True`` each response is held back until ``(request bytes + response bytes +
2 x 3.5) x 11 bits / baud + turnaround_s`` after the request arrived: both frames at 11 bits
per character plus the 3.5-character silent interval that ends each frame. The response
goes out within about 0.1 ms of that moment: the event-loop timer (which can fire a
millisecond or two late) wakes 2.5 ms early, a blocking sleep and a 0.2 ms spin wait out
the rest, and the frame is written at once; on a half-duplex line nothing else can happen
meanwhile.

Fault injection (``SimArray.faults``) happens per request in the connection handler: delay,
no response, exception response, garbled frame (RTU: bad CRC; Modbus/TCP: bad protocol id)
and dropped TCP connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import ssl
import time
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from typing import Any

from pymodbus.constants import DeviceInformation, ExcCodes
from pymodbus.framer import FramerRTU, FramerType
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.device import DeviceInformationFactory, ModbusDeviceIdentification
from pymodbus.pdu.mei_message import ReadDeviceInformationRequest, ReadDeviceInformationResponse
from pymodbus.server import ModbusSerialServer, ModbusTcpServer, ModbusTlsServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import SimDevice

from .array import SimArray
from .faults import NO_FAULT, FaultDecision
from .pymodbus_device import Binding, static_device

#: Bits per RTU character on the line (start + 8 data + parity/stop + stop).
BITS_PER_CHAR = 11
#: Silent interval that ends an RTU frame, in characters.
FRAME_GAP_CHARS = 3.5
#: How long before a response is due on an emulated line its timer fires (s).
LINE_TIMER_LEAD_S = 0.0025
#: The last part of that wait, spun rather than slept (s).
LINE_SPIN_S = 0.0004


class ServerStartError(OSError):
    """The server could not start (address in use, serial device missing, bad certificate)."""


# -------------------------------------------------------------------------- handler
@dataclass(frozen=True)
class LineTiming:
    """RTU line emulation: baud rate and the device's turnaround time."""

    baudrate: int
    turnaround_s: float = 0.0

    def transaction_s(self, request_bytes: int, response_bytes: int) -> float:
        """Wire time of a request and its response, with the silent interval after each."""
        chars = request_bytes + response_bytes + 2 * FRAME_GAP_CHARS
        return chars * BITS_PER_CHAR / self.baudrate + self.turnaround_s


class _Identity:
    """Stands in for pymodbus' global control block: one identity per device."""

    def __init__(self, info: dict[str, str]) -> None:
        self.Identity = ModbusDeviceIdentification(info_name=info)


class _SimHandler(ServerRequestHandler):
    """Connection handler: per-device identity, fault injection, line timing."""

    def __init__(self, owner: Any) -> None:
        super().__init__(owner, owner.trace_packet, owner.trace_pdu, owner.trace_connect)
        self._timers: dict[int, asyncio.TimerHandle] = {}
        self._next_timer = 0
        self._arrival_s = 0.0
        self._decision: FaultDecision = NO_FAULT
        self._request_bytes = 0

    def callback_data(self, data: bytes, addr: tuple[Any, ...] | None = None) -> int:
        self._arrival_s = self.loop.time()
        used: int = super().callback_data(data, addr)
        return used

    def callback_disconnected(self, exc: Exception | None) -> None:
        self.cancel_pending()
        super().callback_disconnected(exc)

    def cancel_pending(self) -> None:
        """Drop responses still held back (the connection is going away)."""
        for handle in self._timers.values():
            handle.cancel()
        self._timers.clear()

    async def handle_request(self) -> None:
        pdu: ModbusPDU | None = self.last_pdu
        if pdu is None:
            return
        owner = self.server
        array: SimArray | None = owner.sim_arrays.get(pdu.dev_id)
        addr = self.last_addr
        if array is None:
            if not owner.sim_bus:
                self._reply(ExceptionResponse(pdu.function_code, ExcCodes.GATEWAY_NO_RESPONSE), pdu, addr)
            return
        decision = array.faults.decide(array.device_time_s)
        if decision.drop_connection and not owner.sim_serial:
            if self.transport:
                self.transport.abort()  # type: ignore[attr-defined]
            return
        if decision.no_response or decision.drop_connection:
            return
        self._decision = decision
        if owner.sim_line is not None:
            self._request_bytes = len(self.framer.buildFrame(pdu))
        try:
            if decision.exception_code is not None:
                self._reply(ExceptionResponse(pdu.function_code, decision.exception_code), pdu, addr)
            elif isinstance(pdu, ReadDeviceInformationRequest):
                self._reply(self._identity_response(pdu, array), pdu, addr)
            else:
                await super().handle_request()
        finally:
            self._decision = NO_FAULT

    def _reply(self, response: ModbusPDU, request: ModbusPDU, addr: tuple[Any, ...] | None) -> None:
        response.transaction_id = request.transaction_id
        response.dev_id = request.dev_id
        self.server_send(response, addr)

    @staticmethod
    def _identity_response(pdu: ReadDeviceInformationRequest, array: SimArray) -> ModbusPDU:
        if not (0 <= pdu.object_id <= 0xFF and 0 <= pdu.read_code <= 0x04):
            return ExceptionResponse(pdu.function_code, ExcCodes.ILLEGAL_VALUE)
        information = DeviceInformationFactory.get(_Identity(array.identity()), pdu.read_code, pdu.object_id)
        if pdu.read_code == DeviceInformation.SPECIFIC and (
            0x07 <= pdu.object_id < 0x80 or not information.get(pdu.object_id)
        ):
            return ExceptionResponse(pdu.function_code, ExcCodes.ILLEGAL_ADDRESS)
        return ReadDeviceInformationResponse(read_code=pdu.read_code, information=information)

    def server_send(self, pdu: ModbusPDU | None, addr: tuple[Any, ...] | None) -> None:
        if not pdu:
            return
        decision = self._decision
        line: LineTiming | None = self.server.sim_line
        if decision is NO_FAULT and line is None:
            super().server_send(pdu, addr)
            return
        packet: bytes = self.trace_packet(True, self.framer.buildFrame(self.trace_pdu(True, pdu)))
        if decision.garble:
            packet = _garble(packet, isinstance(self.framer, FramerRTU))
        delay = decision.delay_s
        if line is not None:
            delay += line.transaction_s(self._request_bytes, len(packet))
        due = self._arrival_s + delay
        if due <= self.loop.time():
            self.send(packet, addr)
            return
        key = self._next_timer
        self._next_timer += 1
        # an event-loop timer fires up to a millisecond or two late (epoll counts whole
        # milliseconds): on a line, wake early and wait out the rest precisely
        lead = LINE_TIMER_LEAD_S if line is not None else 0.0
        self._timers[key] = self.loop.call_at(due - lead, self._send_later, key, packet, addr, due)

    def _send_later(self, key: int, packet: bytes, addr: tuple[Any, ...] | None, due: float) -> None:
        self._timers.pop(key, None)
        if not self.transport or self.is_closing:
            return
        # a serial line carries one transaction at a time: nothing else is waiting. A sleep
        # overshoots by about 0.1 ms (timer slack), so the last LINE_SPIN_S is spun; the
        # frame is handed to the transport first (pymodbus' send costs about 0.1 ms), and
        # written at the due moment (its serial transport would write on the loop's next pass)
        remaining = due - self.loop.time()
        if remaining > LINE_SPIN_S:
            time.sleep(remaining - LINE_SPIN_S)
        write_now = getattr(self.transport, "intern_write_ready", None)
        if callable(write_now):
            self.send(packet, addr)
        while self.loop.time() < due:
            pass
        if callable(write_now):
            write_now()
        else:
            self.send(packet, addr)


def _garble(packet: bytes, rtu: bool) -> bytes:
    """Corrupt a response: RTU gets a wrong CRC, Modbus/TCP a non-zero protocol id."""
    if rtu:
        return packet[:-1] + bytes([packet[-1] ^ 0xA5])
    return packet[:2] + b"\x00\x01" + packet[4:]


class _SimServerMixin:
    sim_arrays: dict[int, SimArray]
    sim_bus: bool
    sim_serial: bool
    sim_line: LineTiming | None

    def callback_new_connection(self) -> _SimHandler:
        return _SimHandler(self)


class _TcpServer(_SimServerMixin, ModbusTcpServer):
    pass


class _TlsServer(_SimServerMixin, ModbusTlsServer):
    pass


class _SerialServer(_SimServerMixin, ModbusSerialServer):
    pass


# --------------------------------------------------------------------------- servers
class SimServer:
    """A running server: ``port`` (TCP/TLS, the real bound port), ``device`` (serial)."""

    def __init__(
        self, server: Any, arrays: Sequence[SimArray], kind: str, host: str, port: int, device: str
    ) -> None:
        self._server = server
        self.arrays = list(arrays)
        self.kind = kind
        self.host = host
        self.port = port
        self.device = device
        self._ticker: asyncio.Task[None] | None = None

    def array(self, device_id: int) -> SimArray:
        for a in self.arrays:
            if a.device_id == device_id:
                return a
        raise KeyError(f"no array with device id {device_id}")

    def start_ticker(self, tick_s: float) -> None:
        """Advance every array every ``tick_s`` wall seconds (feeds recorders and fault schedules).

        Without it (``tick_s=None`` in ``serve_*``) the physics advances only when registers are read.
        """

        async def tick() -> None:
            while True:
                await asyncio.sleep(tick_s)
                for a in self.arrays:
                    a.advance()
                    a.faults.apply_due(a.device_time_s)

        self._ticker = asyncio.get_running_loop().create_task(tick(), name="sim_device ticker")

    async def stop(self) -> None:
        """Stop serving: close the listener and every connection, cancel pending work."""
        if self._ticker is not None:
            self._ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._ticker
            self._ticker = None
        server = self._server
        listener = server.transport
        for handler in list(server.active_connections.values()):
            handler.cancel_pending()
            if handler.transport is not None and self.kind != "serial":
                handler.transport.abort()
        await server.shutdown()
        if isinstance(listener, asyncio.AbstractServer):
            await asyncio.wait_for(listener.wait_closed(), timeout=5.0)
        for _ in range(3):
            await asyncio.sleep(0)


def _prepare(arrays: SimArray | Sequence[SimArray]) -> tuple[list[SimArray], list[SimDevice]]:
    items = [arrays] if isinstance(arrays, SimArray) else list(arrays)
    if not items:
        raise ValueError("at least one SimArray is needed")
    ids = [a.device_id for a in items]
    if len(set(ids)) != len(ids):
        raise ValueError(f"device ids must be unique, got {ids}")
    return items, [Binding(a).device for a in items]


def _configure(server: Any, arrays: list[SimArray], bus: bool, serial: bool, line: LineTiming | None) -> None:
    server.sim_arrays = {a.device_id: a for a in arrays}
    server.sim_bus = bus
    server.sim_serial = serial
    server.sim_line = line


async def _start(server: Any, what: str) -> None:
    try:
        await server.serve_forever(background=True)
    except RuntimeError as exc:
        await server.shutdown()
        raise ServerStartError(
            f"cannot start the Modbus server on {what} (address in use, not available, or not permitted)"
        ) from exc


@contextlib.asynccontextmanager
async def _running(sim: SimServer, tick_s: float | None) -> AsyncIterator[SimServer]:
    """Run a started server's physics ticker (if any) until the block ends, then stop it."""
    if tick_s is not None:
        sim.start_ticker(tick_s)
    try:
        yield sim
    finally:
        await sim.stop()


@contextlib.asynccontextmanager
async def serve_tcp(
    arrays: SimArray | Sequence[SimArray],
    host: str = "127.0.0.1",
    port: int = 0,
    framer: str = "socket",
    *,
    tick_s: float | None = 0.25,
) -> AsyncIterator[SimServer]:
    """Serve arrays over Modbus TCP (``framer="socket"``) or RTU framing over TCP (``"rtu"``)."""
    if framer not in ("socket", "rtu"):
        raise ValueError(f'framer must be "socket" or "rtu", got {framer!r}')
    items, devices = _prepare(arrays)
    server = _TcpServer(devices, framer=FramerType(framer), address=(host, port))
    _configure(server, items, framer == "rtu", False, None)
    await _start(server, f"{host}:{port}")
    bound = server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]
    kind = "rtu-tcp" if framer == "rtu" else "tcp"
    async with _running(SimServer(server, items, kind, host, int(bound), ""), tick_s) as sim:
        yield sim


@contextlib.asynccontextmanager
async def serve_tls(
    arrays: SimArray | Sequence[SimArray],
    host: str = "127.0.0.1",
    port: int = 0,
    *,
    certfile: str,
    keyfile: str,
    password: str | None = None,
    tick_s: float | None = 0.25,
) -> AsyncIterator[SimServer]:
    """Serve arrays over Modbus/TCP security (TLS) with the given certificate and key."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:
        context.load_cert_chain(certfile=certfile, keyfile=keyfile, password=password)
    except (OSError, ssl.SSLError) as exc:
        raise ServerStartError(f"cannot load TLS certificate {certfile!r} / key {keyfile!r}: {exc}") from exc
    items, devices = _prepare(arrays)
    server = _TlsServer(devices, address=(host, port), sslctx=context)
    _configure(server, items, False, False, None)
    await _start(server, f"{host}:{port} (TLS)")
    bound = server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]
    async with _running(SimServer(server, items, "tls", host, int(bound), ""), tick_s) as sim:
        yield sim


def _check_serial_device(port: str) -> None:
    """A plain device path must exist (pyserial URLs such as socket://host:port are passed on)."""
    if "://" not in port and not os.path.exists(port):
        raise ServerStartError(f"serial device {port} does not exist")


@contextlib.asynccontextmanager
async def serve_serial(
    arrays: SimArray | Sequence[SimArray],
    port: str,
    baudrate: int = 115200,
    line_timing: bool = True,
    turnaround_s: float = 0.0,
    *,
    bytesize: int = 8,
    parity: str = "N",
    stopbits: int = 1,
    tick_s: float | None = 0.25,
) -> AsyncIterator[SimServer]:
    """Serve arrays as RTU devices on one serial line (``port`` is the device path)."""
    if not (isinstance(baudrate, int) and baudrate > 0):
        raise ValueError(f"baudrate must be a positive integer, got {baudrate!r}")
    if not turnaround_s >= 0.0:
        raise ValueError(f"turnaround_s must be >= 0, got {turnaround_s!r}")
    _check_serial_device(port)
    items, devices = _prepare(arrays)
    server = _SerialServer(
        devices,
        framer=FramerType.RTU,
        port=port,
        baudrate=baudrate,
        bytesize=bytesize,
        parity=parity,
        stopbits=stopbits,
    )
    _configure(server, items, True, True, LineTiming(baudrate, turnaround_s) if line_timing else None)
    await _start(server, f"serial device {port}")
    async with _running(SimServer(server, items, "serial", "", 0, port), tick_s) as sim:
        yield sim


@contextlib.asynccontextmanager
async def serve_static_tcp(
    n_channels: int, host: str = "127.0.0.1", port: int = 0, device_id: int = 1
) -> AsyncIterator[int]:
    """A bare pymodbus server with the same register layout and static values; yields the port."""
    async with serve_device_tcp(static_device(n_channels, device_id), host, port) as bound:
        yield bound


@contextlib.asynccontextmanager
async def serve_device_tcp(device: SimDevice, host: str = "127.0.0.1", port: int = 0) -> AsyncIterator[int]:
    """Any pymodbus ``SimDevice`` over Modbus TCP until the block ends; yields the bound port
    (port 0: an ephemeral one). Its connections are dropped and the listener closed on exit."""
    server = ModbusTcpServer(device, address=(host, port))
    await _start(server, f"{host}:{port}")
    listener = server.transport
    try:
        yield int(listener.sockets[0].getsockname()[1])  # type: ignore[attr-defined]
    finally:
        for handler in list(server.active_connections.values()):
            if handler.transport is not None:
                handler.transport.abort()  # type: ignore[attr-defined]
        await server.shutdown()
        if isinstance(listener, asyncio.AbstractServer):
            await asyncio.wait_for(listener.wait_closed(), timeout=5.0)
        for _ in range(3):
            await asyncio.sleep(0)
