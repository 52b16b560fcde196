"""``tactile-gateway scan`` on the in-process virtual bus: chunking, splitting refused reads,
the table, the suggestions, errors as one line, and never a write."""

from __future__ import annotations

import ast
import asyncio
import io
import json
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

from gateway.cli import main, scan_cmd, scan_report, scan_table
from gateway.cli.scan_cmd import LiveView, ScanEndpoint, parse_ranges, render_table, scan_device
from gateway.errors import DeviceExceptionResponse
from gateway.modbus import scan_read
from gateway.modbus.endpoint import Endpoint
from gateway.modbus.transport import Transport
from gateway.modbus.virtual import VirtualDevice, VirtualTransport

IDS = [0x5447, 0x0103, 0x0000, 0x0001, 0xE240, 0x0007]
FRAME, CHANNELS = 32, 36


class Board(VirtualTransport):
    """An undocumented board on the virtual bus: ids at input 0-5, a uint32 ms counter at
    10-11 and 36 noisy 12-bit counts at 32 (nothing else readable); holding 0-3 constant.
    The counter and the noise move on every read; a write fails the test."""

    def __init__(self, silent_on_holes: bool = False) -> None:
        device = VirtualDevice(identification={"VendorName": "Acme", "ProductCode": "AT-6x6"})
        device.set_input(0, IDS)
        device.set_holding(0, [1, 2, 3, 4])
        super().__init__("board", {1: device}, timeout_s=0.2)
        self.device = device
        self.silent_on_holes = silent_on_holes
        self._rng = np.random.default_rng(4)
        self._t0 = time.monotonic()
        self._move()

    def _move(self) -> None:
        ms = 65_000 + round((time.monotonic() - self._t0) * 1000.0)
        self.device.set_input(10, [ms >> 16, ms & 0xFFFF])
        self.device.set_input(FRAME, [int(v) for v in 3000 + self._rng.integers(-3, 4, CHANNELS)])

    async def _read(self, kind: str, device_id: int, address: int, count: int, what: str) -> Sequence[int]:
        self._move()
        image = self.device.input if kind == "input" else self.device.holding
        if self.silent_on_holes and any(a not in image for a in range(address, address + count)):
            self.requests.append((kind, device_id, address, count))
            raise TimeoutError
        return await super()._read(kind, device_id, address, count, what)

    async def _write(self, device_id: int, address: int, values: list[int], what: str) -> None:
        raise AssertionError("the scan wrote to the device")


@pytest.fixture
def board(monkeypatch: pytest.MonkeyPatch) -> Iterator[Board]:
    """The board behind ``scan``'s transport factory; any write through the transport
    interface fails the test."""
    bus = Board()
    seen: list[Endpoint] = []

    def factory(endpoint: Endpoint) -> Transport:
        seen.append(endpoint)
        return bus

    async def no_write(*args: object, **kwargs: object) -> None:
        raise AssertionError("the scan called write_registers")

    monkeypatch.setattr(scan_cmd, "transport_factory", factory)
    monkeypatch.setattr(Transport, "write_registers", no_write)
    bus.endpoints = seen  # type: ignore[attr-defined]
    yield bus
    assert all(kind != "write" for kind, *_ in bus.requests)


def invoke(*args: str) -> Result:
    return CliRunner().invoke(main, ["scan", "--host", "192.0.2.1", "--unit", "1", *args])


def expected_reads(readable: set[int], address: int, count: int) -> list[tuple[int, int]]:
    """The reads of a span when every refused read is split in halves."""
    reads = [(address, count)]
    if count > 1 and not all(a in readable for a in range(address, address + count)):
        half = count // 2
        reads += expected_reads(readable, address, half)
        reads += expected_reads(readable, address + half, count - half)
    return reads


def test_chunks_of_at_most_125_registers(board: Board) -> None:
    board.device.set_input(0, range(300))
    result = invoke("--input", "0-299", "--rounds", "2", "--interval", "0")
    assert result.exit_code == 0, result.output
    chunks = [("input", 1, 0, 125), ("input", 1, 125, 125), ("input", 1, 250, 50)]
    assert board.requests == chunks * 3 + [("identification", 1, 0, 0)]


