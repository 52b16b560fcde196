"""The register map of a tactile array: the one module that knows its layout.

``docs/register-map.md`` is the contract (addresses are zero-based protocol addresses, every
multi-register value big-endian unless the configuration says otherwise). A ``RegisterMap``
says where a device keeps each block; ``register_blocks`` lists the blocks one poll reads for
a device of N channels: three status bitmaps ``STATUS_BITMAP_STRIDE`` registers apart (one bit
per channel, ``ceil(N / 16)`` registers each), the ADC counts (one uint16 per channel) or the
resistances (one float32 per channel, ohm), optionally the bench's reference force (N)
and temperature (degrees C) as float32, and the device clock when the map names one
(``DeviceClock``: an unsigned counter of 1, 2 or 4 registers and its tick in seconds).
Nothing is read that the map does not name. ``DeviceChecks`` are the optional registers and
identification verified when a device is connected, before it is polled.

A device whose frame does not follow that map describes it with a ``ValueFrame``: what each
value is (ADC counts, resistance, or a force or pressure the device has calibrated itself),
its unit, its encoding (Telegraf's types and byte orders, scale and offset), and the blocks
that carry it: input or holding registers, a vendor-defined function code
(``vendor_fc.VendorRead``), or one row at a time behind a row-select register. ``DeviceWrite``
is a register write the configuration names: a set-up write made at connect, or one step
of a named action (a device zero). Nothing else is ever written.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Protocol, TypeVar

from ..errors import ConfigError
from ..keys import Choice, choice_of
from .special_codes import SpecialCodes
from .vendor_fc import VendorRead

__all__ = [
    "BYTE_ORDERS",
    "CLOCK_REGISTERS",
    "CLOCK_UNITS",
    "DEVICE_TIME_ADDRESS",
    "DEVICE_TIME_REGISTERS",
    "ENCODINGS",
    "FRAME_ENCODINGS",
    "FRAME_QUANTITIES",
    "IDENTIFICATION_FIELDS",
    "MAX_ADDRESS",
    "MAX_READ_REGISTERS",
    "MAX_VALUE_STRIDE",
    "MAX_WRITE_REGISTERS",
    "REGISTER_TABLES",
    "STATUS_BITMAPS",
    "STATUS_BITMAP_STRIDE",
    "DeviceChecks",
    "DeviceClock",
    "DeviceLayout",
    "DeviceWrite",
    "Encoding",
    "FrameBlock",
    "FrameQuantity",
    "FrameTable",
    "RegisterBlock",
    "RegisterCheck",
    "RegisterKind",
    "RegisterMap",
    "RegisterSpace",
    "ValueFrame",
    "config_word",
    "frame_space",
    "register_blocks",
    "status_registers",
    "status_span",
]


class Encoding(Choice):
    """How a device reports each channel: ``adc`` counts of a divider, ``float32`` ohm, or its
    own calibrated ``output`` (force or pressure; only through a ``ValueFrame``)."""

    ADC = "adc"
    FLOAT32 = "float32"
    OUTPUT = "output"


class RegisterKind(Choice):
    """A Modbus register table: ``input`` (read with function 4) or ``holding`` (function 3)."""

    INPUT = "input"
    HOLDING = "holding"

    @property
    def read_function(self) -> int:
        """The function code that reads this table."""
        return _READ_FUNCTIONS[self]


_READ_FUNCTIONS: Final = {RegisterKind.INPUT: 4, RegisterKind.HOLDING: 3}


class FrameQuantity(Choice):
    """What a ``ValueFrame``'s values are: ADC counts, resistance, or the device's own force or
    pressure."""

    COUNTS = "counts"
    RESISTANCE = "resistance"
    FORCE = "force"
    PRESSURE = "pressure"


class FrameTable(Choice):
    """Where a frame's blocks are read: function 4, function 3, or a vendor-defined function."""

    INPUT = "input"
    HOLDING = "holding"
    VENDOR = "vendor"


