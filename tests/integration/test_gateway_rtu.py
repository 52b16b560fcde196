"""End to end over Modbus RTU on a serial line: a socat pty pair, 115200 baud, line timing.

Two simulated arrays share one line (device ids 1 and 2); the gateway sends one request at
a time and reads both. The drift check of the TCP test is repeated over the serial line.
"""

from __future__ import annotations

import asyncio
import time

from test_gateway_tcp import Recorder, array_device, drift_errors, holds_array, report, until

from gateway.config import bus_config_for, gateway_config_for
from gateway.modbus.client import ModbusTransport
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import ChannelStatus
from sim_device import ArrayConfig, SimArray, serve_serial

BAUD = 115200


async def test_holds_drift_corrected_over_rtu(pty_pair: tuple[str, str]) -> None:
    gw_port, dev_port = pty_pair
    array = holds_array(channels=4, columns=2)
    async with serve_serial([array], port=dev_port, baudrate=BAUD, line_timing=True):
        bus = bus_config_for(
            "line",
            "rtu",
            [array_device(array, "arr")],
            serial_port=gw_port,
            baudrate=BAUD,
            poll_interval_s=0.03,
            timeout_s=0.5,
        )
        holder = SnapshotHolder()
        rec = Recorder("arr")
        holder.subscribe(rec)
        end_s = array.scenario.duration_s
        async with Poller(gateway_config_for([bus]), holder):
            finished = await until(lambda: array.device_time_s >= end_s, 25.0)
        assert finished, "the scenario did not finish in time"
    r = drift_errors(rec.rows)
    message = report("RTU", r)
    print(message)
    assert r["samples"] >= 50, message
    assert r["within"] >= 0.95, message
    assert r["holds"] == 3, message
    assert r["static_end_n"] > r["static_start_n"] + 0.05, message


async def test_two_devices_on_one_line(pty_pair: tuple[str, str]) -> None:
    gw_port, dev_port = pty_pair
    cfg = ArrayConfig(channels=8, columns=4, pitch_mm=2.5, seed=4, scenario="holds", speed=1.0)
    a1, a2 = SimArray(cfg, device_id=1), SimArray(cfg, device_id=2)
    async with serve_serial([a1, a2], port=dev_port, baudrate=BAUD, line_timing=True):
        bus = bus_config_for(
            "line",
            "rtu",
            [array_device(a1, "first", 1, bench=False), array_device(a2, "second", 2, bench=False)],
            serial_port=gw_port,
            baudrate=BAUD,
            poll_interval_s=0.05,
        )
        holder = SnapshotHolder()
        async with Poller(gateway_config_for([bus]), holder):
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                counters = holder.get().counters
                if all(
                    counters.get(n) is not None and counters[n].polls_total >= 10 for n in ("first", "second")
                ):
                    break
                await asyncio.sleep(0.05)
        snap = holder.get()
        async with ModbusTransport(bus) as transport:
            ident = await transport.read_device_identification(2)
    for name in ("first", "second"):
        dev = snap.devices[name]
        c = snap.counters[name]
        assert dev.up, dev.error
        assert c.polls_total >= 10, c
        assert sum(c.read_errors_total.values()) == 0, c.read_errors_total
        assert all(ChannelStatus(s) == ChannelStatus.NO_CONTACT for s in dev.status)
    assert ident["ProductCode"] == "TSA-SIM"


async def test_silent_device_on_a_line_times_out_and_the_other_keeps_going(pty_pair: tuple[str, str]) -> None:
    gw_port, dev_port = pty_pair
    cfg = ArrayConfig(channels=4, columns=2, pitch_mm=2.5, seed=5, scenario="holds", speed=1.0)
    a1, a2 = SimArray(cfg, device_id=1), SimArray(cfg, device_id=2)
    a2.faults.no_response = True
    async with serve_serial([a1, a2], port=dev_port, baudrate=BAUD, line_timing=True):
        bus = bus_config_for(
            "line",
            "rtu",
            [array_device(a1, "alive", 1, bench=False), array_device(a2, "silent", 2, bench=False)],
            serial_port=gw_port,
            baudrate=BAUD,
            poll_interval_s=0.05,
            timeout_s=0.1,
            retries=0,
            backoff_initial_s=0.2,
            backoff_max_s=1.0,
        )
        holder = SnapshotHolder()
        async with Poller(gateway_config_for([bus]), holder):
            await asyncio.sleep(3.0)
            snap = holder.get()
            a2.faults.clear()
            recovered = await until(lambda: holder.get().devices["silent"].up, 5.0)
    alive, silent = snap.counters["alive"], snap.counters["silent"]
    assert snap.devices["alive"].up and not snap.devices["silent"].up
    assert silent.read_errors_total["timeout"] >= 3
    assert all(ChannelStatus(s) == ChannelStatus.STALE for s in snap.devices["silent"].status)
    # 3 s at 0.05 s: 60 polls if nothing were lost; the back-off keeps the dead one cheap
    assert alive.polls_total >= 30, alive
    assert recovered, "the device that came back was not picked up again"
