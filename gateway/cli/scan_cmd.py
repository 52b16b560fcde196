"""``tactile-gateway scan``: find where an undocumented Modbus board keeps its ADC frame.

One unit, over Modbus TCP (``--host``) or RTU (``--serial``). A first pass finds the readable
registers of the ``--input``/``--holding`` ranges: reads of at most 125 registers, and a read
the device refuses as an illegal address (exception 2; also 3 and 4, which some devices answer
instead), or answers with fewer registers than asked, is split in halves down to single
registers, so one hole does not hide its neighbours. Then ``--rounds`` rounds, ``--interval``
s apart, read only the readable registers, so that every round takes the same short time and a
clock's rate against host time comes out right. Function 43/14 (device identification) is
tried once at the end: a device that does not know it may drop the connection.

On a terminal the register table is redrawn every round, registers that changed since the
previous round in reverse video; otherwise the final table is printed once, registers that
changed during the scan marked ``*``. Then the identification, the suggestions of
``gateway.modbus.scan`` (ADC frames, clocks, constants) and a configuration snippet.

The scan only reads (functions 3, 4 and 43): it never writes to the device. A connection
that fails, a timeout or an answer that makes no sense is one line on stderr and exit 1.

The command is thin: the reading is ``gateway.modbus.scan_read``, the register table and
live view ``scan_table``, the report ``scan_report``; their names are re-exported here.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import signal
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import click

from ..errors import GatewayError
from ..modbus.backends import open_transport
from ..modbus.endpoint import BusKind, Endpoint, SerialClient, TlsSettings
from ..modbus.register_map import RegisterKind
from ..modbus.scan import analyse
from ..modbus.scan_read import BISECT_CODES as BISECT_CODES
from ..modbus.scan_read import ILLEGAL_FUNCTION as ILLEGAL_FUNCTION
from ..modbus.scan_read import TABLES as TABLES
from ..modbus.scan_read import Range, RoundView, ScanRun, TableReader, scan_device
from ..modbus.scan_read import Registers as Registers
from ..modbus.transport import Transport
from .scan_report import SHOWN_FRAMES as SHOWN_FRAMES
from .scan_report import report_json, report_lines
from .scan_table import ROW as ROW
from .scan_table import LiveView, render_table
from .scan_table import changed_between as changed_between

__all__ = ["ScanEndpoint", "TableReader", "parse_ranges", "scan", "scan_device", "transport_factory"]

EXIT_UNREACHABLE = 1


@dataclass(frozen=True)
class ScanEndpoint:
    """The bus of a scan, from the command line (a ``gateway.modbus.endpoint.Endpoint``)."""

    kind: BusKind
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
    serial_client: SerialClient = SerialClient.PYMODBUS

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", BusKind(self.kind))
        object.__setattr__(self, "serial_client", SerialClient(self.serial_client))


#: Builds the transport of a scan; tests put an in-process bus here.
transport_factory: Callable[[Endpoint], Transport] = open_transport


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


# --------------------------------------------------------------------------- the command
def _target(bus: ScanEndpoint) -> str:
    if bus.kind is BusKind.RTU:
        return f"{bus.serial_port} ({bus.baudrate} baud, parity {bus.parity})"
    return f"{bus.host}:{bus.port} ({bus.kind})"


async def _run(
    bus: ScanEndpoint,
    device_id: int,
    ranges: Mapping[RegisterKind, Sequence[Range]],
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

    Finds the readable registers (refused and short reads are split down to single registers), reads
    them --rounds times, then lists ADC frame candidates, clocks, constant registers, the
    device identification and a configuration snippet. Only reads: never writes to the
    device. Exit status 1 if the device cannot be reached or does not answer.
    """
    if (host is None) == (serial_port is None):
        raise click.UsageError("give --host (Modbus TCP) or --serial (Modbus RTU), one of them")
    if input_text is None and holding_text is None:
        raise click.UsageError("give --input and/or --holding: the register ranges to read")
    ranges: dict[RegisterKind, list[Range]] = {}
    if input_text is not None:
        ranges[RegisterKind.INPUT] = parse_ranges(input_text, "--input")
    if holding_text is not None:
        ranges[RegisterKind.HOLDING] = parse_ranges(holding_text, "--holding")
    if serial_port is not None:
        bus = ScanEndpoint(
            BusKind.RTU, serial_port=serial_port, baudrate=baud, parity=parity, timeout_s=timeout_s
        )
    else:
        bus = ScanEndpoint(BusKind.TCP, host=host, port=port, timeout_s=timeout_s)
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
