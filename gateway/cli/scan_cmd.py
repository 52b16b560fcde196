"""``tactile-gateway scan``: find where an undocumented Modbus board keeps its ADC frame.

One unit, over Modbus TCP (``--host``) or RTU (``--serial``). A first pass finds the
readable registers of the ``--input``/``--holding`` ranges: reads of at most 125 registers,
and a read the device refuses as an illegal address (exception 2; also 3 and 4, which some
devices answer instead) is split in halves down to single registers, so one hole does not
hide its neighbours. Then ``--rounds`` rounds, ``--interval`` s apart, read only the
readable registers, so that every round takes the same short time and a clock's rate
against host time comes out right. Function 43/14 (device identification) is tried once
at the end: a device that does not know it may drop the connection.

On a terminal the register table is redrawn every round, registers that changed since the
previous round in reverse video; otherwise the final table is printed once, registers that
changed during the scan marked ``*``. Then the identification, the suggestions of
``gateway.modbus.scan`` (ADC frames, clocks, constants) and a configuration snippet.

The scan only reads (functions 3, 4 and 43): it never writes to the device. A connection
that fails, a timeout or an answer that makes no sense is one line on stderr and exit 1.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import shutil
import signal
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TextIO

import click

from ..errors import DeviceError, DeviceExceptionResponse, DeviceTimeoutError, GatewayError
from ..modbus.client import ModbusTransport
from ..modbus.endpoint import Endpoint, TlsSettings
from ..modbus.scan import ScanResult, Snapshot, analyse, config_snippet, constant_runs, printable_text
from ..modbus.transport import MAX_READ_COUNT, Transport

__all__ = ["ScanEndpoint", "TableReader", "parse_ranges", "scan", "scan_device", "transport_factory"]

EXIT_UNREACHABLE = 1
#: Register tables in the order they are read and shown, with their read function codes.
TABLES: dict[str, int] = {"input": 4, "holding": 3}
#: Exception codes that mean "not these addresses": the read is split.
BISECT_CODES = frozenset({2, 3, 4})
ILLEGAL_FUNCTION = 1
#: Registers per row of the table.
ROW = 10
#: Frame candidates listed.
SHOWN_FRAMES = 5

Registers = dict[str, dict[int, int | None]]
Range = tuple[int, int]


@dataclass(frozen=True)
class ScanEndpoint:
    """The bus of a scan, from the command line (a ``gateway.modbus.endpoint.Endpoint``)."""

    kind: str
    host: str | None = None
    port: int | None = None
    serial_port: str | None = None
    baudrate: int = 19200
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8
    timeout_s: float = 1.0
    name: str = "scan"
    tls: TlsSettings | None = None


def _modbus_transport(bus: Endpoint) -> Transport:
    return ModbusTransport(bus)


#: Builds the transport of a scan; tests put an in-process bus here.
transport_factory: Callable[[Endpoint], Transport] = _modbus_transport


# --------------------------------------------------------------------------- ranges
def parse_ranges(text: str, what: str) -> list[Range]:
    """``"0-200"``, ``"7"`` or a comma-separated list of both: inclusive ranges within
    0..65535, sorted and merged; a click error names the bad item."""
    ranges: list[Range] = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        first, sep, last = item.partition("-")
        try:
            lo = int(first.strip())
            hi = int(last.strip()) if sep else lo
        except ValueError:
            raise click.BadParameter(
                f"{item!r} is not a register range: A-B (inclusive) or A", param_hint=what
            ) from None
        if not (0 <= lo <= 0xFFFF and 0 <= hi <= 0xFFFF):
            raise click.BadParameter(f"{item!r}: register addresses are 0..65535", param_hint=what)
        if hi < lo:
            raise click.BadParameter(f"{item!r}: the range ends before it starts", param_hint=what)
        ranges.append((lo, hi))
    if not ranges:
        raise click.BadParameter("needs a register range: A-B (inclusive) or A", param_hint=what)
    merged: list[Range] = []
    for lo, hi in sorted(ranges):
        if merged and lo <= merged[-1][1] + 1:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


def _chunks(ranges: Sequence[Range]) -> list[tuple[int, int]]:
    """(start, count) reads of at most ``MAX_READ_COUNT`` registers covering ``ranges``."""
    out: list[tuple[int, int]] = []
    for lo, hi in ranges:
        for start in range(lo, hi + 1, MAX_READ_COUNT):
            out.append((start, min(MAX_READ_COUNT, hi + 1 - start)))
    return out


def _ranges_of(addresses: Sequence[int]) -> list[Range]:
    ranges: list[Range] = []
    for a in sorted(addresses):
        if ranges and ranges[-1][1] == a - 1:
            ranges[-1] = (ranges[-1][0], a)
        else:
            ranges.append((a, a))
    return ranges


# --------------------------------------------------------------------------- reading
class _TableUnsupported(Exception):
    pass


class TableReader:
    """Reads the ranges of one register table of one device with read functions only.

    The first ``read`` finds the readable registers (splitting refused reads); later ones
    read only those, split again if the device refuses one of them after all.
    """

    def __init__(self, transport: Transport, device_id: int, table: str, ranges: Sequence[Range]) -> None:
        if table not in TABLES:
            raise ValueError(f"unknown register table {table!r}")
        self.transport = transport
        self.device_id = device_id
        self.table = table
        self.addresses = [a for lo, hi in ranges for a in range(lo, hi + 1)]
        self.unsupported = False
        self._spans = _chunks(ranges)
        self._discovered = False
        self._answered = 0

    async def _request(self, address: int, count: int) -> list[int]:
        if self.table == "input":
            return await self.transport.read_input_registers(self.device_id, address, count)
        return await self.transport.read_holding_registers(self.device_id, address, count)

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
            if count > 1:
                half = count // 2
                await self._read_span(start, half, found)
                await self._read_span(start + half, count - half, found)
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
    ranges: Mapping[str, Sequence[Range]],
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
                f"the device does not support function {TABLES[r.table]} ({r.table} registers): "
                "exception 1, illegal function"
            )
    return run


# --------------------------------------------------------------------------- the table
def _cell(value: int | None, in_range: bool, marked: bool, ansi: bool) -> str:
    text = "      " if not in_range else ("    --" if value is None else f"{value:6d}")
    if marked and ansi:
        return f"\x1b[7m{text}\x1b[0m "
    return text + ("*" if marked else " ")


def render_table(
    data: Mapping[str, Mapping[int, int | None]], marked: set[tuple[str, int]], ansi: bool
) -> list[str]:
    """The registers ``ROW`` to a line, unreadable ones as ``--``; ``marked`` ones in reverse
    video (``ansi``) or followed by ``*``. Consecutive rows without a readable register
    shrink to one line."""
    lines: list[str] = []
    for table, values in data.items():
        if not values:
            continue
        if lines:
            lines.append("")
        lines.append(f"{table:>7} " + " ".join(f"{'+' + str(k):>6}" for k in range(ROW)))
        rows: dict[int, list[int]] = {}
        for a in sorted(values):
            rows.setdefault(a // ROW, []).append(a)
        blank: list[int] = []  # consecutive rows without a readable register
        for row in [*sorted(rows), None]:
            readable = row is not None and any(values[a] is not None for a in rows[row])
            if row is not None and not readable and (not blank or blank[-1] == row - 1):
                blank.append(row)
                continue
            if len(blank) == 1:
                lines.append(_row_line(table, blank[0], values, marked, ansi))
            elif blank:
                lines.append(f"{rows[blank[0]][0]:>7}-{rows[blank[-1]][-1]}: unreadable")
            blank = [] if readable or row is None else [row]
            if readable and row is not None:
                lines.append(_row_line(table, row, values, marked, ansi))
    return lines


def _row_line(
    table: str, row: int, values: Mapping[int, int | None], marked: set[tuple[str, int]], ansi: bool
) -> str:
    cells = [
        _cell(values.get(a), a in values, (table, a) in marked, ansi)
        for a in range(row * ROW, row * ROW + ROW)
    ]
    return f"{row * ROW:>7} " + "".join(cells).rstrip()


def changed_between(
    now: Mapping[str, Mapping[int, int | None]], before: Registers | None
) -> set[tuple[str, int]]:
    """Registers read in both rounds with different values."""
    if before is None:
        return set()
    return {
        (table, a)
        for table, values in now.items()
        for a, v in values.items()
        if v is not None and before.get(table, {}).get(a) is not None and before[table][a] != v
    }


class LiveView:
    """Redraws the table on a terminal every round (ANSI), changes in reverse video; cut to
    the terminal's height (``truncated`` then: the full table is printed at the end)."""

    def __init__(self, out: TextIO, title: str, rounds: int, height: int | None = None) -> None:
        self.out = out
        self.title = title
        self.rounds = rounds
        self.height = height if height is not None else shutil.get_terminal_size().lines
        self.last: Registers | None = None
        self.truncated = False

    def __call__(self, k: int, data: Registers, previous: Registers | None) -> None:
        table = render_table(data, changed_between(data, previous), ansi=True)
        room = max(1, self.height - 5)
        if len(table) > room:
            self.truncated = True
            table = [*table[: room - 1], "  ... (the whole table follows at the end)"]
        lines = [f"{self.title}: round {k} of {self.rounds} (Ctrl-C stops and analyses)", "", *table]
        lines += ["", "reverse video: changed since the previous round; --: unreadable"]
        clear = "\x1b[2J" if self.last is None else ""
        self.out.write(clear + "\x1b[H" + "\x1b[K\n".join(lines) + "\x1b[K\n\x1b[J")
        self.out.flush()
        self.last = data