_Word = TypeVar("_Word", bound=Choice)


def config_word(kind: type[_Word], where: str, name: str, value: object) -> _Word:
    """``value`` as a member of ``kind``; ``ConfigError`` naming ``where``, ``name``, the
    closest and every allowed word otherwise (``keys.choice_of``)."""
    try:
        return choice_of(kind, value, f"{where}: {name}")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


ENCODINGS: Final = tuple(Encoding)
#: The encoding a frame's quantity stands for.
FRAME_ENCODINGS: Final = {
    FrameQuantity.COUNTS: Encoding.ADC,
    FrameQuantity.RESISTANCE: Encoding.FLOAT32,
    FrameQuantity.FORCE: Encoding.OUTPUT,
    FrameQuantity.PRESSURE: Encoding.OUTPUT,
}
BYTE_ORDERS: Final = ("big", "little")
#: The three status bitmaps (open, short, saturated) start 16 registers apart.
STATUS_BITMAP_STRIDE: Final = 16
STATUS_BITMAPS: Final = ("open", "short", "saturated")
#: The highest Modbus register address.
MAX_ADDRESS: Final = 65535
#: Most registers one read may ask for (Modbus application protocol, functions 3 and 4).
MAX_READ_REGISTERS: Final = 125
#: Most registers from one frame value to the next (``ValueFrame.stride``).
MAX_VALUE_STRIDE: Final = 64
#: Most registers one write may carry (function 16).
MAX_WRITE_REGISTERS: Final = 123
#: The simulator's device clock (input registers 2-5, uint64 ms; docs/register-map.md).
DEVICE_TIME_ADDRESS: Final = 2
DEVICE_TIME_REGISTERS: Final = 4
#: Register tables: ``input`` (function 4) and ``holding`` (function 3).
REGISTER_TABLES: Final = tuple(RegisterKind)
#: A clock is an unsigned counter of this many registers (16, 32 or 64 bit).
CLOCK_REGISTERS: Final = (1, 2, 4)
#: Clock units and their tick in seconds.
CLOCK_UNITS: Final = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
#: FC 43/14 identification objects a configuration may expect, by their config key.
IDENTIFICATION_FIELDS: Final = ("vendor_name", "product_code", "revision", "product_name", "model_name")


def _check_address(where: str, name: str, value: object, span: int = 1) -> None:
    high = MAX_ADDRESS + 1 - span
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= high:
        raise ConfigError(f"{where}: {name}: {value!r} is out of range; allowed: 0..{high}")


def _set_table(owner: DeviceClock | RegisterCheck | RegisterMap, where: str) -> None:
    """A frozen dataclass's ``table`` as a ``RegisterKind`` (``ConfigError`` for anything else)."""
    object.__setattr__(owner, "table", config_word(RegisterKind, where, "table", owner.table))


@dataclass(frozen=True)
class DeviceClock:
    """A device clock: an unsigned big-endian counter of ``registers`` registers at
    ``address`` in ``table`` that counts ticks of ``tick_s`` seconds. A counter narrower than
    64 bit wraps; the time step between two polls is taken modulo its range, so a 16-bit
    millisecond clock serves polls less than 65 s apart."""

    address: int
    registers: int = 4
    tick_s: float = 1e-3
    table: RegisterKind = RegisterKind.INPUT

    def __post_init__(self) -> None:
        _set_table(self, "clock")
        if self.registers not in CLOCK_REGISTERS:
            raise ConfigError(f"clock: registers: {self.registers!r} is not allowed; allowed: 1, 2, 4")
        _check_address("clock", "address", self.address, self.registers)
        if not (isinstance(self.tick_s, float | int) and 0.0 < self.tick_s <= 3600.0):
            raise ConfigError(f"clock: tick_s: {self.tick_s!r} is out of range; allowed: (0, 3600] s")

    @property
    def modulus(self) -> int:
        """The counter's range, 2^(16 registers)."""
        return 1 << (16 * self.registers)

    @property
    def unit(self) -> str:
        """The tick as a unit name (``ms``) or in seconds."""
        for name, tick in CLOCK_UNITS.items():
            if tick == self.tick_s:
                return name
        return f"{self.tick_s:g} s"


