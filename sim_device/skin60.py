"""The "skin60" device (``docs/register-map-skin60.md``): a 60-point piezoresistive skin whose
frame is read with the vendor-defined function code 0x42.

Modeled on the public description of such a product: 60 points (6 rows of 10), a 12-bit
ADC per point, and

- function 0x42 (read points): request = start point (u16 BE) + number of points (u16 BE);
  answer = byte count (u8) + 2 bytes per point (u16 BE). Points 0..59; a range outside
  them is exception 2, a malformed count exception 3;
- holding registers (functions 3, 6, 16): product id, point count, OUTPUT_MODE (0: raw
  12-bit counts, 1: force in mN through an 11-point piecewise-linear table per point),
  the write-only DYNAMIC_ZERO and AUTO_ZERO_AT_POWER_ON (a read covering them is
  exception 2), AD_MASK (counts below it read 0) and POINT_AREA (0.1 mm^2 units);
- input registers 0..59 (function 4): the points, as function 0x42 answers them;
- any other function code: exception 1 (illegal function).

The sensors are a ``SimArray`` of the default map with 60 channels and a 12-bit converter
(``skin60_config``): the scenarios, the speed, the world effects and the faults are those of
every simulated array. ``Skin60Device`` is the device's logic (pure numpy) and keeps every
request it received in ``requests`` (function code, address, count, values written);
``serve_skin60_tcp`` and ``serve_skin60_serial`` put it on Modbus TCP, RTU over TCP or RTU
on a serial line with pymodbus.

Framing of the vendor code in pymodbus (3.16): a PDU class for function 0x42 is registered
with the server's decoder; its fixed RTU request size (address + code + 4 + CRC = 8 bytes)
lets the RTU framer find the end of a request. A request with a function code the decoder
does not know becomes an ``_UnknownFunction`` PDU (answered with exception 1): over TCP the
MBAP header frames it; on RTU its end is the first position where a CRC matches (the
device cannot know the layout of a function it does not implement).
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray
from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerRTU, FramerType
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.simulator import DataType, SimData, SimDevice

from .array import SimArray
from .config import ArrayConfig
from .modbus_server import (
    LineTiming,
    SimServer,
    _check_serial_device,
    _configure,
    _running,
    _SerialServer,
    _SimHandler,
    _start,
    _TcpServer,
)
from .scenarios import Scenario

MAP_NAME = "skin60"
N_POINTS = 60
COLUMNS = 10
ADC_BITS = 12
FULL_SCALE = (1 << ADC_BITS) - 1
PITCH_MM = 4.0

#: The vendor-defined read of the points.
FC_READ_POINTS = 0x42

# holding registers
HR_PRODUCT_ID = 0
HR_POINT_COUNT = 1
HR_OUTPUT_MODE = 2
HR_DYNAMIC_ZERO = 3
HR_AUTO_ZERO_AT_POWER_ON = 4
HR_AD_MASK = 5
HR_POINT_AREA = 6
HOLDING_COUNT = 7
WRITE_ONLY = frozenset({HR_DYNAMIC_ZERO, HR_AUTO_ZERO_AT_POWER_ON})
READ_ONLY = frozenset({HR_PRODUCT_ID, HR_POINT_COUNT, HR_POINT_AREA})

PRODUCT_ID = 0x5360
#: Area of one point, 0.1 mm^2 (100: 10 mm^2).
POINT_AREA = 100
OUTPUT_RAW = 0
OUTPUT_FORCE_MN = 1

#: Knots of the force tables: 11 counts from 0 to full scale.
TABLE_COUNTS = np.rint(np.linspace(0.0, FULL_SCALE, 11)).astype(np.int64)
#: Nominal force at the knots (mN): 20 N at full scale, convex.
TABLE_NOMINAL_MN = 20000.0 * np.linspace(0.0, 1.0, 11) ** 1.6

ILLEGAL_FUNCTION = 1
ILLEGAL_ADDRESS = 2
ILLEGAL_VALUE = 3

_BIT_FUNCTIONS = frozenset({1, 2, 5, 15})


class Skin60Error(Exception):
    """A request the device answers with Modbus exception ``code``."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Skin60Request:
    """One request the device received: function code, address, count (registers or
    points), the values written (empty for a read) and the device id."""

    function_code: int
    address: int
    count: int
    values: tuple[int, ...] = ()
    device_id: int = 1

    @property
    def is_write(self) -> bool:
        return self.function_code in (5, 6, 15, 16, 22, 23)


