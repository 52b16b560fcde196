"""The read plan: the Modbus requests one poll of a device makes.

``read_plan`` coalesces the register blocks of ``register_map.register_blocks`` into the
fewest requests a bus allows (at most ``register_map.MAX_READ_REGISTERS`` each, never splitting a
float32); ``device_plan`` adds the device clock when the register map names one.
``block_registers`` reassembles a block from the answers.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Final

from .register_map import (
    MAX_READ_REGISTERS,
    REGISTER_TABLES,
    DeviceClock,
    DeviceLayout,
    RegisterBlock,
    RegisterKind,
    RegisterSpace,
    register_blocks,
)
from .vendor_fc import VendorRead

__all__ = [
    "MAX_GAP_REGISTERS",
    "MERGE_GAP",
    "ReadRequest",
    "block_registers",
    "device_plan",
    "plan_with_device_time",
    "read_plan",
]

#: Two register ranges at most this many registers apart are read in one request.
MAX_GAP_REGISTERS: Final = 8


@dataclass(frozen=True)
class ReadRequest:
    """One Modbus read of a poll: ``count`` registers from ``address``.

    ``kind`` is ``"input"`` (function 4) or ``"holding"`` (function 3), or the space of a
    frame block (``register_map.frame_space``): a ``vendor`` read (``address`` is its start
    field, ``count`` the 16-bit words it answers) or a read behind a row select, ``select``
    being the (holding register, value) written first. ``purpose`` names the register blocks
    it covers, in address order, e.g. ``("status", "adc")``.
    """

    kind: RegisterSpace
    address: int
    count: int
    purpose: tuple[str, ...]
    vendor: VendorRead | None = None
    select: tuple[int, int] | None = None

    @property
    def table(self) -> RegisterKind:
        """The register table a standard read uses (``input`` or ``holding``; ``ValueError``
        for a vendor read's space or any other word: no read falls back to a table)."""
        return RegisterKind(self.kind.partition("@")[0])

    @property
    def end(self) -> int:
        """The last address read (inclusive)."""
        return self.address + self.count - 1


def read_plan(
    device: DeviceLayout, max_read_registers: int, max_gap: int = MAX_GAP_REGISTERS
) -> tuple[ReadRequest, ...]:
    """The reads of one poll of ``device``, coalesced into the fewest requests.

    Register ranges of the same kind that touch or lie at most ``max_gap`` registers apart are
    read together (the gap registers are read and ignored); no request is longer than
    ``max_read_registers``, and a float32 value is never split across two requests. Raises
    ``ValueError`` if ``max_read_registers`` cannot hold one value.
    """
    if not 1 <= max_read_registers <= MAX_READ_REGISTERS:
        raise ValueError(f"max_read_registers = {max_read_registers} is outside 1..{MAX_READ_REGISTERS}")
    if max_gap < 0:
        raise ValueError(f"max_gap = {max_gap} must be >= 0")
    blocks = register_blocks(device, clock=False)
    widest = max((b.value_registers for b in blocks if b.kind in REGISTER_TABLES), default=1)
    if widest > max_read_registers:
        raise ValueError(
            f"max_read_registers = {max_read_registers} cannot hold a float32 value (2 registers, "
            f"never split across reads); allowed: 2..{MAX_READ_REGISTERS}"
        )
    requests: list[ReadRequest] = []
    for kind in (RegisterKind.HOLDING, RegisterKind.INPUT):
        # Every value of every block as (start, registers, purpose), in address order.
        units = sorted(
            (b.address + k * b.value_stride, b.value_registers, b.purpose)
            for b in blocks
            if b.kind == kind
            for k in range(b.n_values)
        )
        start = end = -1
        purposes: list[str] = []
        for unit_start, width, purpose in units:
            unit_end = unit_start + width - 1
            if (
                start >= 0
                and unit_start - end - 1 <= max_gap
                and max(end, unit_end) - start < max_read_registers
            ):
                end = max(end, unit_end)
                if purpose not in purposes:
                    purposes.append(purpose)
                continue
            if start >= 0:
                requests.append(ReadRequest(kind, start, end - start + 1, tuple(purposes)))
            start, end, purposes = unit_start, unit_end, [purpose]
        if start >= 0:
            requests.append(ReadRequest(kind, start, end - start + 1, tuple(purposes)))
    requests.extend(_frame_requests(device, blocks))
    return tuple(requests)


def _frame_requests(device: DeviceLayout, blocks: Sequence[RegisterBlock]) -> list[ReadRequest]:
    """A request of its own for each frame block read through a vendor function or behind a
    row select (neither merges with anything): in frame order, each row's select first."""
    frame = device.registers.frame
    if frame is None:
        return []
    out: list[ReadRequest] = []
    for block, fb in zip((b for b in blocks if b.purpose == "frame"), frame.blocks, strict=True):
        if block.kind in REGISTER_TABLES:
            continue
        select = None
        if fb.row is not None and frame.row_select_address is not None:
            select = (frame.row_select_address, fb.row)
        out.append(ReadRequest(block.kind, block.address, block.count, ("frame",), frame.vendor, select))
    return out


def block_registers(
    block: RegisterBlock, responses: Iterable[tuple[ReadRequest, Sequence[int]]]
) -> list[int]:
    """Assemble the registers of ``block`` from the answers to a read plan.

    ``responses`` pairs each request with the registers it returned. Raises ``ValueError`` if
    the answers do not cover the whole block.
    """
    out: list[int | None] = [None] * block.count
    for request, registers in responses:
        if request.kind != block.kind:
            continue
        if len(registers) != request.count:
            raise ValueError(
                f"read of {request.count} registers at {request.address} returned {len(registers)} registers"
            )
        low = max(block.address, request.address)
        high = min(block.end, request.end)
        for address in range(low, high + 1):
            out[address - block.address] = registers[address - request.address]
    missing = [block.address + i for i, v in enumerate(out) if v is None]
    if missing:
        raise ValueError(f"block {block.name} misses register {missing[0]} in the responses")
    return [v for v in out if v is not None]


# ------------------------------------------------------------------ the reads of one poll
#: Reads merge across gaps of at most this many registers. The three status bitmaps are 16
#: registers apart and every register between them exists (docs/register-map.md), so the
#: bitmaps of any channel count come in one request. Registers in a wider gap may not exist
#: (a device answers exception 2), so nothing wider is merged; a device that refuses a
#: merged read anyway falls back to unmerged reads.
MERGE_GAP = 15


def plan_with_device_time(
    plan: tuple[ReadRequest, ...], clock: DeviceClock, max_read_registers: int
) -> tuple[ReadRequest, ...]:
    """Add the device clock to a read plan.

    The clock makes the creep time steps right whatever the poll timing (and with a
    simulator running faster than real time). Its request goes first: the values are read
    as soon after the time as the bus allows, and a device that latches a frame when its
    clock is read (as data loggers with a snapshot register do) answers the rest of the poll
    from that instant. It joins a read of its table that touches or
    adjoins it, else it is one more request: registers across a wider gap may not exist
    (the simulator's 7-15 do not), so the clock never rides on a read over unknown ground.
    """
    lo, hi = clock.address, clock.address + clock.registers - 1
    same = [r for r in plan if r.kind == clock.table]
    if any(r.address <= lo and r.end >= hi for r in same):
        return _clock_first(
            ReadRequest(r.kind, r.address, r.count, ("device_time", *r.purpose))
            if r.address <= lo and r.end >= hi and "device_time" not in r.purpose
            else r
            for r in plan
        )
    for r in same:
        start, end = min(r.address, lo), max(r.end, hi)
        if r.address <= hi + 1 and r.end >= lo - 1 and end - start + 1 <= max_read_registers:
            merged = ReadRequest(r.kind, start, end - start + 1, ("device_time", *r.purpose))
            return _clock_first(merged if q is r else q for q in plan)
    return (ReadRequest(clock.table, lo, clock.registers, ("device_time",)), *plan)


def _clock_first(plan: Iterable[ReadRequest]) -> tuple[ReadRequest, ...]:
    """The plan with the request that reads the clock first (the others in their order)."""
    return tuple(sorted(plan, key=lambda r: "device_time" not in r.purpose))


def device_plan(
    device: DeviceLayout, max_read_registers: int, merge_gap: int, clock: bool
) -> tuple[ReadRequest, ...]:
    """The reads of one poll: the configuration's ``read_plan`` (coalesced across gaps of
    ``merge_gap`` registers) plus the device clock when the map names one and ``clock``."""
    plan = tuple(read_plan(device, max_read_registers, max_gap=merge_gap))
    device_clock = device.registers.clock
    if not clock or device_clock is None:
        return plan
    return plan_with_device_time(plan, device_clock, max_read_registers)
