"""The simulated hand (``sim_device.hand``) on Modbus: holding registers only (functions 3, 6
and 16), over TCP, RTU framing over TCP, or RTU on a serial line.

Mapped registers: the control block (``hand_map.CONTROL_FIRST .. CONTROL_LAST``) and the 17
taxel regions where the layout puts them; any other address is exception 2, as are input
registers, coils and discrete inputs, and a write to a read-only register. A value out of
range is exception 3. The connection handler is the simulator's (faults of the palm's array
apply to the whole hand, line timing on a serial line).
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any, cast

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.simulator import DataType, SimData, SimDevice

from . import hand_map as hm
from .array import SimArray
from .hand import HandDevice, HandWriteError
from .modbus_server import (
    LineTiming,
    SimServer,
    _check_serial_device,
    _configure,
    _running,
    _SerialServer,
    _start,
    _TcpServer,
)

_HOLDING_FUNCTIONS = frozenset({3, 6, 16})
_WRITABLE = (
    (hm.HR_ANGLE_SET, hm.N_JOINTS),
    (hm.HR_FORCE_CALIBRATE, 1),
    (hm.HR_FORCE_SET, hm.N_JOINTS),
)


def holding_simdata(layout: hm.Layout) -> list[SimData]:
    """The pymodbus blocks of the mapped holding registers (read-only where not writable)."""
    data = []
    writable = {a for first, n in _WRITABLE for a in range(first, first + n)}
    address = hm.CONTROL_FIRST
    while address <= hm.CONTROL_LAST:
        end = address
        while end + 1 <= hm.CONTROL_LAST and ((end + 1) in writable) == (address in writable):
            end += 1
        count = end - address + 1
        data.append(
            SimData(
                address, count=count, values=0, datatype=DataType.REGISTERS, readonly=address not in writable
            )
        )
        address = end + 1
    for r in hm.REGIONS:
        first = layout.region_address(r)
        data.append(SimData(first, count=r.size, values=0, datatype=DataType.REGISTERS, readonly=True))
    return data


class HandBinding:
    """Connects a ``HandDevice`` to its pymodbus ``SimDevice``."""

    def __init__(self, hand: HandDevice) -> None:
        self.hand = hand
        bits = [SimData(0, count=16, values=False, datatype=DataType.BITS)]
        inputs = [SimData(0, values=0, datatype=DataType.UINT16)]
        holding = holding_simdata(hand.layout)
        self.device = SimDevice(id=hand.device_id, simdata=(bits, bits, holding, inputs), action=self.action)

    async def action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        if function_code not in _HOLDING_FUNCTIONS:
            return ExcCodes.ILLEGAL_ADDRESS
        try:
            if set_values:
                self.hand.write(address, [int(v) for v in set_values])
                return None
            registers[address - start_address : address - start_address + count] = self.hand.read(
                address, count
            )
        except HandWriteError as exc:
            return ExcCodes(exc.code)
        return None


def _prepare(hand: HandDevice) -> list[SimDevice]:
    return [HandBinding(hand).device]


class _HandFace:
    """The palm's array as the server's device (its clock and faults), answering function 43
    with the hand's identification rather than the palm grid's."""

    def __init__(self, hand: HandDevice) -> None:
        self._hand = hand
        self._palm = hand.arrays["palm"]

    def identity(self) -> dict[str, str]:
        return self._hand.identity()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._palm, name)


def _face(hand: HandDevice) -> SimArray:
    return cast(SimArray, _HandFace(hand))


@contextlib.asynccontextmanager
async def serve_hand_tcp(
    hand: HandDevice, host: str = "127.0.0.1", port: int = 0, framer: str = "socket"
) -> AsyncIterator[SimServer]:
    """Serve the hand over Modbus TCP (``framer="socket"``) or RTU framing over TCP (``"rtu"``);
    port 0: an ephemeral one (``SimServer.port``)."""
    if framer not in ("socket", "rtu"):
        raise ValueError(f'framer must be "socket" or "rtu", got {framer!r}')
    server = _TcpServer(_prepare(hand), framer=FramerType(framer), address=(host, port))
    palm = _face(hand)
    _configure(server, [palm], framer == "rtu", False, None)
    await _start(server, f"{host}:{port}")
    bound = server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]
    kind = "rtu-tcp" if framer == "rtu" else "tcp"
    async with _running(SimServer(server, [palm], kind, host, int(bound), ""), None) as sim:
        yield sim


@contextlib.asynccontextmanager
async def serve_hand_serial(
    hand: HandDevice,
    port: str,
    baudrate: int = 115200,
    line_timing: bool = True,
    turnaround_s: float = 0.0,
) -> AsyncIterator[SimServer]:
    """Serve the hand as an RTU device on a serial line (``port``: the device path), 8N1."""
    if not (isinstance(baudrate, int) and baudrate > 0):
        raise ValueError(f"baudrate must be a positive integer, got {baudrate!r}")
    _check_serial_device(port)
    server = _SerialServer(_prepare(hand), framer=FramerType.RTU, port=port, baudrate=baudrate)
    palm = _face(hand)
    _configure(server, [palm], True, True, LineTiming(baudrate, turnaround_s) if line_timing else None)
    await _start(server, f"serial device {port}")
    async with _running(SimServer(server, [palm], "serial", "", 0, port), None) as sim:
        yield sim