def test_refused_reads_are_split_down_to_single_registers(board: Board) -> None:
    result = invoke("--input", "0-79", "--rounds", "5", "--interval", "0.05")
    assert result.exit_code == 0, result.output
    readable = {*range(6), 10, 11, *range(FRAME, FRAME + CHANNELS)}
    first_pass = expected_reads(readable, 0, 80)
    assert [(a, n) for _, _, a, n in board.requests[: len(first_pass)]] == first_pass
    later = [(0, 6), (10, 2), (FRAME, CHANNELS)]
    assert [(a, n) for _, _, a, n in board.requests[len(first_pass) : -1]] == later * 5
    lines = result.output.splitlines()
    row0 = next(line for line in lines if line.startswith("      0 "))
    assert row0.split() == ["0", *(str(v) for v in IDS), "--", "--", "--", "--"]
    row20 = next(line for line in lines if line.startswith("     20 "))
    assert row20.split() == ["20", *["--"] * 10]


def test_the_report_names_frame_clock_constants_and_identification(board: Board) -> None:
    result = invoke("--input", "0-79", "--holding", "0-9", "--rounds", "5", "--interval", "0.05")
    assert result.exit_code == 0, result.output
    out = result.output
    assert "unit 1 on 192.0.2.1:502 (tcp): 5 round(s) 0.05 s apart" in out
    assert "1. input 32-67: 36 registers, 12-bit codes" in out
    clock_line = next(line for line in out.splitlines() if "input 10-11: uint32 rising" in line)
    assert clock_line.endswith("/s: ms")
    assert 'input 0-5: 0x5447 0x0103 0x0000 0x0001 0xE240 0x0007  text "TG"' in out
    assert "holding 0-3: 0x0001 0x0002 0x0003 0x0004" in out
    assert "  VendorName: Acme" in out and "  ProductCode: AT-6x6" in out
    assert "adc_address = 32" in out and "channels = 36" in out and 'unit = "ms"' in out
    assert " 3000*" in out or any(f" {v}*" in out for v in range(2997, 3004)), "changed values are marked"
    assert board.endpoints == [ScanEndpoint("tcp", host="192.0.2.1", port=502, timeout_s=1.0)]  # type: ignore[attr-defined]


def test_json_output(board: Board) -> None:
    result = invoke("--input", "0-79", "--rounds", "4", "--interval", "0.05", "--json")
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["rounds"] == 4 and data["identification"]["VendorName"] == "Acme"
    assert data["frames"][0] | {"score": 0} == {
        "table": "input",
        "address": FRAME,
        "count": CHANNELS,
        "bits": 12,
        "changed": data["frames"][0]["changed"],
        "max": data["frames"][0]["max"],
        "score": 0,
        "float_like": False,
    }
    assert [(c["address"], c["registers"], c["unit"]) for c in data["clocks"]] == [(10, 2, "ms")]
    assert {c["address"]: c["hex"] for c in data["constants"]}[0] == "0x5447"
    registers = {r["address"]: r for r in data["registers"]["input"]}
    assert registers[7] == {
        "address": 7,
        "readable": False,
        "min": None,
        "max": None,
        "distinct": 0,
        "changed": False,
        "last": None,
    }
    assert "adc_address = 32" in data["config"]