def skin60_config(
    scenario: str | Scenario = "idle",
    *,
    speed: float = 1.0,
    seed: int = 1,
    noise_lsb_rms: float = 2.0,
    **changes: Any,
) -> ArrayConfig:
    """The sensors of a skin: 60 channels in 6 rows of 10 at 4 mm, a 12-bit converter; any
    other ``ArrayConfig`` field may be given (``world_effects``, ``sample_period_s``, ...)."""
    base = ArrayConfig(
        channels=N_POINTS,
        columns=COLUMNS,
        pitch_mm=PITCH_MM,
        seed=seed,
        speed=speed,
        noise_lsb_rms=noise_lsb_rms,
        adc_bits=ADC_BITS,
        **changes,
    )
    loaded = scenario if isinstance(scenario, Scenario) else Scenario.load(scenario, base.layout)
    return base.with_changes(scenario=loaded)


def force_tables(seed: int) -> NDArray[np.float64]:
    """Each point's force table (mN) at the knots ``TABLE_COUNTS``, shape (60, 11).

    Point i scales the nominal curve by a gain within 5 % and each knot by 2 % more,
    deterministic from ``seed``; every table starts at 0 mN and rises strictly.
    """
    rng = np.random.default_rng([seed, 60])
    gain = 1.0 + 0.05 * rng.uniform(-1.0, 1.0, size=(N_POINTS, 1))
    jitter = 1.0 + 0.02 * rng.uniform(-1.0, 1.0, size=(N_POINTS, 11))
    tables = TABLE_NOMINAL_MN[None, :] * gain * jitter
    tables[:, 0] = 0.0
    steps = np.maximum(np.diff(tables, axis=1), 1.0)  # strictly rising
    return np.concatenate([np.zeros((N_POINTS, 1)), np.cumsum(steps, axis=1)], axis=1)


