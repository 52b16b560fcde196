"""The "rawgrid" map (``docs/register-map-rawgrid.md``): a commercial-style array's wire format.

Same physics and scenarios as the default device; only the registers and the read-out
differ. Input registers only (no holding registers, coils or discrete inputs):

====================  ===========================================================
address               content
====================  ===========================================================
0                     product id 0x5447
1                     firmware version 0x0103 (v1.3)
2..5                  serial number 0x0000 0x0001 0xE240 0x0007
8                     channel count N
32..32+N-1            12-bit ADC counts, rows stored bottom-up (``storage_order``)
====================  ===========================================================

Read-out: a low-side divider (``sim_device.electronics.LowSideDivider``): pull-up
10 kohm from 3.3 V, the sensor to ground shunted by the board leakage
(``ArrayConfig.board_leakage_ohm``), a ratiometric 12-bit ADC.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .batch import SampleBatch
from .config import RAWGRID_BOARD, ArrayConfig
from .electronics import LowSideDivider, full_scale
from .faults import CHANNEL_MODES
from .maps import Block, DeviceMap, FloatArray, IntArray
from .registers import Electronics

IR_PRODUCT_ID = 0
IR_FIRMWARE_VERSION = 1
IR_SERIAL_NUMBER = 2
IR_CHANNEL_COUNT = 8
IR_ADC_COUNTS = 32

PRODUCT_ID = 0x5447
FIRMWARE_VERSION = 0x0103
SERIAL_NUMBER = (0x0000, 0x0001, 0xE240, 0x0007)

VENDOR_NAME = "Acme Tactile"
REVISION = "1.3"


def storage_order(channels: int, columns: int) -> NDArray[np.intp]:
    """Element k: the physical channel stored at ADC register 32 + k.

    Physical channel p sits at row p // columns (row 0 on top), column p % columns. The
    registers store the rows bottom-up, each row left to right; a short last row (N not a
    multiple of ``columns``) is the bottom row and comes first. 16 channels on 4 columns:
    12 13 14 15 8 9 10 11 4 5 6 7 0 1 2 3.
    """
    rows = -(-channels // columns)
    starts = np.arange(rows)[::-1] * columns
    return np.concatenate([np.arange(s, min(s + columns, channels)) for s in starts]).astype(np.intp)


class RawgridMap(DeviceMap):
    """``docs/register-map-rawgrid.md`` with the board's low-side read-out."""

    name = "rawgrid"
    fixed_electronics = frozenset(RAWGRID_BOARD)

    def __init__(self, channels: int, columns: int, pitch_um: int, leakage_ohm: float) -> None:
        super().__init__(channels, columns, pitch_um)
        self.leakage_ohm = float(leakage_ohm)
        self._order = storage_order(self.n_channels, self.columns)
        head = [0] * IR_ADC_COUNTS
        head[IR_PRODUCT_ID] = PRODUCT_ID
        head[IR_FIRMWARE_VERSION] = FIRMWARE_VERSION
        head[IR_SERIAL_NUMBER : IR_SERIAL_NUMBER + 4] = SERIAL_NUMBER
        head[IR_CHANNEL_COUNT] = self.n_channels
        self._head = head

    def electronics(self, config: ArrayConfig) -> Electronics:
        return Electronics(
            adc_bits=int(RAWGRID_BOARD["adc_bits"]),
            supply_v=RAWGRID_BOARD["supply_v"],
            reference_ohm=RAWGRID_BOARD["reference_ohm"],
            sample_period_s=float(config.sample_period_s),
            noise_lsb_rms=float(config.noise_lsb_rms),
        )

    def divider(self, electronics: Electronics) -> LowSideDivider:
        """The board's divider (``reference_ohm`` is the pull-up)."""
        return LowSideDivider(
            pullup_ohm=electronics.reference_ohm,
            supply_v=electronics.supply_v,
            adc_bits=electronics.adc_bits,
            leakage_ohm=self.leakage_ohm,
        )

    def input_blocks(self) -> list[Block]:
        return [
            Block(IR_PRODUCT_ID, "uint16", value=PRODUCT_ID, readonly=True),
            Block(IR_FIRMWARE_VERSION, "uint16", value=FIRMWARE_VERSION, readonly=True),
            Block(IR_SERIAL_NUMBER, "registers", count=4, readonly=True),
            Block(IR_CHANNEL_COUNT, "uint16", value=self.n_channels, readonly=True),
            Block(IR_ADC_COUNTS, "uint16", count=self.n_channels, readonly=True),
        ]

    def holding_blocks(self) -> list[Block]:
        return []

    def input_image(self, latest: SampleBatch, sample_counter: int, electronics: Electronics) -> list[int]:
        counts = latest.adc_counts[0][self._order]
        return [*self._head, *(int(c) for c in counts)]

    def convert(
        self,
        resistance_ohm: FloatArray,
        modes: NDArray[np.int8],
        electronics: Electronics,
        noise_lsb: FloatArray | float,
    ) -> IntArray:
        counts = self.divider(electronics).counts(resistance_ohm, noise_lsb)
        # a broken line leaves the input on the pull-up: full scale; a short pulls it to 0 V
        counts[modes == CHANNEL_MODES["open"]] = full_scale(electronics.adc_bits)
        counts[modes == CHANNEL_MODES["short"]] = 0
        return counts

    def measured_ohm(self, counts: IntArray, electronics: Electronics) -> FloatArray:
        return self.divider(electronics).resistance_from_counts(counts)

    def identity(self) -> dict[str, str]:
        return {
            "VendorName": VENDOR_NAME,
            "ProductCode": f"AT-{self.rows}x{self.columns}",
            "MajorMinorRevision": REVISION,
        }

    def register_channels(self) -> NDArray[np.intp]:
        return self._order.copy()