def test_serial_options_build_an_rtu_endpoint(board: Board) -> None:
    serial = ["--serial", "/dev/ttyUSB7", "--baud", "9600", "--parity", "E", "--timeout", "0.3"]
    result = CliRunner().invoke(
        main, ["scan", *serial, "--unit", "1", "--holding", "0-3", "--rounds", "2", "--interval", "0"]
    )
    assert result.exit_code == 0, result.output
    assert board.endpoints == [  # type: ignore[attr-defined]
        ScanEndpoint("rtu", serial_port="/dev/ttyUSB7", baudrate=9600, parity="E", timeout_s=0.3)
    ]
    assert "unit 1 on /dev/ttyUSB7 (9600 baud, parity E)" in result.output


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("refuse", "cannot connect to virtual bus 'board'"),
        ("unknown unit", "no answer from virtual bus 'board' within 0.2 s"),
        ("exception 11", "exception 11 (gateway target device failed to respond)"),
        ("garbled", "garbled answer"),
    ],
)
def test_errors_are_one_line_and_exit_1(board: Board, setup: str, message: str) -> None:
    args = ["--input", "0-9", "--rounds", "2", "--interval", "0"]
    if setup == "refuse":
        board.refuse_connects = 1
    elif setup == "unknown unit":
        args = ["--unit", "9", *args]
    elif setup == "exception 11":
        board.fail_next(("exception", 11))
    else:
        board.fail_next("garbled")
    result = CliRunner().invoke(main, ["scan", "--host", "192.0.2.1", "--unit", "1", *args])
    assert result.exit_code == 1
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("tactile-gateway: ")
    assert message in result.stderr and "Traceback" not in result.stderr
    assert not board.connected


def test_a_device_silent_on_unmapped_registers_gets_a_hint(board: Board) -> None:
    board.silent_on_holes = True
    result = invoke("--input", "0-5,10-20", "--rounds", "2", "--interval", "0")
    assert result.exit_code == 1
    assert "some devices stay silent on registers they do not have" in result.stderr


def test_a_table_the_device_does_not_have_is_a_note(board: Board) -> None:
    board.fail_next(("exception", 1))
    result = invoke("--holding", "0-3", "--input", "0-5", "--rounds", "3", "--interval", "0")
    assert result.exit_code == 0, result.output
    assert "note: the device does not support function 4 (input registers)" in result.output
    assert [r for r in board.requests if r[0] == "input"] == [("input", 1, 0, 6)]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--input", "5-3"], "'5-3': the range ends before it starts"),
        (["--input", "0-70000"], "'0-70000': register addresses are 0..65535"),
        (["--holding", "1-x"], "'1-x' is not a register range"),
        (["--input", ","], "needs a register range"),
        ([], "give --input and/or --holding"),
        (["--input", "0", "--serial", "/dev/ttyS0"], "give --host (Modbus TCP) or --serial (Modbus RTU)"),
        (["--input", "0", "--rounds", "0"], "--rounds"),
    ],
)
def test_bad_options_are_usage_errors(board: Board, args: list[str], message: str) -> None:
    result = invoke(*args)
    assert result.exit_code == 2
    assert message in result.stderr
    assert board.requests == []


def test_parse_ranges_merges_and_sorts() -> None:
    assert parse_ranges("100-110, 7,0-5,6,105-120", "--input") == [(0, 7), (100, 120)]
    assert parse_ranges("65535", "--input") == [(65535, 65535)]


def test_the_table_shrinks_unreadable_rows_and_marks_changes() -> None:
    data = {"input": {**dict.fromkeys(range(0, 40)), 3: 7, 35: 9}}
    lines = render_table(data, {("input", 3)}, ansi=False)
    assert lines[1].split() == ["0", "--", "--", "--", "7*", "--", "--", "--", "--", "--", "--"]
    assert lines[2] == "     10-29: unreadable"
    assert lines[3].split()[6] == "9"
    ansi = render_table(data, {("input", 3)}, ansi=True)
    assert "\x1b[7m     7\x1b[0m" in ansi[1]


async def test_the_live_view_redraws_every_round_and_highlights_changes() -> None:
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Terminal()
    bus = Board()
    view = LiveView(out, "unit 1 on board", 3, height=40)
    run = await scan_device(bus, 1, {"input": [(0, 79)]}, 3, 0.02, view)
    text = out.getvalue()
    assert len(run.snapshots) == 3 and text.count("\x1b[H") == 3 and text.count("\x1b[2J") == 1
    assert "round 3 of 3" in text and not view.truncated
    frames = text.split("\x1b[H")[1:]
    assert "\x1b[7m" not in frames[0], "nothing changed before the first round"
    assert "\x1b[7m" in frames[2]
    assert not bus.connected

    short = LiveView(Terminal(), "unit 1 on board", 1, height=8)
    short(1, run.snapshots[-1][1], None)  # type: ignore[arg-type]
    assert short.truncated
    assert short.out.getvalue().count("\n") == 8 - 1  # type: ignore[attr-defined]


