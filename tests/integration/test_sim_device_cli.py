"""tactile-sim as a process: serves a plain client, records, and stops cleanly on SIGINT/SIGTERM."""

from __future__ import annotations

import asyncio
import re
import signal
import sys
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient
from waiting import until

from sim_device import registers as reg

pytestmark = pytest.mark.slow  # a simulator process per test

SPEED = 20.0  # the 0.5 N hold is device time 10-130 s: 0.5-6.5 s of wall time after the start


async def start(*args: str) -> tuple[asyncio.subprocess.Process, int]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "sim_device.cli", "run", *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    assert proc.stderr is not None
    line = await asyncio.wait_for(proc.stderr.readline(), timeout=20.0)
    match = re.search(rb"on tcp 127\.0\.0\.1:(\d+)", line)
    assert match, line
    return proc, int(match.group(1))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
async def test_cli_serves_records_and_stops_on_signal(tmp_path: Path, sig: signal.Signals) -> None:
    record = tmp_path / "live.csv"
    options = ["--scenario", "holds", "--speed", f"{SPEED:g}", "--channels", "4"]
    proc, port = await start(
        "--tcp", "127.0.0.1:0", *options, "--record", str(record), "--record-period", "0.5"
    )
    try:
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0)
        assert await client.connect()
        rr = await client.read_holding_registers(0, count=1, device_id=1)
        assert rr.registers == [4]

        async def device_time_past(limit_s: float) -> float:
            """The device's clock if it is past ``limit_s``, else 0. A read of the clock latches
            the frame: the force read next is of the same instant."""
            rr = await client.read_input_registers(0, count=7, device_id=1)
            assert not rr.isError(), rr
            w = rr.registers
            t_s = ((w[2] << 48) | (w[3] << 32) | (w[4] << 16) | w[5]) / 1e3
            return t_s if t_s >= limit_s else 0.0

        # the device's own clock past 20.5 s: in the 0.5 N hold, with 40 record periods behind it
        t_s = await until(lambda: device_time_past(20.5), 20.0, "20.5 s of device time")
        forces = await client.read_input_registers(reg.IR_TRUE_FORCE, count=8, device_id=1)
        assert 20.5 <= t_s < 130.0, f"the machine stalled past the 0.5 N hold (device time {t_s} s)"
        assert client.convert_from_registers(forces.registers[:2], client.DATATYPE.FLOAT32) == 0.5
        client.close()
        proc.send_signal(sig)
        _out, err = await asyncio.wait_for(proc.communicate(), timeout=10.0)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode == 0, err
    assert b"stopped" in err and b"Traceback" not in err
    lines = record.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    assert lines[header] == "time_s,channel,resistance_ohm,force_n,temperature_c"
    rows = [line.split(",") for line in lines[header + 1 :]]
    assert len(rows) >= 4 * 40
    assert {row[1] for row in rows} == {"0", "1", "2", "3"}
    assert max(float(row[3]) for row in rows) == 0.5
