"""The simulated arrays' registers as pymodbus devices (``SimData`` blocks and the access callback).

Each ``SimArray`` becomes a pymodbus ``SimDevice`` with non-shared blocks (holding and input
registers are separate address spaces) and an ``action`` callback that refreshes the
registers from the array on every access and validates configuration writes. A read that
covers the device clock latches the frame, as a data logger's snapshot register does: input
reads without the clock that follow within ``LATCH_S`` of wall time are answered from the
same conversion, so a poll's clock and values agree however long the requests between them
take (a read that covers the clock, or one after ``LATCH_S``, is live). The blocks
are those of the array's register map (``sim_device.maps``); a map without holding
registers gets a placeholder block that the callback refuses (exception 2), as the bit blocks.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Final

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from . import registers as reg
from .array import SimArray
from .maps import Block, TactileSimMap

_BIT_FUNCTIONS = frozenset({1, 2, 5, 15})
_INPUT_FUNCTIONS = frozenset({4})
#: Wall seconds a clock read's frame serves the input reads that follow it.
LATCH_S: Final = 1.0


_DATATYPES = {
    "uint16": DataType.UINT16,
    "uint32": DataType.UINT32,
    "uint64": DataType.UINT64,
    "float32": DataType.FLOAT32,
    "registers": DataType.REGISTERS,
}


def _simdata(blocks: list[Block]) -> list[SimData]:
    """pymodbus data for a map's blocks (an empty list: a placeholder register the action refuses)."""
    if not blocks:
        return [SimData(0, values=0, datatype=DataType.UINT16)]
    data = []
    for b in blocks:
        kind = _DATATYPES[b.datatype]
        data.append(SimData(b.address, count=b.count, values=b.value, datatype=kind, readonly=b.readonly))
    return data


def _bit_block() -> list[SimData]:
    # pymodbus needs a non-empty coil/discrete-input block; the action refuses every access.
    return [SimData(0, count=16, values=False, datatype=DataType.BITS)]


class Binding:
    """Connects one ``SimArray`` to its pymodbus ``SimDevice`` registers."""

    def __init__(self, array: SimArray, wall: Callable[[], float] = time.monotonic) -> None:
        self.array = array
        self._wall = wall
        self._input_image: list[int] | None = None
        self._latched_at = -float("inf")
        device_map = array.register_map
        self._has_holding = bool(device_map.holding_blocks())
        holding = _simdata(device_map.holding_blocks())
        inputs = _simdata(device_map.input_blocks())
        self.device = SimDevice(
            id=array.device_id,
            simdata=(_bit_block(), _bit_block(), holding, inputs),
            action=self.action,
        )

    def _input_frame(self, address: int, count: int) -> list[int]:
        """The input image a read of ``count`` registers at ``address`` sees (see the module docstring)."""
        clock = self.array.register_map.clock_registers
        now = self._wall()
        if clock is not None and address <= clock[0] + clock[1] - 1 and address + count - 1 >= clock[0]:
            self._latched_at = now
            return self.array.input_registers()
        if self._input_image is not None and now - self._latched_at < LATCH_S:
            return self._input_image
        self._latched_at = -float("inf")
        return self.array.input_registers()

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
            image = self._input_frame(address, count)
            if image is not self._input_image:
                registers[-start_address : len(image) - start_address] = image
                self._input_image = image
            return None
        if not self._has_holding:
            return ExcCodes.ILLEGAL_ADDRESS
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
    """A plain pymodbus device with the default map's layout and static values (a baseline)."""
    device_map = TactileSimMap(n_channels, columns, 2500)
    holding, inputs = _simdata(device_map.holding_blocks()), _simdata(device_map.input_blocks())
    return SimDevice(id=device_id, simdata=(_bit_block(), _bit_block(), holding, inputs))
