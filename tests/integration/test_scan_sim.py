"""``tactile-gateway scan`` (a real process) against the simulator served in this process over
loopback Modbus TCP: it finds the ADC block, the clock and the identification of each map,
and the server sees read requests only.

(Named ``test_scan_sim.py``: ``tests/unit/gateway/modbus/test_scan.py`` has the basename
``test_scan.py`` and the test directories are no packages.)
"""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from netutil import free_port

from sim_device import ArrayConfig, SimArray, modbus_server, serve_tcp
from sim_device.dfrobot_map import DFRobotBoard, serve_dfrobot_tcp

CLI = Path(sys.executable).parent / "tactile-gateway"
READ_FUNCTIONS = {3, 4, 43}


@pytest.fixture
def function_codes(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[int]]:
    """The function code of every request the simulator's servers handle from now on."""
    seen: list[int] = []
    original = modbus_server._SimHandler.handle_request

    async def handle_request(self: modbus_server._SimHandler) -> None:
        if self.last_pdu is not None:
            seen.append(int(self.last_pdu.function_code))
        await original(self)

    monkeypatch.setattr(modbus_server._SimHandler, "handle_request", handle_request)
    yield seen


async def run_scan(port: int, *options: str, rounds: int = 5) -> tuple[int, str, str]:
    args = ["scan", "--host", "127.0.0.1", "--port", str(port), "--unit", "1", "--input", "0-200"]
    proc = await asyncio.create_subprocess_exec(
        str(CLI), *args, "--rounds", str(rounds), "--interval", "0.1", *options,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    try:
        out, err = await asyncio.wait_for(proc.communicate(), timeout=60.0)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


def line_with(text: str, start: str) -> str:
    found = [line.strip() for line in text.splitlines() if line.strip().startswith(start)]
    assert found, f"no line starting with {start!r} in:\n{text}"
    return found[0]


async def test_scan_finds_the_default_map(function_codes: list[int]) -> None:
    """docs/register-map.md, idle: ADC counts at input 100 (one per channel, noise only),
    the ms clock at 2-5 (uint64), the sample counter at 0-1, the identification.

    20 rounds, as docs/bring-your-own-array.md scans this map: an idle cell's 2 LSB of noise
    is clipped at the rail, so it reads 0 in 52-68 % of rounds, and an end cell that read 0
    in every round looks like the zeros beside the frame (found by the stress run, where the
    load changed the noise drawn: measured on this array, an end cell is constant over 5
    rounds in 7-10 % of windows; over 20 rounds about 0.65^20, 2e-4)."""
    array = SimArray(ArrayConfig(channels=12, columns=4))
    holding = list(array.holding_registers())
    async with serve_tcp(array) as server:
        code, out, err = await run_scan(server.port, "--holding", "0-20", rounds=20)
    assert code == 0, err
    assert err == ""
    assert line_with(out, "1. input").startswith("1. input 100-111: 12 registers,")
    assert line_with(out, "input 2-5:").startswith("input 2-5: uint64 rising")
    assert line_with(out, "input 2-5:").endswith(": ms")
    assert line_with(out, "input 0-1:").startswith("input 0-1: uint32 rising")
    assert "ProductCode: TSA-SIM" in out and "ModelName: Linqstat 3x4" in out
    assert line_with(out, "holding 0-11:").startswith("holding 0-11: 0x000C 0x0010")
    assert "adc_address = 100" in out and "channels = 12" in out
    assert "[bus.device.clock]" in out and "address = 2" in out and 'unit = "ms"' in out
    assert array.holding_registers() == holding
    assert set(function_codes) == READ_FUNCTIONS, "reads of both tables and the identification, no write"


async def test_scan_finds_the_rawgrid_map(function_codes: list[int]) -> None:
    """docs/register-map-rawgrid.md: 12-bit counts at input 32, constants at 0-5, no clock."""
    array = SimArray(ArrayConfig(register_map="rawgrid", channels=16, columns=4))
    async with serve_tcp(array) as server:
        code, out, err = await run_scan(server.port)
    assert code == 0, err
    assert line_with(out, "1. input").startswith("1. input 32-47: 16 registers, 12-bit codes")
    assert line_with(out, "input 0-5:").startswith("input 0-5: 0x5447 0x0103 0x0000 0x0001 0xE240 0x0007")
    assert line_with(out, "clock candidates:") == "clock candidates:"
    assert line_with(out, "none: no register rises") == "none: no register rises steadily with time"
    assert "VendorName: Acme Tactile" in out
    assert "adc_address = 32" in out and "adc_bits = 12" in out and "[bus.device.clock]" not in out
    assert set(function_codes) <= READ_FUNCTIONS and 4 in function_codes


async def test_scan_of_a_closed_port_is_one_line_and_exit_1() -> None:
    code, out, err = await run_scan(free_port())
    assert code == 1 and out == ""
    assert err.count("\n") == 1 and err.startswith("tactile-gateway: ") and "cannot connect" in err


@pytest.mark.parametrize("gap", ["zero", "absent"])
async def test_scan_finds_the_frame_of_a_dfrobot_board(gap: str) -> None:
    """A DFRobot-style 6x6 board (``sim_device.dfrobot_map``): VID and PID 0x3343 at input 0-1,
    a gap at 2-6, 36 12-bit cells at 7-42 (five idle at a constant 9), the count 36 at 43.
    The frame is 7-42; the ids and the count are constants and the snippet's checks."""
    async with serve_dfrobot_tcp(DFRobotBoard(gap=gap)) as port:
        code, out, err = await run_scan(port)
    assert code == 0, err
    assert line_with(out, "1. input").startswith("1. input 7-42: 36 registers, 12-bit codes")
    assert "2. input" not in out
    first = "input 0-6: 0x3343 0x3343 0x0000" if gap == "zero" else "input 0-1: 0x3343 0x3343"
    assert line_with(out, first.split(":")[0] + ":").startswith(first)
    assert line_with(out, "input 43:") == "input 43: 0x0024"
    assert line_with(out, "input 43 reads") == "input 43 reads 36: the channel count of frame 1?"
    assert "adc_address = 7" in out and "channels = 36" in out and "adc_bits = 12" in out
    assert '{ what = "identifier", table = "input", address = 0, value = 0x3343 },' in out
    assert '{ what = "identifier", table = "input", address = 1, value = 0x3343 },' in out
    assert 'channel_count = { table = "input", address = 43 }' in out
