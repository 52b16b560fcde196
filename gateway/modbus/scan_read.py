"""Reading an unknown device's registers for ``tactile-gateway scan`` (read functions only).

A first pass finds the readable registers of the requested ranges: reads of at most 125
registers, and a read the device refuses as an illegal address (exception 2; also 3 and 4,
which some devices answer instead), or answers with fewer registers than asked (a device that
stops at the end of its map, or reads at most so many at once), is split in halves down to
single registers, so one hole does not hide its neighbours. The registers of a short answer
are not used: which addresses they are is not said. Then ``rounds`` rounds, ``interval_s``
apart, read only the readable registers, so that every round takes the same short time and a
clock's rate against host time comes out right. Function 43/14 (device identification) is
tried once at the end. The snapshots go to ``gateway.modbus.scan`` for analysis.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from ..errors import DeviceError, DeviceExceptionResponse, DeviceTimeoutError, ShortAnswerError
from .register_map import MAX_READ_REGISTERS, RegisterKind
from .scan import Snapshot
from .transport import Transport

__all__ = ["ScanRun", "TableReader", "scan_device"]

#: Register tables in the order they are read and shown.
TABLES: tuple[RegisterKind, ...] = (RegisterKind.INPUT, RegisterKind.HOLDING)
#: Exception codes that mean "not these addresses": the read is split.
BISECT_CODES = frozenset({2, 3, 4})
ILLEGAL_FUNCTION = 1

Registers = dict[str, dict[int, int | None]]
Range = tuple[int, int]


def _chunks(ranges: Sequence[Range]) -> list[tuple[int, int]]:
    """(start, count) reads of at most ``MAX_READ_REGISTERS`` registers covering ``ranges``."""
    out: list[tuple[int, int]] = []
    for lo, hi in ranges:
        for start in range(lo, hi + 1, MAX_READ_REGISTERS):
            out.append((start, min(MAX_READ_REGISTERS, hi + 1 - start)))
    return out


def _ranges_of(addresses: Sequence[int]) -> list[Range]:
    ranges: list[Range] = []
    for a in sorted(addresses):
        if ranges and ranges[-1][1] == a - 1:
            ranges[-1] = (ranges[-1][0], a)
        else:
            ranges.append((a, a))
    return ranges


class _TableUnsupported(Exception):
    pass


class TableReader:
    """Reads the ranges of one register table of one device with read functions only.

    The first ``read`` finds the readable registers (splitting refused reads); later ones
    read only those, split again if the device refuses one of them after all.
    """

    def __init__(
        self, transport: Transport, device_id: int, table: RegisterKind, ranges: Sequence[Range]
    ) -> None:
        self.transport = transport
        self.device_id = device_id
        self.table = RegisterKind(table)  # a misspelt table is a ValueError naming both
        self.addresses = [a for lo, hi in ranges for a in range(lo, hi + 1)]
        self.unsupported = False
        self._spans = _chunks(ranges)
        self._discovered = False
        self._answered = 0

    async def _request(self, address: int, count: int) -> list[int]:
        return await self.transport.read_registers(self.device_id, self.table, address, count)

    async def read(self) -> dict[int, int | None]:
        """Every address of the ranges: its value, or None where the device refused it."""
        found: dict[int, int] = {}
        if not self.unsupported:
            try:
                for start, count in self._spans:
                    await self._read_span(start, count, found)
            except _TableUnsupported:
                self.unsupported = True
                found.clear()
        if not self._discovered:
            self._discovered = True
            self._spans = _chunks(_ranges_of(list(found)))
        return {a: found.get(a) for a in self.addresses}

    async def _read_span(self, start: int, count: int, found: dict[int, int]) -> None:
        try:
            values = await self._request(start, count)
        except DeviceExceptionResponse as exc:
            if exc.exception_code == ILLEGAL_FUNCTION:
                raise _TableUnsupported from exc
            if exc.exception_code not in BISECT_CODES:
                raise
            await self._split(start, count, found)
            return
        except ShortAnswerError:
            await self._split(start, count, found)
            return
        except DeviceTimeoutError as exc:
            if self._answered and not self._discovered:
                raise DeviceTimeoutError(
                    f"{exc} (the device answered other reads: some devices stay silent on "
                    "registers they do not have; scan smaller ranges)"
                ) from exc
            raise
        self._answered += 1
        found.update(zip(range(start, start + count), values, strict=True))

    async def _split(self, start: int, count: int, found: dict[int, int]) -> None:
        """Read a span the device would not answer whole in two halves (a single register it
        will not answer is unreadable)."""
        if count > 1:
            half = count // 2
            await self._read_span(start, half, found)
            await self._read_span(start + half, count - half, found)


async def _read_round(readers: Sequence[TableReader]) -> Registers:
    return {r.table: await r.read() for r in readers}


@dataclass
class ScanRun:
    """What a scan read: the rounds (without the first pass), identification, notes."""

    snapshots: list[Snapshot] = field(default_factory=list)
    identification: dict[str, str] | None = None
    notes: list[str] = field(default_factory=list)


#: Called after every round with its number, its registers and those of the round before.
RoundView = Callable[[int, Registers, Registers | None], None]


async def scan_device(
    transport: Transport,
    device_id: int,
    ranges: Mapping[RegisterKind, Sequence[Range]],
    rounds: int,
    interval_s: float,
    view: RoundView | None = None,
    stop: asyncio.Event | None = None,
) -> ScanRun:
    """Connect, find the readable registers, read them ``rounds`` times ``interval_s`` apart
    (fewer if ``stop`` is set), try the identification, close. Device errors propagate."""
    readers = [TableReader(transport, device_id, t, ranges[t]) for t in TABLES if t in ranges]
    stop = stop or asyncio.Event()
    run = ScanRun()
    async with transport:
        await _read_round(readers)
        previous: Registers | None = None
        start = time.monotonic()
        for k in range(rounds):
            delay = start + k * interval_s - time.monotonic()
            if k and delay > 0:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), timeout=delay)
            if stop.is_set():
                break
            t0 = time.monotonic()
            data = await _read_round(readers)
            run.snapshots.append(((t0 + time.monotonic()) / 2.0, data))
            if view is not None:
                view(k + 1, data, previous)
            previous = data
        try:
            run.identification = await transport.read_device_identification(device_id) or None
        except DeviceError:
            run.identification = None
    for r in readers:
        if r.unsupported:
            run.notes.append(
                f"the device does not support function {r.table.read_function} ({r.table} registers): "
                "exception 1, illegal function"
            )
    return run