class Skin60Device:
    """The skin's logic: its registers, zero, mask and force tables over a ``SimArray``.

    ``request(function_code, address, count, values)`` is the whole device as the bus sees
    it (logged in ``requests``; raises ``Skin60Error`` for an exception answer).
    """

    def __init__(self, array: SimArray, log_file: TextIO | None = None) -> None:
        if array.n_channels != N_POINTS or array.electronics.adc_bits != ADC_BITS:
            raise ValueError("a skin60 device needs a 60-channel, 12-bit array (skin60_config)")
        self.array = array
        self.device_id = array.device_id
        self.tables_mn = force_tables(array.config.seed * 1000 + array.device_id)
        self.output_mode = OUTPUT_RAW
        self.ad_mask = 0
        self.auto_zero_at_power_on = 0
        self.zero: NDArray[np.int64] | None = None
        self.requests: list[Skin60Request] = []
        self._log_file = log_file

    # ------------------------------------------------------------------ values
    def raw_counts(self) -> NDArray[np.int64]:
        """The latest 12-bit counts of the 60 points after advancing to now."""
        self.array.advance()
        return np.asarray(self.array.latest().adc_counts[0], dtype=np.int64)

    def corrected_counts(self, raw: NDArray[np.int64] | None = None) -> NDArray[np.int64]:
        """Counts less the dynamic zero (not below 0), then 0 below ``ad_mask``."""
        counts = self.raw_counts() if raw is None else np.asarray(raw, dtype=np.int64)
        if self.zero is not None:
            counts = np.maximum(counts - self.zero, 0)
        return np.where(counts < self.ad_mask, 0, counts)

    def force_mn(self, counts: NDArray[np.int64]) -> NDArray[np.int64]:
        """Each point's force (mN) from its corrected counts through its table, 0..65535."""
        c = np.asarray(counts, dtype=np.float64)
        force = np.array([np.interp(c[i], TABLE_COUNTS, self.tables_mn[i]) for i in range(N_POINTS)])
        return np.clip(np.rint(force), 0, 0xFFFF).astype(np.int64)

    def points(self) -> list[int]:
        """The 60 point values as the device serves them in its current output mode."""
        counts = self.corrected_counts()
        values = counts if self.output_mode == OUTPUT_RAW else self.force_mn(counts)
        return [int(v) for v in values]

    def holding(self) -> list[int]:
        """The holding registers 0..6 (the write-only ones hold 0 here)."""
        regs = [0] * HOLDING_COUNT
        regs[HR_PRODUCT_ID] = PRODUCT_ID
        regs[HR_POINT_COUNT] = N_POINTS
        regs[HR_OUTPUT_MODE] = self.output_mode
        regs[HR_AD_MASK] = self.ad_mask
        regs[HR_POINT_AREA] = POINT_AREA
        return regs

    # ------------------------------------------------------------------ control
    def power_on(self) -> None:
        """What the device does when it starts: with AUTO_ZERO_AT_POWER_ON set, take a zero."""
        if self.auto_zero_at_power_on:
            self.zero = self.raw_counts()

    def write_holding(self, address: int, values: Sequence[int]) -> None:
        """Apply a write (all or nothing); ``Skin60Error`` 2 (address) or 3 (value) if refused."""
        if address < 0 or address + len(values) > HOLDING_COUNT or not values:
            raise Skin60Error(ILLEGAL_ADDRESS, f"holding registers {address}+{len(values)} not mapped")
        changes: list[tuple[int, int]] = []
        for k, value in enumerate(values):
            reg = address + k
            if reg in READ_ONLY:
                raise Skin60Error(ILLEGAL_ADDRESS, f"holding register {reg} is read-only")
            ok = 0 <= value <= FULL_SCALE if reg == HR_AD_MASK else value in (0, 1)
            if not ok:
                raise Skin60Error(ILLEGAL_VALUE, f"value {value} not allowed in holding register {reg}")
            changes.append((reg, int(value)))
        for reg, value in changes:
            if reg == HR_OUTPUT_MODE:
                self.output_mode = value
            elif reg == HR_AD_MASK:
                self.ad_mask = value
            elif reg == HR_AUTO_ZERO_AT_POWER_ON:
                self.auto_zero_at_power_on = value
            elif reg == HR_DYNAMIC_ZERO:
                self.zero = self.raw_counts() if value else None

    # ------------------------------------------------------------------ the bus
    def log(self, entry: Skin60Request) -> None:
        """Keep a request (and write it to the log file, if any)."""
        self.requests.append(entry)
        if self._log_file is not None:
            values = ",".join(str(v) for v in entry.values)
            self._log_file.write(
                f"{entry.device_id}\t0x{entry.function_code:02X}\t{entry.address}\t{entry.count}\t{values}\n"
            )
            self._log_file.flush()

    def read_points(self, start: int, count: int) -> list[int]:
        """Function 0x42: ``count`` points from ``start``; exception 2 outside 0..59."""
        if not 1 <= count <= N_POINTS or not 0 <= start <= N_POINTS - count:
            raise Skin60Error(ILLEGAL_ADDRESS, f"points {start}+{count} outside 0..{N_POINTS - 1}")
        return self.points()[start : start + count]

    def read_registers(self, function_code: int, address: int, count: int) -> list[int]:
        """Function 3 (holding) or 4 (input: the points)."""
        if function_code == 4:
            return self.read_points(address, count)
        if address < 0 or count < 1 or address + count > HOLDING_COUNT:
            raise Skin60Error(ILLEGAL_ADDRESS, f"holding registers {address}+{count} not mapped")
        if any(address <= r < address + count for r in WRITE_ONLY):
            raise Skin60Error(ILLEGAL_ADDRESS, "a read covers a write-only register")
        return self.holding()[address : address + count]