@dataclass(frozen=True)
class RegisterCheck:
    """A register whose value must be ``value`` (a product id, a channel count): a device
    answering anything else is not the device the configuration describes."""

    what: str
    table: RegisterKind
    address: int
    value: int

    def __post_init__(self) -> None:
        _set_table(self, f"check {self.what!r}")
        _check_address(f"check {self.what!r}", "address", self.address)
        if isinstance(self.value, bool) or not isinstance(self.value, int) or not 0 <= self.value <= 0xFFFF:
            raise ConfigError(
                f"check {self.what!r}: value: {self.value!r} is out of range; allowed: 0..65535"
            )


@dataclass(frozen=True)
class DeviceChecks:
    """What is verified when a device is connected: register values and FC 43/14 objects
    (``identification``: pairs of an ``IDENTIFICATION_FIELDS`` key and its expected text)."""

    registers: tuple[RegisterCheck, ...] = ()
    identification: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        for key, _ in self.identification:
            if key not in IDENTIFICATION_FIELDS:
                raise ConfigError(
                    f"identification: {key!r} is not allowed; allowed: {', '.join(IDENTIFICATION_FIELDS)}"
                )

    def __bool__(self) -> bool:
        return bool(self.registers or self.identification)


#: What a frame's values can be, with each unit's factor to the gateway's base unit (counts,
#: ohm, N, kPa).
FRAME_QUANTITIES: Final[dict[FrameQuantity, dict[str, float]]] = {
    FrameQuantity.COUNTS: {"counts": 1.0},
    FrameQuantity.RESISTANCE: {"ohm": 1.0, "kohm": 1e3, "Mohm": 1e6},
    FrameQuantity.FORCE: {
        "N": 1.0,
        "mN": 1e-3,
        "kN": 1e3,
        "gf": 9.80665e-3,
        "kgf": 9.80665,
        "lbf": 4.4482216152605,
    },
    FrameQuantity.PRESSURE: {
        "kPa": 1.0,
        "Pa": 1e-3,
        "MPa": 1e3,
        "mbar": 0.1,
        "bar": 100.0,
        "psi": 6.894757293168,
    },
}
#: Registers per value of each type (``decode.VALUE_TYPES``' widths).
FRAME_TYPE_WIDTHS: Final = {"uint16": 1, "int16": 1, "uint32": 2, "int32": 2, "float32": 2, "float64": 4}
#: Where a frame's blocks are read: function 4, function 3, or a vendor-defined function code.
FRAME_TABLES: Final = tuple(FrameTable)


@dataclass(frozen=True)
class FrameBlock:
    """One block of a frame: ``values`` consecutive values from ``address`` (a register
    address, or a vendor read's start field), the next channels in order. ``row`` is the value
    written to the frame's row-select register before this block is read (None: no select)."""

    address: int
    values: int
    row: int | None = None


