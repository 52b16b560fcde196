"""A DFRobot-style 6x6 tactile board as a bare pymodbus server (no physics): the public register
map of such boards, for testing ``tactile-gateway scan`` on a map it has not seen.

Input registers: 0 = VID ``0x3343``, 1 = PID ``0x3343`` (constant), 2..6 zeros (``gap="zero"``)
or not mapped (``"absent"``: exception 2), 7..42 the 36 cells of 12-bit counts (a press moving
across the grid over a noise floor of 10-30 counts; the ``idle`` cells read ``idle_value`` and
never move), 43 = the channel count 36. Every input read draws a new frame; nothing else is
mapped. Imports nothing of ``gateway``.
"""

from __future__ import annotations

import contextlib
import math
import random
import time
from collections.abc import AsyncIterator, Sequence

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from .modbus_server import serve_device_tcp

VID = PID = 0x3343
FRAME_ADDRESS, CELLS, COLUMNS = 7, 36, 6
COUNT_ADDRESS = FRAME_ADDRESS + CELLS


class DFRobotBoard:
    """The board's input registers, a new frame on every read (``frame``)."""

    def __init__(
        self,
        gap: str = "zero",
        idle: Sequence[int] = (0, 4, 17, 18, 35),
        idle_value: int = 9,
        seed: int = 1,
        period_s: float = 1.0,
    ) -> None:
        if gap not in ("zero", "absent"):
            raise ValueError(f'gap must be "zero" or "absent", got {gap!r}')
        self.gap = gap
        self.idle = frozenset(idle)
        self.idle_value = idle_value
        self.period_s = period_s
        self._rng = random.Random(seed)
        self._t0 = time.monotonic()

    def frame(self) -> list[int]:
        """The 36 cells now: a press crossing the grid in ``period_s``, noise on every cell."""
        phase = ((time.monotonic() - self._t0) / self.period_s) % 1.0
        x, y = (COLUMNS - 1) * phase, (CELLS // COLUMNS - 1) / 2.0
        cells = []
        for i in range(CELLS):
            if i in self.idle:
                cells.append(self.idle_value)
                continue
            r2 = (i % COLUMNS - x) ** 2 + (i // COLUMNS - y) ** 2
            counts = 20 + self._rng.randint(-10, 10) + 3000.0 * math.exp(-r2 / 2.0)
            cells.append(min(round(counts), 4095))
        return cells

    def device(self, device_id: int = 1) -> SimDevice:
        inputs = [SimData(0, count=2, values=VID, datatype=DataType.UINT16)]
        if self.gap == "zero":
            inputs.append(SimData(2, count=FRAME_ADDRESS - 2, values=0, datatype=DataType.UINT16))
        inputs.append(SimData(FRAME_ADDRESS, count=CELLS, values=0, datatype=DataType.UINT16))
        inputs.append(SimData(COUNT_ADDRESS, values=CELLS, datatype=DataType.UINT16))
        bits = [SimData(0, count=16, values=False, datatype=DataType.BITS)]
        holding = [SimData(0, values=0, datatype=DataType.UINT16)]
        return SimDevice(id=device_id, simdata=(bits, bits, holding, inputs), action=self.action)

    async def action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """Input reads get a new frame; everything else is refused (exception 2)."""
        if function_code != 4:
            return ExcCodes.ILLEGAL_ADDRESS
        offset = FRAME_ADDRESS - start_address
        registers[offset : offset + CELLS] = self.frame()
        return None


@contextlib.asynccontextmanager
async def serve_dfrobot_tcp(
    board: DFRobotBoard | None = None, host: str = "127.0.0.1", port: int = 0, device_id: int = 1
) -> AsyncIterator[int]:
    """Serve the board over Modbus TCP until the block ends; yields the bound port."""
    async with serve_device_tcp((board or DFRobotBoard()).device(device_id), host, port) as bound:
        yield bound
