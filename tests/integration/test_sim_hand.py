"""The simulated hand (``tactile-sim run --map hand``) through a real pymodbus client on an
ephemeral loopback port: the 17 regions at their addresses under both layouts and an offset,
reads of at most 125 registers, the 30 Hz frames by the device's clock, the saturation code,
dead and frozen taxels, status and error registers, and set points written with functions 6
and 16. Nothing here imports ``gateway``."""

from __future__ import annotations

import asyncio
import os
import re
import sys
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.framer import FramerType
from waiting import ManualClock

from sim_device import hand_map as hm
from sim_device.hand import FRAME_PERIOD_S, HandDevice
from sim_device.hand_scenarios import parse_taxel_specs
from sim_device.hand_server import serve_hand_tcp

MAX_READ = 125


async def read_block(client: AsyncModbusTcpClient, address: int, count: int) -> tuple[list[int], int]:
    """``count`` holding registers from ``address`` in reads of at most 125; and the number of reads."""
    words: list[int] = []
    reads = 0
    for start in range(0, count, MAX_READ):
        rr = await client.read_holding_registers(
            address + start, count=min(MAX_READ, count - start), device_id=1
        )
        assert not rr.isError(), rr
        words += rr.registers
        reads += 1
    return words, reads


@pytest.mark.parametrize(
    ("kind", "offset"), [("byte", 0), ("register", 0), ("register", 100), ("byte", -200)]
)
async def test_every_region_at_its_address(kind: str, offset: int) -> None:
    clock = ManualClock()
    hand = HandDevice("grasp", layout=hm.Layout(kind, offset), clock=clock)
    clock.advance(5.0)  # device time 5 s: the palm pressed, the finger tips and pads touching
    public = {"little": 3000, "ring": 3370, "middle": 3740, "index": 4110, "thumb": 4480, "palm": 4900}
    async with serve_hand_tcp(hand) as server:
        client = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
        assert await client.connect()
        try:
            total = 0
            for group, byte_address in public.items():
                first = (byte_address // 2 if kind == "byte" else byte_address) + offset
                size = 210 if group == "thumb" else 112 if group == "palm" else 185
                words, reads = await read_block(client, first, size)
                assert reads == (1 if group == "palm" else 2)  # a finger's block needs two reads
                at = 0
                for r in (r for r in hm.REGIONS if r.group == group):
                    assert words[at : at + r.size] == hand.taxels(r.name).tolist(), r.name
                    at += r.size
                total += len(words)
            assert total == 1062
            # pressed palm and touching finger pads (5 s into "grasp") read non-zero
            palm, _ = await read_block(client, public["palm"] // (2 if kind == "byte" else 1) + offset, 112)
            assert min(palm) > 0
            before = (public["little"] // 2 if kind == "byte" else public["little"]) + offset - 1
            rr = await client.read_holding_registers(before, count=2, device_id=1)
            assert rr.isError()  # the register before the first block is not mapped
            if kind == "register":  # registers between the blocks are not mapped
                rr = await client.read_holding_registers(3000 + offset + 185, count=1, device_id=1)
                assert rr.isError()
        finally:
            client.close()


async def test_frames_change_at_30_hz_by_the_device_clock() -> None:
    clock = ManualClock()
    hand = HandDevice("sine", clock=clock, noise_lsb=2.0)
    clock.advance(2.0)
    palm = hand.layout.region_address(hm.region("palm"))
    async with serve_hand_tcp(hand) as server:
        client = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
        assert await client.connect()
        try:
            first, _ = await read_block(client, palm, 112)
            clock.advance(0.5 * FRAME_PERIOD_S)
            again, _ = await read_block(client, palm, 112)
            assert again == first  # within one frame: the same values, however many reads
            clock.advance(0.6 * FRAME_PERIOD_S)
            later, _ = await read_block(client, palm, 112)
            assert later != first
            # function 43 names the hand, not the palm's grid
            response = await client.read_device_information(read_code=2, device_id=1)
            assert not response.isError(), response
            assert response.information[4] == b"Simulated dexterous hand with a tactile skin"
            assert response.information[5] == b"hand 1062 taxels in 17 regions"
        finally:
            client.close()


async def test_saturation_dead_frozen_status_and_set_points(tmp_path: Path) -> None:
    path = tmp_path / "crush.toml"
    path.write_text(
        "[region.palm]\n[[region.palm.load]]\nchannels = [9]\ninitial_n = 50.0\nsteps = [{ hold_s = 1 }]\n"
    )
    clock = ManualClock(0.0)
    hand = HandDevice(
        str(path),
        clock=clock,
        dead=parse_taxel_specs("thumb-pad", "--dead"),
        frozen=parse_taxel_specs("middle-tip=321", "--frozen", allow_value=True),
    )
    hand.set_error("ring", "over-current")
    address = hand.layout.addresses()
    async with serve_hand_tcp(hand) as server:
        client = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
        assert await client.connect()
        try:
            palm, _ = await read_block(client, address["palm"], 112)
            assert palm[9] == 0xFFFF and max(palm[:9] + palm[10:]) < 0xFF00
            thumb_pad, _ = await read_block(client, address["thumb-pad"], 96)
            assert thumb_pad == [0] * 96
            tip, _ = await read_block(client, address["middle-tip"], 9)
            assert tip == [321] * 9
            rr = await client.write_register(hm.HR_ANGLE_SET + 1, 800, device_id=1)
            assert not rr.isError()
            rr = await client.write_registers(hm.HR_FORCE_SET, [100, 200, 300], device_id=1)
            assert not rr.isError()
            rr = await client.write_register(hm.HR_FORCE_CALIBRATE, 1, device_id=1)
            assert not rr.isError() and hand.force_calibrations == 1
            rr = await client.read_holding_registers(hm.CONTROL_FIRST, count=40, device_id=1)
            assert not rr.isError()
            regs = rr.registers
            assert regs[0:6] == [0, 800, 0, 0, 0, 0]
            assert regs[10:16] == [100, 200, 300, 0, 0, 0]
            # the ring joint has an over-current error: a fault, and it does not move
            assert regs[28:34] == [0, 4, 0, 0, 0, 0] and regs[34:40] == [0, 0b100, 0, 0, 0, 0]
            for bad in (
                client.write_register(hm.HR_ANGLE_SET, 1001, device_id=1),
                client.write_register(hm.HR_STATUS, 0, device_id=1),
                client.write_register(hm.HR_RESERVED, 0, device_id=1),
                client.write_register(address["palm"], 0, device_id=1),
            ):
                assert (await bad).isError()
            clock.advance(0.5)
            rr = await client.read_holding_registers(hm.HR_ANGLE_ACTUAL, count=2, device_id=1)
            assert rr.registers == [0, 0]
            hand.set_error("ring", "over-current", on=False)
            clock.advance(0.5)
            rr = await client.read_holding_registers(hm.HR_ANGLE_ACTUAL, count=2, device_id=1)
            assert rr.registers == [0, 500]
        finally:
            client.close()


@pytest.mark.slow  # starts a simulator process
async def test_the_command_line_serves_the_layout_it_was_given() -> None:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    args = ["--map", "hand", "--tcp", "127.0.0.1:0", "--layout", "register", "--base-offset", "100"]
    args += ["--dead", "thumb-pad,middle-tip", "--scenario", "palm-held", "--stop-after", "60"]
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "sim_device.cli", "run", *args, stderr=asyncio.subprocess.PIPE, env=env
    )
    try:
        assert proc.stderr is not None
        line = (await asyncio.wait_for(proc.stderr.readline(), timeout=30)).decode()
        found = re.search(r"on tcp 127\.0\.0\.1:(\d+)", line)
        assert found, line
        assert (
            "blocks at registers little 3100, ring 3470, middle 3840, index 4210, thumb 4580, palm 5000"
            in line
        )
        client = AsyncModbusTcpClient("127.0.0.1", port=int(found.group(1)), timeout=2.0, retries=0)
        assert await client.connect()
        try:
            thumb_pad, _ = await read_block(client, 4580 + 9 + 96 + 9, 96)  # after tip, nail, middle
            middle_tip, _ = await read_block(client, 3840, 9)
            assert thumb_pad == [0] * 96 and middle_tip == [0] * 9
            palm, _ = await read_block(client, 5000, 112)  # held loaded from the start
            assert min(palm) > 0
        finally:
            client.close()
    finally:
        proc.terminate()
        await asyncio.wait_for(proc.wait(), timeout=10)


async def test_rtu_framing_over_tcp_reads_a_finger_and_writes_a_set_point() -> None:
    clock = ManualClock()
    hand = HandDevice("palm-held", clock=clock)
    index_tip = hand.layout.region_address(hm.region("index-tip"))
    async with serve_hand_tcp(hand, framer="rtu") as server:
        client = AsyncModbusTcpClient(
            "127.0.0.1", port=server.port, framer=FramerType.RTU, timeout=2.0, retries=0
        )
        assert await client.connect()
        try:
            words, reads = await read_block(client, index_tip, 185)
            assert reads == 2 and words[:9] == hand.taxels("index-tip").tolist()
            assert not (await client.write_registers(hm.HR_ANGLE_SET + 4, [250, 750], device_id=1)).isError()
            rr = await client.read_holding_registers(hm.HR_ANGLE_SET + 4, count=2, device_id=1)
            assert rr.registers == [250, 750]
        finally:
            client.close()