# ---------------------------------------------------------------------------- pymodbus
class _PointsPDU(ModbusPDU):
    """Function 0x42 on the server: the request (start, count) and, with ``points``, its answer."""

    function_code = FC_READ_POINTS
    rtu_frame_size = 8  # device address, code, start (2), count (2), CRC (2)

    def __init__(self, address: int = 0, count: int = 0, points: Sequence[int] | None = None) -> None:
        super().__init__(address=address, count=count)
        self.points = list(points) if points is not None else None
        self.skin: Skin60Device | None = None

    def encode(self) -> bytes:
        if self.points is not None:
            data = b"".join(int(p).to_bytes(2, "big") for p in self.points)
            return len(data).to_bytes(1, "big") + data
        return self.address.to_bytes(2, "big") + self.count.to_bytes(2, "big")

    def decode(self, data: bytes) -> None:
        if len(data) != 4:
            raise ValueError(f"function 0x42 request of {len(data)} bytes, expected 4")
        self.address = int.from_bytes(data[0:2], "big")
        self.count = int.from_bytes(data[2:4], "big")

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        skin = self.skin
        if skin is None:
            return ExceptionResponse(self.function_code, ExcCodes.DEVICE_FAILURE)
        try:
            points = skin.read_points(self.address, self.count)
        except Skin60Error as exc:
            return ExceptionResponse(self.function_code, exc.code)
        return _PointsPDU(self.address, self.count, points)


class _UnknownFunction(ModbusPDU):
    """A request with a function code the device does not implement: exception 1."""

    def __init__(self, function_code: int = 0, data: bytes = b"") -> None:
        super().__init__()
        self.function_code = function_code
        self.data = data

    def encode(self) -> bytes:
        return self.data

    @classmethod
    def calculateRtuFrameSize(cls, data: bytes) -> int:
        """The frame ends where a CRC first matches (at least address + code + CRC)."""
        for size in range(4, len(data) + 1):
            crc = int.from_bytes(data[size - 2 : size], "big")
            if FramerRTU.check_CRC(data[: size - 2], crc):
                return size
        return len(data) if len(data) > 256 else 0  # give up on garbage: the framer drops it

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_FUNCTION)


class _Skin60Decoder(DecodePDU):
    """Server decoder: the public functions, 0x42, and every other code as ``_UnknownFunction``."""

    def __init__(self) -> None:
        super().__init__(True)
        self.register(_PointsPDU)

    def lookupPduClass(self, data: bytes) -> type[ModbusPDU] | None:
        found = super().lookupPduClass(data)
        if found is None and len(data) > 1 and not data[1] & 0x80:
            return _UnknownFunction
        return found

    def decode(self, frame: bytes) -> ModbusPDU | None:
        code = int(frame[0]) if frame else 0
        if 0 < code < 0x80 and self.pdu_table.get(code, (None, None))[0] is None:
            return _UnknownFunction(code, bytes(frame[1:]))
        return super().decode(frame)


class _Skin60Handler(_SimHandler):
    """The simulator's connection handler (faults, line timing) plus the request log."""

    async def handle_request(self) -> None:
        pdu = self.last_pdu
        if pdu is not None:
            skin: Skin60Device | None = self.server.skin_devices.get(pdu.dev_id)
            if skin is not None:
                values: tuple[int, ...] = ()
                count = int(pdu.count)
                if pdu.function_code in (6, 16):
                    values = tuple(int(v) for v in pdu.registers)
                    count = len(values)
                skin.log(Skin60Request(pdu.function_code, int(pdu.address), count, values, pdu.dev_id))
            if isinstance(pdu, _PointsPDU):
                pdu.skin = skin
        await super().handle_request()