@dataclass(frozen=True)
class ValueFrame:
    """How a device lays out its channel values (module docstring): ``quantity`` in ``unit``
    (``FRAME_QUANTITIES``), each value ``value_type`` in byte order ``order``, read as
    raw x ``scale`` + ``offset``, from ``blocks`` in ``table``; ``vendor`` is the read when
    ``table`` is ``"vendor"``; ``row_select_address`` the holding register a row's number is
    written to before that row's block is read."""

    quantity: FrameQuantity
    unit: str
    value_type: str
    order: str
    scale: float
    offset: float
    table: FrameTable
    blocks: tuple[FrameBlock, ...]
    vendor: VendorRead | None = None
    row_select_address: int | None = None
    #: registers from one value to the next (0: the value's width, values back to back)
    stride: int = 0
    #: raw values that are codes (saturation, errors), not readings (None: none)
    special: SpecialCodes | None = None

    def __post_init__(self) -> None:
        units = FRAME_QUANTITIES.get(self.quantity)
        if units is None:
            raise ConfigError(
                f"frame: quantity: {self.quantity!r} is not allowed; allowed: {', '.join(FRAME_QUANTITIES)}"
            )
        if self.unit not in units:
            raise ConfigError(
                f"frame: unit: {self.unit!r} is not allowed for {self.quantity}; allowed: {', '.join(units)}"
            )
        if self.value_type not in FRAME_TYPE_WIDTHS:
            raise ConfigError(
                f"frame: type: {self.value_type!r} is not allowed; allowed: {', '.join(FRAME_TYPE_WIDTHS)}"
            )
        if self.table not in FRAME_TABLES:
            raise ConfigError(
                f"frame: table: {self.table!r} is not allowed; allowed: {', '.join(FRAME_TABLES)}"
            )
        object.__setattr__(self, "quantity", FrameQuantity(self.quantity))
        object.__setattr__(self, "table", FrameTable(self.table))
        if (self.table is FrameTable.VENDOR) != (self.vendor is not None):
            raise ConfigError(
                "frame: a vendor read needs table = 'vendor' and its function_code, and only it"
            )
        if not self.blocks:
            raise ConfigError("frame: blocks: at least one block is required")
        rows = [b.row is not None for b in self.blocks]
        if self.row_select_address is not None and not all(rows):
            raise ConfigError("frame: blocks: with row_select_address every block names its row")
        if self.row_select_address is None and any(rows):
            raise ConfigError("frame: blocks: a block names a row but the frame has no row_select_address")
        if self.value_type in FRAME_TYPE_WIDTHS and (
            isinstance(self.stride, bool)
            or not isinstance(self.stride, int)
            or not (self.stride == 0 or self.width <= self.stride <= MAX_VALUE_STRIDE)
        ):
            raise ConfigError(
                f"frame: stride: {self.stride!r} is out of range; allowed: 0 (values back to back) or "
                f"{self.width}..{MAX_VALUE_STRIDE} registers"
            )
        if self.vendor is not None and self.value_stride != self.width:
            raise ConfigError("frame: stride: a vendor read answers its values back to back")
        for b in self.blocks:
            _check_address("frame block", "address", b.address, 1 if self.vendor else self.span(b))

    @property
    def width(self) -> int:
        """Registers per value."""
        return FRAME_TYPE_WIDTHS[self.value_type]

    @property
    def value_stride(self) -> int:
        """Registers from the start of one value to the start of the next."""
        return self.stride or self.width

    def span(self, block: FrameBlock) -> int:
        """Registers from a block's first value to the end of its last."""
        return (block.values - 1) * self.value_stride + self.width

    @property
    def n_values(self) -> int:
        return sum(b.values for b in self.blocks)

    @property
    def factor(self) -> float:
        """The unit's factor to the base unit (counts, ohm, N or kPa)."""
        return FRAME_QUANTITIES[self.quantity][self.unit]

    def describe(self) -> str:
        """One line: ``force in mN, uint16 ABCD, vendor function 0x42: 0+60``."""
        where = (
            f"vendor function {self.vendor.function_code:#04x}" if self.vendor else f"{self.table} registers"
        )
        spans = ", ".join(
            f"{b.address}+{b.values if self.vendor else self.span(b)}"
            + ("" if b.row is None else f" (row {b.row})")
            for b in self.blocks
        )
        scaled = "" if (self.scale, self.offset) == (1.0, 0.0) else f" x {self.scale:g} + {self.offset:g}"
        what = "ADC counts" if self.quantity is FrameQuantity.COUNTS else f"{self.quantity} in {self.unit}"
        strided = (
            "" if self.value_stride == self.width else f", one value every {self.value_stride} registers"
        )
        special = "" if self.special is None else f", codes: {self.special.describe()}"
        return f"{what}, {self.value_type} {self.order}{scaled}{strided}{special}, {where}: {spans}"


