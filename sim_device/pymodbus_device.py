"""The simulated arrays' registers as pymodbus devices (``SimData`` blocks and the access callback).

Each ``SimArray`` becomes a pymodbus ``SimDevice`` with non-shared blocks (holding and input
registers are separate address spaces) and an ``action`` callback that refreshes the
registers from the array on every access and validates configuration writes.
"""

from __future__ import annotations

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from . import registers as reg
from .array import SimArray

_BIT_FUNCTIONS = frozenset({1, 2, 5, 15})
_INPUT_FUNCTIONS = frozenset({4})


def _register_blocks(n_channels: int, columns: int, pitch_um: int) -> tuple[list[SimData], list[SimData]]:
    """Holding and input register blocks of the map, with their data types and RO flags."""
    holding = [
        SimData(reg.HR_CHANNEL_COUNT, values=n_channels, datatype=DataType.UINT16, readonly=True),
        SimData(reg.HR_ADC_BITS, values=16, datatype=DataType.UINT16),
        SimData(reg.HR_SUPPLY_V, values=5.0, datatype=DataType.FLOAT32),
        SimData(reg.HR_REFERENCE_OHM, values=10e3, datatype=DataType.FLOAT32),
        SimData(reg.HR_SAMPLE_PERIOD_S, values=0.01, datatype=DataType.FLOAT32),
        SimData(reg.HR_NOISE_LSB_RMS, values=2.0, datatype=DataType.FLOAT32),
        SimData(reg.HR_GRID_COLUMNS, values=columns, datatype=DataType.UINT16, readonly=True),
        SimData(reg.HR_PITCH_UM, values=pitch_um, datatype=DataType.UINT16, readonly=True),
        SimData(reg.HR_CHANNEL_MODE, count=n_channels, values=0, datatype=DataType.UINT16),
    ]
    words = 2 * n_channels
    inputs = [
        SimData(reg.IR_SAMPLE_COUNTER, values=0, datatype=DataType.UINT32),
        SimData(reg.IR_DEVICE_TIME_MS, values=0, datatype=DataType.UINT64),
        SimData(reg.IR_STATUS_SUMMARY, values=0, datatype=DataType.UINT16),
        SimData(reg.IR_OPEN_BITMAP, count=3 * reg.BITMAP_WORDS, values=0, datatype=DataType.UINT16),
        SimData(reg.IR_ADC_COUNTS, count=n_channels, values=0, datatype=DataType.UINT16),
        SimData(reg.IR_RESISTANCE, count=words, values=0, datatype=DataType.REGISTERS),
        SimData(reg.IR_TRUE_FORCE, count=words, values=0, datatype=DataType.REGISTERS),
        SimData(reg.IR_TEMPERATURE, count=words, values=0, datatype=DataType.REGISTERS),
        SimData(reg.IR_TRUE_RESISTANCE, count=words, values=0, datatype=DataType.REGISTERS),
    ]
    return holding, inputs


def _bit_block() -> list[SimData]:
    # pymodbus needs a non-empty coil/discrete-input block; the action refuses every access.
    return [SimData(0, count=16, values=False, datatype=DataType.BITS)]


class Binding:
    """Connects one ``SimArray`` to its pymodbus ``SimDevice`` registers."""

    def __init__(self, array: SimArray) -> None:
        self.array = array
        self._input_image: list[int] | None = None
        pitch_um = round(array.layout.pitch_mm * 1000.0)
        holding, inputs = _register_blocks(array.n_channels, array.layout.columns, pitch_um)
        self.device = SimDevice(
            id=array.device_id,
            simdata=(_bit_block(), _bit_block(), holding, inputs),
            action=self.action,
        )

    async def action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """Refresh the accessed block from the array; validate and apply writes."""
        if function_code in _BIT_FUNCTIONS:
            return ExcCodes.ILLEGAL_ADDRESS
        if function_code in _INPUT_FUNCTIONS:
            image = self.array.input_registers()
            if image is not self._input_image:
                registers[-start_address : len(image) - start_address] = image
                self._input_image = image
            return None
        if set_values:
            try:
                self.array.write_holding(address, [int(v) for v in set_values])
            except reg.RegisterWriteError as exc:
                return ExcCodes(exc.code)
            return None
        image = self.array.holding_registers()
        registers[-start_address : len(image) - start_address] = image
        return None


def static_device(n_channels: int, device_id: int = 1, columns: int = 4) -> SimDevice:
    """A plain pymodbus device with the same register layout and static values (a baseline)."""
    holding, inputs = _register_blocks(n_channels, columns, 2500)
    return SimDevice(id=device_id, simdata=(_bit_block(), _bit_block(), holding, inputs))
