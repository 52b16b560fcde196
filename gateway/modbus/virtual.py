"""An in-process Modbus bus for fast tests (after python-can's ``VirtualBus``).

``VirtualTransport`` is a ``Transport`` backend whose devices are register images in memory
(input and holding registers per device id, and identification objects), changed by the test
between polls. A fault script decides the outcome of the next requests, so every branch of
the poll loop runs without sockets and without waiting:

* ``"timeout"``: no answer (raises at once; the template method maps it as a timeout);
* ``("exception", code)``: the device answers a Modbus exception;
* ``"garbled"``: bytes that are no valid frame;
* ``"short"``: an answer with one register too few;
* ``"disconnect"``: the connection drops (and stays down until ``connect``);
* ``"ok"``: a normal answer (to script a fault for a later request).

A read of an address that is not in the image answers exception 2 (illegal data address),
as a real device does; a device id that is not there gives no answer (a timeout).

Vendor-defined reads (``read_vendor``): ``VirtualDevice.vendor`` maps a function code to a
handler ``(address, count words) -> words`` (``set_vendor_image`` installs one that serves a
list of words, exception 2 outside it); a handler may raise ``DeviceExceptionResponse``. A
device without a handler for the code answers exception 1 (illegal function), as a real
one does. Function 6 (``write_register``) and 16 (``write_registers``) write the holding
image.

``requests`` logs every request in order as ``(kind, device_id, address, count)``: kind
"input", "holding", "write" (function 16), "write_single" (function 6), "identification"
or "vendor 0x42" (a vendor read, count in words). ``writes`` logs every write request with
its values, ``(device_id, address, values)``: empty means nothing was asked to be written.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

from ..errors import DecodeError, DeviceConnectionError, DeviceExceptionResponse
from .register_map import RegisterKind
from .transport import EXCEPTION_NAMES, Transport
from .vendor_fc import VendorRead

Fault = str | tuple[str, int]
#: A vendor read's handler: (address, count in 16-bit words) -> the words of the answer.
VendorHandler = Callable[[int, int], list[int]]
FAULTS = ("ok", "timeout", "garbled", "short", "disconnect", "exception")


@dataclass
class VirtualDevice:
    """The registers of one device: address -> value (0..65535)."""

    input: dict[int, int] = field(default_factory=dict)
    holding: dict[int, int] = field(default_factory=dict)
    identification: dict[str, str] = field(default_factory=dict)
    #: function code -> handler of vendor-defined reads with that code
    vendor: dict[int, VendorHandler] = field(default_factory=dict)

    def set_input(self, address: int, values: Iterable[int]) -> None:
        for k, v in enumerate(values):
            self.input[address + k] = int(v)

    def set_holding(self, address: int, values: Iterable[int]) -> None:
        for k, v in enumerate(values):
            self.holding[address + k] = int(v)

    def set_vendor_image(self, function_code: int, words: Sequence[int]) -> None:
        """Serve vendor reads with ``function_code`` from ``words`` (address = index into it);
        a read outside it answers exception 2. Later changes to ``words`` are served."""

        def serve(address: int, count: int) -> list[int]:
            if address < 0 or address + count > len(words):
                raise DeviceExceptionResponse(
                    f"vendor read 0x{function_code:02X} {address}+{count}: "
                    "exception 2 (illegal data address)",
                    2,
                )
            return [int(w) for w in words[address : address + count]]

        self.vendor[function_code] = serve


class VirtualTransport(Transport):
    """A bus whose devices live in memory (see the module docstring)."""

    def __init__(
        self, name: str = "virtual", devices: dict[int, VirtualDevice] | None = None, timeout_s: float = 0.5
    ) -> None:
        super().__init__(name, timeout_s)
        self.devices: dict[int, VirtualDevice] = devices if devices is not None else {}
        self.requests: list[tuple[str, int, int, int]] = []
        self.writes: list[tuple[int, int, tuple[int, ...]]] = []
        self.connects = 0
        self.refuse_connects = 0
        self._faults: deque[Fault] = deque()
        self._connected = False

    # ------------------------------------------------------------------ the script
    def fail_next(self, fault: Fault, times: int = 1) -> None:
        """The next ``times`` requests get ``fault`` (after those already scripted)."""
        name = fault if isinstance(fault, str) else fault[0]
        if name not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; one of {', '.join(FAULTS)}")
        self._faults.extend([fault] * times)

    @property
    def target(self) -> str:
        return f"virtual bus {self.name!r}"

    @property
    def connected(self) -> bool:
        return self._connected

    # ------------------------------------------------------------------ primitives
    async def _connect(self) -> None:
        self.connects += 1
        if self.refuse_connects > 0:
            self.refuse_connects -= 1
            raise ConnectionRefusedError("connection refused")
        self._connected = True

    async def _close(self) -> None:
        self._connected = False

    def _answer(self, kind: str, device_id: int, address: int, count: int, what: str) -> None:
        """Raise what the scripted fault or the device says instead of an answer."""
        self.requests.append((kind, device_id, address, count))
        fault = self._faults.popleft() if self._faults else None
        if fault == "disconnect":
            self._connected = False
            raise DeviceConnectionError(f"{what}: connection to {self.target} lost")
        if fault == "timeout" or device_id not in self.devices:
            raise TimeoutError
        if fault == "garbled":
            raise DecodeError(f"{what}: garbled answer from {self.target}")
        if isinstance(fault, tuple):
            code = fault[1]
            name = EXCEPTION_NAMES.get(code, "unknown exception")
            raise DeviceExceptionResponse(f"{what}: device answered exception {code} ({name})", code)

    def _short_answer(self) -> bool:
        """Whether the next answer is scripted to be one word short (the fault is used up)."""
        short = bool(self._faults) and self._faults[0] == "short"
        if short:
            self._faults.popleft()
        return short

    async def _read(
        self, kind: RegisterKind, device_id: int, address: int, count: int, what: str
    ) -> Sequence[int]:
        short = self._short_answer()
        self._answer(kind, device_id, address, count, what)
        device = self.devices[device_id]
        image = {RegisterKind.INPUT: device.input, RegisterKind.HOLDING: device.holding}[kind]
        try:
            values = [image[a] for a in range(address, address + count)]
        except KeyError:
            raise DeviceExceptionResponse(
                f"{what}: device answered exception 2 (illegal data address)", 2
            ) from None
        return values[:-1] if short else values

    async def _write(self, device_id: int, address: int, values: list[int], what: str) -> None:
        self.writes.append((device_id, address, tuple(values)))
        self._answer("write", device_id, address, len(values), what)
        self.devices[device_id].set_holding(address, values)

    async def _write_single(self, device_id: int, address: int, value: int, what: str) -> None:
        self.writes.append((device_id, address, (value,)))
        self._answer("write_single", device_id, address, 1, what)
        self.devices[device_id].holding[address] = value

    async def _read_vendor(
        self, read: VendorRead, device_id: int, address: int, count: int, what: str
    ) -> Sequence[int]:
        short = self._short_answer()
        self._answer(f"vendor 0x{read.function_code:02X}", device_id, address, count, what)
        handler = self.devices[device_id].vendor.get(read.function_code)
        if handler is None:
            raise DeviceExceptionResponse(f"{what}: device answered exception 1 (illegal function)", 1)
        try:
            values = list(handler(address, count))
        except DeviceExceptionResponse as exc:
            code = exc.exception_code
            name = EXCEPTION_NAMES.get(code, "unknown exception")
            raise DeviceExceptionResponse(
                f"{what}: device answered exception {code} ({name})", code
            ) from None
        return values[:-1] if short else values

    async def _read_device_identification(self, device_id: int, what: str) -> dict[str, str]:
        self._answer("identification", device_id, 0, 0, what)
        return dict(self.devices[device_id].identification)