async def test_a_stop_ends_the_wait_for_the_next_round() -> None:
    """Ctrl-C (the command sets ``stop``) ends the rounds; what was read is analysed."""
    bus = Board()
    stop = asyncio.Event()

    def view(k: int, data: object, previous: object) -> None:
        asyncio.get_running_loop().call_later(0.05, stop.set)

    start = time.monotonic()
    run = await scan_device(bus, 1, {"holding": [(0, 3)]}, 50, 30.0, view, stop)
    assert time.monotonic() - start < 5.0
    assert len(run.snapshots) == 1 and run.identification == {"VendorName": "Acme", "ProductCode": "AT-6x6"}


def test_the_command_calls_read_functions_only() -> None:
    """By construction: the command's modules (the command, its reading, table and report)
    name no write function of the transport or pymodbus."""
    names: set[str] = set()
    for module in (scan_cmd, scan_read, scan_table, scan_report):
        tree = ast.parse(Path(str(module.__file__)).read_text(encoding="utf-8"))
        names |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
        names |= {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    assert not {n for n in names if n.startswith("write_") or n.startswith("_write")}
    assert {"read_registers", "read_device_identification"} <= names


class ShortBoard(Board):
    """A board that answers a read with fewer registers than asked, without an exception: the
    registers it has in a row from the first one asked (``end_of_map``), or at most ``cap``
    of them. A read whose first register it does not have answers exception 2."""

    def __init__(self, cap: int | None = None) -> None:
        super().__init__()
        self.cap = cap

    async def _read(self, kind: str, device_id: int, address: int, count: int, what: str) -> Sequence[int]:
        image = self.device.input if kind == "input" else self.device.holding
        have = 0
        while have < count and address + have in image:
            have += 1
        if self.cap is not None:
            have = min(have, self.cap)
        self._move()
        self.requests.append((kind, device_id, address, count))
        if not have:
            raise DeviceExceptionResponse(f"{what}: device answered exception 2 (illegal data address)", 2)
        return [image[a] for a in range(address, address + have)]


@pytest.fixture
def short_board(monkeypatch: pytest.MonkeyPatch) -> ShortBoard:
    bus = ShortBoard()
    monkeypatch.setattr(scan_cmd, "transport_factory", lambda _endpoint: bus)
    return bus


def test_a_short_answer_is_split_as_a_refused_read(short_board: ShortBoard) -> None:
    # issue 33 §12: "asked for 71 registers, got 60" ended the scan with exit 1. The board has
    # registers 200..259 here, nothing after them (its counter and frame are at 10..67)
    short_board.device.set_input(200, range(100, 160))
    result = invoke("--input", "200-270", "--rounds", "2", "--interval", "0")
    assert result.exit_code == 0, result.output
    readable = set(range(200, 260))
    first_pass = expected_reads(readable, 200, 71)
    reads = [(a, n) for _, _, a, n in short_board.requests]
    assert reads[: len(first_pass)] == first_pass
    assert reads[len(first_pass) : -1] == [(200, 60)] * 2  # the rounds read what answered
    lines = result.output.splitlines()
    row250 = next(line for line in lines if line.startswith("    250 "))
    assert row250.split()[1:] == [str(100 + a - 200) for a in range(250, 260)]
    assert "    260-270: unreadable" in lines
    assert "  input 200-259: 0x0064 0x0065" in result.output  # the report goes on: constants


def test_a_device_that_answers_at_most_60_registers_is_read_whole(short_board: ShortBoard) -> None:
    short_board.cap = 60
    short_board.device.set_input(200, range(1000, 1125))
    result = invoke("--input", "200-324", "--rounds", "1", "--interval", "0", "--json")
    assert result.exit_code == 0, result.output
    # 125 -> 62 + 63 (both short) -> 31 + 31 and 31 + 32: every register read
    reads = [(a, n) for _, _, a, n in short_board.requests[:-1]]
    per_pass = [(200, 125), (200, 62), (200, 31), (231, 31), (262, 63), (262, 31), (293, 32)]
    assert reads == per_pass * 2
    assert "asked for" not in result.output