#: The register space a block is read from, as the poll's register image names it: a
#: ``RegisterKind`` (``input``, ``holding``), or a frame block's (``frame_space``).
RegisterSpace = str


def frame_space(table: FrameTable, vendor: VendorRead | None = None, row: int | None = None) -> RegisterSpace:
    """The register space a frame block is read from: ``input``, ``holding`` (the
    ``RegisterKind``), ``fc0x42`` (a vendor read), ``input@row3`` (behind a row select)."""
    if vendor is not None:
        space: RegisterSpace = f"fc{vendor.function_code:#04x}"
    else:
        space = RegisterKind(table)
    return space if row is None else f"{space}@row{row}"


#: Function codes a set-up or action write may use: write single register, write multiple.
WRITE_FUNCTIONS: Final = (6, 16)


@dataclass(frozen=True)
class DeviceWrite:
    """A write the configuration names: ``values`` to holding registers from ``address``
    with function 6 or 16, described by ``what``; read back after writing when ``verify``
    (a write-only register cannot be)."""

    what: str
    address: int
    values: tuple[int, ...]
    function: int = 6
    verify: bool = True

    def __post_init__(self) -> None:
        where = f"write {self.what!r}"
        if self.function not in WRITE_FUNCTIONS:
            raise ConfigError(f"{where}: function: {self.function!r} is not allowed; allowed: 6, 16")
        if not self.values or (self.function == 6 and len(self.values) != 1):
            raise ConfigError(f"{where}: function 6 writes one value, function 16 one to 123")
        _check_address(where, "address", self.address, len(self.values))
        for v in self.values:
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 0xFFFF:
                raise ConfigError(f"{where}: value: {v!r} is out of range; allowed: 0..65535")

    def describe(self) -> str:
        shown = ", ".join(str(v) for v in self.values)
        check = "read back" if self.verify else "not read back"
        return f"{self.what}: holding {self.address} <- {shown} (function {self.function}, {check})"


@dataclass(frozen=True)
class RegisterMap:
    """Where a device keeps each block, in its ``table`` (input or holding registers).

    The defaults are the simulator's map (``docs/register-map.md``, the ``tactile-sim``
    profile), for configurations built in code; a configuration file names its map (a
    profile or its own ``[bus.device.registers]``). ``word_order`` is the order of the two
    registers of a float32 (``big``: high word first), ``byte_order`` the order of the bytes
    within a register. ``None`` disables an optional block; ``clock`` None means the
    host's monotonic clock times the samples.
    """

    adc_address: int = 100
    float_address: int = 400
    word_order: str = "big"
    byte_order: str = "big"
    status_address: int | None = 16
    force_reference_address: int | None = None
    temperature_address: int | None = None
    clock: DeviceClock | None = DeviceClock(DEVICE_TIME_ADDRESS, DEVICE_TIME_REGISTERS, 1e-3)
    table: RegisterKind = RegisterKind.INPUT
    #: the channel values' own layout (None: ``adc_address`` or ``float_address`` of ``table``)
    frame: ValueFrame | None = None
    #: writes made at every connect, in order, before the first poll
    setup: tuple[DeviceWrite, ...] = ()
    #: named actions (``zero``, ``unzero``, ...): each a sequence of writes run on request
    actions: tuple[tuple[str, tuple[DeviceWrite, ...]], ...] = ()

    def __post_init__(self) -> None:
        _set_table(self, "register map")
        if self.clock is not None and not isinstance(self.clock, DeviceClock):
            raise ConfigError(f"register map: clock: expected a DeviceClock or None, got {self.clock!r}")
        for name in ("word_order", "byte_order"):
            if getattr(self, name) not in BYTE_ORDERS:
                raise ConfigError(
                    f"register map: {name}: {getattr(self, name)!r} is not allowed; allowed: 'big', 'little'"
                )
        for name in (
            "adc_address",
            "float_address",
            "status_address",
            "force_reference_address",
            "temperature_address",
        ):
            value = getattr(self, name)
            if value is None and name not in ("adc_address", "float_address"):
                continue
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_ADDRESS:
                raise ConfigError(
                    f"register map: {name}: {value!r} is out of range; allowed: 0..{MAX_ADDRESS}"
                )