# --------------------------------------------------------------------------- the report
def _values_text(values: list[int]) -> str:
    if len(values) >= 4 and len(set(values)) == 1:
        return f"0x{values[0]:04X} x{len(values)}"
    shown = " ".join(f"0x{v:04X}" for v in values[:12])
    return shown + (f" ... ({len(values) - 12} more)" if len(values) > 12 else "")


def _span(table: str, address: int, count: int) -> str:
    return f"{table} {address}" if count == 1 else f"{table} {address}-{address + count - 1}"


def report_lines(result: ScanResult, run: ScanRun, device_id: int) -> list[str]:
    """Identification, notes and suggestions as text."""
    lines: list[str] = []
    if run.identification:
        lines.append("identification (FC 43/14):")
        lines += [f"  {name}: {value}" for name, value in run.identification.items()]
    else:
        lines.append("identification (FC 43/14): no answer")
    lines += [f"note: {n}" for n in run.notes]
    if result.snapshots < 3:
        lines.append(f"note: {result.snapshots} round(s): clocks need 3, changes need 2 (--rounds)")
    lines += ["", "ADC frame candidates, best first:"]
    for i, f in enumerate(result.frames[:SHOWN_FRAMES], 1):
        kind = ", reads as float32 pairs (encoding float32?)" if f.float_like else ""
        lines.append(
            f"  {i}. {_span(f.table, f.address, f.count)}: {f.count} registers, {f.bits}-bit codes "
            f"(max {f.maximum}), {f.changed} of {f.count} changed, score {f.score:g}{kind}"
        )
    if not result.frames:
        lines.append("  none: no run of 4 or more readable registers that changes")
    lines.append("clock candidates:")
    for c in result.clocks:
        lines.append(
            f"  {_span(c.table, c.address, c.registers)}: {c.type_name} rising {c.rate_per_s:.4g}/s: "
            f"{c.description}"
        )
    if not result.clocks:
        lines.append("  none: no register rises steadily with time")
    lines.append("constant registers (identification/version candidates):")
    for table, address, values in constant_runs(result.constants):
        text = printable_text(values)
        quoted = "  text " + ", ".join(f'"{t}"' for t in text) if text else ""
        lines.append(f"  {_span(table, address, len(values))}: {_values_text(values)}{quoted}")
    if not result.constants:
        lines.append("  none")
    snippet = config_snippet(result, device_id)
    if snippet is not None:
        lines += [
            "",
            "suggested configuration (a starting point: check it with tactile-gateway check-config):",
        ]
        lines += snippet.rstrip("\n").split("\n")
    return lines


