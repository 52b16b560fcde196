"""The register maps a simulated array can serve, behind one small interface (``DeviceMap``).

A map is the device's wire format and its read-out board: which register blocks exist
(``input_blocks``/``holding_blocks``, declared for the Modbus binding), how the latest
conversion becomes an input-register image (``input_image``), what the holding registers
hold and which writes they accept, how sensor resistances become ADC counts (``convert``)
and back (``measured_ohm``), the device identification, and in which order the ADC block
stores the physical channels (``register_channels``). The physics and the scenarios are the
array's (``SimArray``), the same for every map.

Maps (``ArrayConfig.register_map``):

- ``"tactile-sim"`` (``TactileSimMap``, the default): ``docs/register-map.md``, built from
  ``sim_device.registers``; high-side divider (eq. 18);
- ``"rawgrid"`` (``sim_device.rawgrid.RawgridMap``): ``docs/register-map-rawgrid.md``.

``sim_device.map_factory.make_map`` picks one for an ``ArrayConfig``: it sits above this module
and ``rawgrid`` (which builds on it), so the imports point one way.

Vendor-protocol devices (``VENDOR_MAPS``) are not register maps of a ``SimArray``: they wrap
an array of the default map and answer on the bus themselves (their own function codes):

- ``"skin60"`` (``sim_device.skin60``, ``tactile-sim run --map skin60``):
  ``docs/register-map-skin60.md``, a 60-point skin read with function code 0x42;
- ``"dfrobot"`` (``sim_device.dfrobot_map``, ``tactile-sim run --map dfrobot --tcp ...``): a
  DFRobot-style 6 x 6 board's public register map, a press crossing it (no physics; for
  ``scan`` and bring-up);
- ``"hand"`` (``sim_device.hand``, ``tactile-sim run --map hand``): ``docs/register-map-hand.md``,
  a robot hand's 1,062 taxels in 17 regions and its joints, in holding registers.

Pure python/numpy: ``pymodbus_device`` turns the ``Block`` declarations into pymodbus data.
"""

from __future__ import annotations

import importlib.metadata
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from . import registers as reg
from .batch import SampleBatch
from .config import ArrayConfig
from .electronics import adc_counts, full_scale, resistance_from_counts
from .faults import CHANNEL_MODES
from .registers import Electronics, HoldingWrite

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

VENDOR_NAME = "Tactile Gateway Project"
PRODUCT_CODE = "TSA-SIM"
PRODUCT_NAME = "Simulated MIS piezoresistive sensor array"

#: Devices with a vendor protocol over a default-map array (``sim_device.skin60``).
VENDOR_MAPS: tuple[str, ...] = ("skin60", "dfrobot", "hand")


def package_version() -> str:
    """The installed project version (``MajorMinorRevision`` of the device identification)."""
    try:
        return importlib.metadata.version("tactile-gateway")
    except importlib.metadata.PackageNotFoundError:
        return "0.0.0+unknown"


@dataclass(frozen=True)
class Block:
    """A run of registers of one data type, as the Modbus binding declares it.

    ``datatype`` is one of "uint16", "uint32", "uint64", "float32", "registers"; ``count``
    counts values of that type (a float32 is two registers); ``value`` is the start value.
    """

    address: int
    datatype: str
    count: int = 1
    value: int | float = 0
    readonly: bool = False


