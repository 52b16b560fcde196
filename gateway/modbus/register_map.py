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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Protocol

from ..errors import ConfigError

__all__ = [
    "BYTE_ORDERS",
    "CLOCK_REGISTERS",
    "CLOCK_UNITS",
    "DEVICE_TIME_ADDRESS",
    "DEVICE_TIME_REGISTERS",
    "ENCODINGS",
    "IDENTIFICATION_FIELDS",
    "MAX_ADDRESS",
    "REGISTER_TABLES",
    "STATUS_BITMAPS",
    "STATUS_BITMAP_STRIDE",
    "DeviceChecks",
    "DeviceClock",
    "DeviceLayout",
    "RegisterBlock",
    "RegisterCheck",
    "RegisterMap",
    "register_blocks",
    "status_registers",
]

#: How a device reports each channel: ``adc`` counts of a divider, or ``float32`` ohm.
ENCODINGS: Final = ("adc", "float32")
BYTE_ORDERS: Final = ("big", "little")
#: The three status bitmaps (open, short, saturated) start 16 registers apart.
STATUS_BITMAP_STRIDE: Final = 16
STATUS_BITMAPS: Final = ("open", "short", "saturated")
#: The highest Modbus register address.
MAX_ADDRESS: Final = 65535
#: The simulator's device clock (input registers 2-5, uint64 ms; docs/register-map.md).
DEVICE_TIME_ADDRESS: Final = 2
DEVICE_TIME_REGISTERS: Final = 4
#: Register tables: ``input`` (function 4) and ``holding`` (function 3).
REGISTER_TABLES: Final = ("input", "holding")
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


def _check_table(where: str, value: object) -> None:
    if value not in REGISTER_TABLES:
        raise ConfigError(f"{where}: table: {value!r} is not allowed; allowed: 'input', 'holding'")


@dataclass(frozen=True)
class DeviceClock:
    """A device clock: an unsigned big-endian counter of ``registers`` registers at
    ``address`` in ``table`` that counts ticks of ``tick_s`` seconds. A counter narrower than
    64 bit wraps; the time step between two polls is taken modulo its range, so a 16-bit
    millisecond clock serves polls less than 65 s apart."""

    address: int
    registers: int = 4
    tick_s: float = 1e-3
    table: str = "input"

    def __post_init__(self) -> None:
        _check_table("clock", self.table)
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
    table: str
    address: int
    value: int

    def __post_init__(self) -> None:
        _check_table(f"check {self.what!r}", self.table)
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
    table: str = "input"

    def __post_init__(self) -> None:
        _check_table("register map", self.table)
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
    def encoding(self) -> str: ...

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
    kind: str
    address: int
    count: int
    value_registers: int

    @property
    def end(self) -> int:
        return self.address + self.count - 1


def status_registers(n_channels: int) -> int:
    return (n_channels + 15) // 16


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
    if device.encoding == "adc":
        blocks.append(RegisterBlock("adc", "adc", table, regs.adc_address, n, 1))
    else:
        blocks.append(RegisterBlock("float", "float", table, regs.float_address, 2 * n, 2))
    if regs.force_reference_address is not None:
        blocks.append(
            RegisterBlock("force_reference", "force_reference", table, regs.force_reference_address, 2 * n, 2)
        )
    if regs.temperature_address is not None:
        blocks.append(RegisterBlock("temperature", "temperature", table, regs.temperature_address, 2 * n, 2))
    return tuple(blocks)