def report_json(result: ScanResult, run: ScanRun, device_id: int, target: str) -> dict[str, Any]:
    """A JSON-ready view of the scan."""
    registers: dict[str, list[dict[str, Any]]] = {t: [] for t in result.tables}
    for s in result.registers:
        registers[s.table].append(
            {
                "address": s.address,
                "readable": s.readable,
                "min": s.minimum,
                "max": s.maximum,
                "distinct": s.distinct,
                "changed": s.changed,
                "last": s.last,
            }
        )
    return {
        "device_id": device_id,
        "target": target,
        "rounds": result.snapshots,
        "identification": run.identification,
        "notes": run.notes,
        "registers": registers,
        "frames": [
            {
                "table": f.table,
                "address": f.address,
                "count": f.count,
                "bits": f.bits,
                "changed": f.changed,
                "max": f.maximum,
                "score": f.score,
                "float_like": f.float_like,
            }
            for f in result.frames
        ],
        "clocks": [
            {
                "table": c.table,
                "address": c.address,
                "registers": c.registers,
                "type": c.type_name,
                "rate_per_s": c.rate_per_s,
                "unit": c.unit,
                "tick_s": c.tick_s,
                "description": c.description,
            }
            for c in result.clocks
        ],
        "constants": [
            {"table": c.table, "address": c.address, "value": c.value, "hex": f"0x{c.value:04X}"}
            for c in result.constants
        ],
        "config": config_snippet(result, device_id),
    }


# --------------------------------------------------------------------------- the command
def _target(bus: ScanEndpoint) -> str:
    if bus.kind == "rtu":
        return f"{bus.serial_port} ({bus.baudrate} baud, parity {bus.parity})"
    return f"{bus.host}:{bus.port} ({bus.kind})"