class DeviceMap(ABC):
    """One array's register map and read-out board (see the module docstring)."""

    name: ClassVar[str]
    #: electronics settings the board fixes: ``SimArray.set_electronics`` refuses them
    fixed_electronics: ClassVar[frozenset[str]] = frozenset()
    #: input registers (first, count) of the device clock, whose read latches a frame; None: no clock
    clock_registers: ClassVar[tuple[int, int] | None] = None

    def __init__(self, channels: int, columns: int, pitch_um: int) -> None:
        self.n_channels = channels
        self.columns = columns
        self.rows = -(-channels // columns)
        self.pitch_um = pitch_um

    @abstractmethod
    def electronics(self, config: ArrayConfig) -> Electronics:
        """The start settings of the read-out for ``config``."""

    @abstractmethod
    def input_blocks(self) -> list[Block]:
        """The input registers (function 4); addresses outside every block are exception 2."""

    @abstractmethod
    def holding_blocks(self) -> list[Block]:
        """The holding registers (functions 3, 6, 16); empty: every access is exception 2."""

    @abstractmethod
    def input_image(self, latest: SampleBatch, sample_counter: int, electronics: Electronics) -> list[int]:
        """The input registers from address 0 for the latest conversion (one-sample batch)."""

    def holding_image(self, electronics: Electronics, modes: NDArray[np.int8]) -> list[int]:
        """The holding registers from address 0 with the current configuration."""
        return []

    def decode_write(self, current: Sequence[int], address: int, values: Sequence[int]) -> HoldingWrite:
        """Validate a holding-register write (nothing applied); ``RegisterWriteError`` if refused."""
        raise reg.RegisterWriteError(reg.ILLEGAL_ADDRESS, f"holding register {address} is not mapped")

    @abstractmethod
    def convert(
        self,
        resistance_ohm: FloatArray,
        modes: NDArray[np.int8],
        electronics: Electronics,
        noise_lsb: FloatArray | float,
    ) -> IntArray:
        """ADC counts of the sensed resistances (T, N); open/short channel modes clamp to a rail."""

    @abstractmethod
    def measured_ohm(self, counts: IntArray, electronics: Electronics) -> FloatArray:
        """The sensor resistance the read-out infers from its counts."""

    @abstractmethod
    def identity(self) -> dict[str, str]:
        """Device identification objects (function 43 / MEI 14), by name."""

    def register_channels(self) -> NDArray[np.intp]:
        """Element k: the physical channel (row-major, top row first) of ADC register k."""
        return np.arange(self.n_channels)


class TactileSimMap(DeviceMap):
    """``docs/register-map.md``: the project's own map and high-side divider (eq. 18)."""

    name = "tactile-sim"
    clock_registers = (reg.IR_DEVICE_TIME_MS, 4)

    def __init__(self, channels: int, columns: int, pitch_um: int) -> None:
        super().__init__(channels, columns, pitch_um)
        self._image = reg.InputImage(self.n_channels)

    def electronics(self, config: ArrayConfig) -> Electronics:
        return Electronics(
            adc_bits=config.adc_bits,
            supply_v=float(config.supply_v),
            reference_ohm=float(config.reference_ohm),
            sample_period_s=float(config.sample_period_s),
            noise_lsb_rms=float(config.noise_lsb_rms),
        )

    def holding_blocks(self) -> list[Block]:
        return [
            Block(reg.HR_CHANNEL_COUNT, "uint16", value=self.n_channels, readonly=True),
            Block(reg.HR_ADC_BITS, "uint16", value=16),
            Block(reg.HR_SUPPLY_V, "float32", value=5.0),
            Block(reg.HR_REFERENCE_OHM, "float32", value=10e3),
            Block(reg.HR_SAMPLE_PERIOD_S, "float32", value=0.01),
            Block(reg.HR_NOISE_LSB_RMS, "float32", value=2.0),
            Block(reg.HR_GRID_COLUMNS, "uint16", value=self.columns, readonly=True),
            Block(reg.HR_PITCH_UM, "uint16", value=self.pitch_um, readonly=True),
            Block(reg.HR_CHANNEL_MODE, "uint16", count=self.n_channels),
        ]

    def input_blocks(self) -> list[Block]:
        n, words = self.n_channels, 2 * self.n_channels
        return [
            Block(reg.IR_SAMPLE_COUNTER, "uint32"),
            Block(reg.IR_DEVICE_TIME_MS, "uint64"),
            Block(reg.IR_STATUS_SUMMARY, "uint16"),
            Block(reg.IR_OPEN_BITMAP, "uint16", count=3 * reg.BITMAP_WORDS),
            Block(reg.IR_ADC_COUNTS, "uint16", count=n),
            Block(reg.IR_RESISTANCE, "registers", count=words),
            Block(reg.IR_TRUE_FORCE, "registers", count=words),
            Block(reg.IR_TEMPERATURE, "registers", count=words),
            Block(reg.IR_TRUE_RESISTANCE, "registers", count=words),
        ]

    def input_image(self, latest: SampleBatch, sample_counter: int, electronics: Electronics) -> list[int]:
        counts = latest.adc_counts[0]
        modes = latest.modes[0]
        fs = full_scale(electronics.adc_bits)
        normal = modes == CHANNEL_MODES["normal"]
        return self._image.update(
            sample_counter=sample_counter,
            device_time_ms=round(float(latest.time_s[-1]) * 1000.0),
            open_=modes == CHANNEL_MODES["open"],
            short=modes == CHANNEL_MODES["short"],
            saturated=normal & ((counts <= 1) | (counts >= fs - 1)),
            adc_counts=counts,
            resistance_ohm=latest.resistance_ohm[0],
            true_force_n=latest.force_n[0],
            temperature_c=latest.temperature_c[0],
            true_resistance_ohm=latest.true_resistance_ohm[0],
        )

    def holding_image(self, electronics: Electronics, modes: NDArray[np.int8]) -> list[int]:
        return reg.holding_image(self.n_channels, self.columns, self.pitch_um, electronics, modes)

    def decode_write(self, current: Sequence[int], address: int, values: Sequence[int]) -> HoldingWrite:
        return reg.decode_holding_write(current, self.n_channels, address, values)

    def convert(
        self,
        resistance_ohm: FloatArray,
        modes: NDArray[np.int8],
        electronics: Electronics,
        noise_lsb: FloatArray | float,
    ) -> IntArray:
        e = electronics
        counts = adc_counts(resistance_ohm, e.reference_ohm, e.adc_bits, noise_lsb)
        counts[modes == CHANNEL_MODES["open"]] = 0
        counts[modes == CHANNEL_MODES["short"]] = full_scale(e.adc_bits)
        return counts

    def measured_ohm(self, counts: IntArray, electronics: Electronics) -> FloatArray:
        return resistance_from_counts(counts, electronics.reference_ohm, electronics.adc_bits)

    def identity(self) -> dict[str, str]:
        return {
            "VendorName": VENDOR_NAME,
            "ProductCode": PRODUCT_CODE,
            "MajorMinorRevision": package_version(),
            "ProductName": PRODUCT_NAME,
            "ModelName": f"Linqstat {self.rows}x{self.columns}",
        }