class _Skin60Binding:
    """Connects a ``Skin60Device`` to the pymodbus ``SimDevice`` of functions 3, 4, 6, 16."""

    def __init__(self, skin: Skin60Device) -> None:
        self.skin = skin
        holding = [SimData(0, count=HOLDING_COUNT, values=0, datatype=DataType.REGISTERS)]
        inputs = [SimData(0, count=N_POINTS, values=0, datatype=DataType.REGISTERS)]
        bits = [SimData(0, count=16, values=False, datatype=DataType.BITS)]
        self.device = SimDevice(id=skin.device_id, simdata=(bits, bits, holding, inputs), action=self.action)

    async def action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        skin = self.skin
        if function_code in _BIT_FUNCTIONS:
            return ExcCodes.ILLEGAL_ADDRESS
        try:
            if set_values:
                skin.write_holding(address, [int(v) for v in set_values])
                return None
            if function_code in (3, 4):
                image = skin.read_registers(function_code, address, count)
                registers[address - start_address : address - start_address + count] = image
                return None
        except Skin60Error as exc:
            return ExcCodes(exc.code)
        # the read-back of a write (function 6): the written value, even of a write-only register
        return None


class _Skin60Tcp(_TcpServer):
    def callback_new_connection(self) -> _Skin60Handler:
        return _Skin60Handler(self)


class _Skin60Serial(_SerialServer):
    def callback_new_connection(self) -> _Skin60Handler:
        return _Skin60Handler(self)


def _prepare(devices: Skin60Device | Sequence[Skin60Device]) -> tuple[list[Skin60Device], list[SimDevice]]:
    items = [devices] if isinstance(devices, Skin60Device) else list(devices)
    if not items:
        raise ValueError("at least one Skin60Device is needed")
    ids = [d.device_id for d in items]
    if len(set(ids)) != len(ids):
        raise ValueError(f"device ids must be unique, got {ids}")
    return items, [_Skin60Binding(d).device for d in items]


def _install(server: Any, items: list[Skin60Device]) -> None:
    server.decoder = _Skin60Decoder()
    server.skin_devices = {d.device_id: d for d in items}


@contextlib.asynccontextmanager
async def serve_skin60_tcp(
    devices: Skin60Device | Sequence[Skin60Device],
    host: str = "127.0.0.1",
    port: int = 0,
    framer: str = "socket",
    *,
    tick_s: float | None = 0.25,
) -> AsyncIterator[SimServer]:
    """Serve skins over Modbus TCP (``framer="socket"``) or RTU framing over TCP (``"rtu"``)."""
    if framer not in ("socket", "rtu"):
        raise ValueError(f'framer must be "socket" or "rtu", got {framer!r}')
    items, sim_devices = _prepare(devices)
    server = _Skin60Tcp(sim_devices, framer=FramerType(framer), address=(host, port))
    _install(server, items)
    arrays = [d.array for d in items]
    _configure(server, arrays, framer == "rtu", False, None)
    await _start(server, f"{host}:{port}")
    bound = server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]
    kind = "rtu-tcp" if framer == "rtu" else "tcp"
    async with _running(SimServer(server, arrays, kind, host, int(bound), ""), tick_s) as sim:
        yield sim


@contextlib.asynccontextmanager
async def serve_skin60_serial(
    devices: Skin60Device | Sequence[Skin60Device],
    port: str,
    baudrate: int = 115200,
    line_timing: bool = True,
    turnaround_s: float = 0.0,
    *,
    tick_s: float | None = 0.25,
) -> AsyncIterator[SimServer]:
    """Serve skins as RTU devices on one serial line (``port``: the device path), 8N1."""
    if not (isinstance(baudrate, int) and baudrate > 0):
        raise ValueError(f"baudrate must be a positive integer, got {baudrate!r}")
    _check_serial_device(port)
    items, sim_devices = _prepare(devices)
    server = _Skin60Serial(sim_devices, framer=FramerType.RTU, port=port, baudrate=baudrate)
    _install(server, items)
    arrays = [d.array for d in items]
    _configure(server, arrays, True, True, LineTiming(baudrate, turnaround_s) if line_timing else None)
    await _start(server, f"serial device {port}")
    async with _running(SimServer(server, arrays, "serial", "", 0, port), tick_s) as sim:
        yield sim


def open_request_log(path: str | Path) -> TextIO:
    """A request log file (``--log-requests``): one line per request, tab-separated device id,
    function code, address, count and the values written."""
    handle = Path(path).open("w", encoding="utf-8")  # noqa: SIM115 - closed by the caller
    handle.write("device_id\tfunction\taddress\tcount\tvalues\n")
    return handle