class DeviceLayout(Protocol):
    """What the register map needs to know of a device (a ``DeviceConfig`` is one)."""

    @property
    def encoding(self) -> Encoding: ...

    @property
    def n_channels(self) -> int: ...

    @property
    def registers(self) -> RegisterMap: ...


@dataclass(frozen=True)
class RegisterBlock:
    """One block of the register map a poll needs.

    ``name`` is one of ``status_open``, ``status_short``, ``status_saturated``, ``adc``,
    ``float``, ``force_reference``, ``temperature``, ``clock``; ``purpose`` groups the three
    status bitmaps as ``status`` and calls the clock ``device_time``. ``value_registers`` is
    1 for uint16 values, 2 for float32 values, the clock's width for the clock.
    """

    name: str
    purpose: str
    kind: RegisterSpace
    address: int
    count: int
    value_registers: int
    #: registers from one value to the next (0: ``value_registers``, values back to back)
    stride: int = 0

    @property
    def end(self) -> int:
        return self.address + self.count - 1

    @property
    def value_stride(self) -> int:
        return self.stride or self.value_registers

    @property
    def n_values(self) -> int:
        return (self.count - self.value_registers) // self.value_stride + 1


def status_registers(n_channels: int) -> int:
    """Registers of one status bitmap: one bit per channel, 16 per register."""
    return (n_channels + 15) // 16


def status_span(n_channels: int) -> int:
    """Registers from the first status bitmap to the end of the third."""
    return 2 * STATUS_BITMAP_STRIDE + status_registers(n_channels)


def register_blocks(device: DeviceLayout, clock: bool = True) -> tuple[RegisterBlock, ...]:
    """The register blocks one poll of ``device`` reads, in the order of the register map;
    without the clock when ``clock`` is False (a device whose clock was refused)."""
    n = device.n_channels
    regs = device.registers
    table = regs.table
    blocks: list[RegisterBlock] = []
    if clock and regs.clock is not None:
        c = regs.clock
        blocks.append(RegisterBlock("clock", "device_time", c.table, c.address, c.registers, c.registers))
    if regs.status_address is not None:
        width = status_registers(n)
        for i, bitmap in enumerate(STATUS_BITMAPS):
            address = regs.status_address + i * STATUS_BITMAP_STRIDE
            blocks.append(RegisterBlock(f"status_{bitmap}", "status", table, address, width, 1))
    if regs.frame is not None:
        f = regs.frame
        for k, b in enumerate(f.blocks):
            space = frame_space(f.table, f.vendor, b.row)
            count = f.span(b)
            stride = 0 if f.value_stride == f.width else f.value_stride
            blocks.append(RegisterBlock(f"frame{k}", "frame", space, b.address, count, f.width, stride))
    elif device.encoding is Encoding.ADC:
        blocks.append(RegisterBlock("adc", "adc", table, regs.adc_address, n, 1))
    elif device.encoding is Encoding.FLOAT32:
        blocks.append(RegisterBlock("float", "float", table, regs.float_address, 2 * n, 2))
    else:
        raise ConfigError(f"encoding {device.encoding!r} has no channel registers without a frame")
    if regs.force_reference_address is not None:
        blocks.append(
            RegisterBlock("force_reference", "force_reference", table, regs.force_reference_address, 2 * n, 2)
        )
    if regs.temperature_address is not None:
        blocks.append(RegisterBlock("temperature", "temperature", table, regs.temperature_address, 2 * n, 2))
    for k, word in enumerate(getattr(device, "status_words", ())):  # ``status_word.StatusWord``s
        blocks.append(RegisterBlock(f"status_word{k}", "status_word", word.table, word.address, 1, 1))
    return tuple(blocks)