async def _run(
    bus: ScanEndpoint,
    device_id: int,
    ranges: Mapping[str, Sequence[Range]],
    rounds: int,
    interval_s: float,
    view: RoundView | None,
) -> ScanRun:
    """The scan with Ctrl-C (SIGINT) ending the rounds early instead of the program."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    handled = False
    with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
        loop.add_signal_handler(signal.SIGINT, stop.set)
        handled = True
    try:
        return await scan_device(transport_factory(bus), device_id, ranges, rounds, interval_s, view, stop)
    finally:
        if handled:
            loop.remove_signal_handler(signal.SIGINT)


@click.command("scan")
@click.option("--host", help="address of the device or Modbus TCP gateway (Modbus TCP)")
@click.option("--port", default=502, show_default=True, type=click.IntRange(1, 65535), help="TCP port")
@click.option(
    "--unit", "device_id", required=True, type=click.IntRange(0, 247), help="Modbus unit (device) id"
)
@click.option(
    "--input",
    "input_text",
    metavar="RANGES",
    help='input registers to read (function 4): "0-200" inclusive, "7", or a list "0-9,100-131"',
)
@click.option("--holding", "holding_text", metavar="RANGES", help="holding registers to read (function 3)")
@click.option(
    "--rounds",
    default=20,
    show_default=True,
    type=click.IntRange(1, 1_000_000),
    help="rounds of reads after the first pass",
)
@click.option(
    "--interval",
    "interval_s",
    default=0.2,
    show_default=True,
    type=click.FloatRange(0.0, 3600.0),
    help="seconds between the starts of two rounds",
)
@click.option("--serial", "serial_port", metavar="DEVICE", help="serial port: Modbus RTU instead of --host")
@click.option("--baud", default=19200, show_default=True, type=click.IntRange(min=1), help="RTU baud rate")
@click.option(
    "--parity", default="N", show_default=True, type=click.Choice(["N", "E", "O"]), help="RTU parity"
)
@click.option(
    "--timeout",
    "timeout_s",
    default=1.0,
    show_default=True,
    type=click.FloatRange(0.0, 60.0, min_open=True),
    help="seconds to wait for each answer",
)
@click.option("--json", "as_json", is_flag=True, help="print JSON instead of tables")
def scan(
    host: str | None,
    port: int,
    device_id: int,
    input_text: str | None,
    holding_text: str | None,
    rounds: int,
    interval_s: float,
    serial_port: str | None,
    baud: int,
    parity: str,
    timeout_s: float,
    as_json: bool,
) -> None:
    """Read register ranges of an unknown device repeatedly and suggest its map.

    Finds the readable registers (refused reads are split down to single registers), reads
    them --rounds times, then lists ADC frame candidates, clocks, constant registers, the
    device identification and a configuration snippet. Only reads: never writes to the
    device. Exit status 1 if the device cannot be reached or does not answer.
    """
    if (host is None) == (serial_port is None):
        raise click.UsageError("give --host (Modbus TCP) or --serial (Modbus RTU), one of them")
    if input_text is None and holding_text is None:
        raise click.UsageError("give --input and/or --holding: the register ranges to read")
    ranges: dict[str, list[Range]] = {}
    if input_text is not None:
        ranges["input"] = parse_ranges(input_text, "--input")
    if holding_text is not None:
        ranges["holding"] = parse_ranges(holding_text, "--holding")
    if serial_port is not None:
        bus = ScanEndpoint("rtu", serial_port=serial_port, baudrate=baud, parity=parity, timeout_s=timeout_s)
    else:
        bus = ScanEndpoint("tcp", host=host, port=port, timeout_s=timeout_s)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # its errors are reported as ours
    out = sys.stdout
    title = f"unit {device_id} on {_target(bus)}"
    view = LiveView(out, title, rounds) if not as_json and out.isatty() else None
    try:
        run = asyncio.run(_run(bus, device_id, ranges, rounds, interval_s, view))
    except GatewayError as exc:
        if view is not None and view.last is not None:
            out.write("\n")
        click.echo(f"tactile-gateway: {' '.join(str(exc).split())}", err=True)
        sys.exit(EXIT_UNREACHABLE)
    result = analyse(run.snapshots)
    if as_json:
        click.echo(json.dumps(report_json(result, run, device_id, _target(bus)), indent=2))
        return
    lines: list[str] = []
    if view is None or view.truncated:
        last = run.snapshots[-1][1] if run.snapshots else {}
        marked = {(s.table, s.address) for s in result.registers if s.changed}
        lines += [f"{title}: {result.snapshots} round(s) {interval_s:g} s apart", ""]
        lines += render_table(last, marked, ansi=False)
        lines += ["", "*: changed during the scan; --: unreadable", ""]
    else:
        lines.append("")
    lines += report_lines(result, run, device_id)
    click.echo("\n".join(lines))
