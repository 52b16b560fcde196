"""The register map of a tactile array: the one module that knows its layout.

``docs/register-map.md`` is the contract (addresses are zero-based protocol addresses, every
multi-register value big-endian unless the configuration says otherwise). A ``RegisterMap``
says where a device keeps each block; ``register_blocks`` lists the blocks one poll reads for
a device of N channels: three status bitmaps ``STATUS_BITMAP_STRIDE`` registers apart (one bit
per channel, ``ceil(N / 16)`` registers each), the ADC counts (one uint16 per channel) or the
resistances (one float32 per channel, ohm), and optionally the bench's reference force (N)
and temperature (degrees C) as float32.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Protocol

from ..errors import ConfigError

__all__ = [
    "BYTE_ORDERS",
    "DEVICE_TIME_ADDRESS",
    "DEVICE_TIME_REGISTERS",
    "ENCODINGS",
    "MAX_ADDRESS",
    "STATUS_BITMAPS",
    "STATUS_BITMAP_STRIDE",
    "DeviceLayout",
    "RegisterBlock",
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
#: The device clock (input registers 2-5, uint64 ms; docs/register-map.md).
DEVICE_TIME_ADDRESS: Final = 2
DEVICE_TIME_REGISTERS: Final = 4


@dataclass(frozen=True)
class RegisterMap:
    """Input-register addresses of a device (defaults: ``docs/register-map.md``).

    ``word_order`` is the order of the two registers of a float32 (``big``: high word first),
    ``byte_order`` the order of the bytes within a register. ``None`` disables an optional block.
    """

    adc_address: int = 100
    float_address: int = 400
    word_order: str = "big"
    byte_order: str = "big"
    status_address: int | None = 16
    force_reference_address: int | None = None
    temperature_address: int | None = None

    def __post_init__(self) -> None:
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
    ``float``, ``force_reference``, ``temperature``; ``purpose`` groups the three status
    bitmaps as ``status``. ``value_registers`` is 1 for uint16 values, 2 for float32 values.
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


def register_blocks(device: DeviceLayout) -> tuple[RegisterBlock, ...]:
    """The register blocks one poll of ``device`` reads, in the order of the register map."""
    n = device.n_channels
    regs = device.registers
    blocks: list[RegisterBlock] = []
    if regs.status_address is not None:
        width = status_registers(n)
        for i, bitmap in enumerate(STATUS_BITMAPS):
            address = regs.status_address + i * STATUS_BITMAP_STRIDE
            blocks.append(RegisterBlock(f"status_{bitmap}", "status", "input", address, width, 1))
    if device.encoding == "adc":
        blocks.append(RegisterBlock("adc", "adc", "input", regs.adc_address, n, 1))
    else:
        blocks.append(RegisterBlock("float", "float", "input", regs.float_address, 2 * n, 2))
    if regs.force_reference_address is not None:
        blocks.append(
            RegisterBlock(
                "force_reference", "force_reference", "input", regs.force_reference_address, 2 * n, 2
            )
        )
    if regs.temperature_address is not None:
        blocks.append(
            RegisterBlock("temperature", "temperature", "input", regs.temperature_address, 2 * n, 2)
        )
    return tuple(blocks)
