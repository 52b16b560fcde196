"""End to end over Modbus RTU on a serial line: a socat pty pair, 115200 baud, line timing.

Two simulated arrays share one line (device ids 1 and 2); the gateway sends one request at
a time and reads both. The drift check of the TCP test is repeated over the serial line.
"""

from __future__ import annotations

import time

import pytest
from test_gateway_tcp import Recorder, array_device, drift_errors, holds_array, report, until
from waiting import until as wait_for_event

from gateway.config import bus_config_for, gateway_config_for
from gateway.modbus.backends import open_transport
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import ChannelStatus
from sim_device import ArrayConfig, SimArray, serve_serial

BAUD = 115200


@pytest.fixture(params=["pymodbus", "direct"])
def serial_client(request: pytest.FixtureRequest) -> str:
    """Who frames RTU on the gateway's side: pymodbus' client or the direct one (rtu_line)."""
    return str(request.param)


@pytest.mark.slow  # plays the whole holds scenario (about 7 s)
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


async def test_two_devices_on_one_line(pty_pair: tuple[str, str], serial_client: str) -> None:
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
            serial_client=serial_client,
        )
        holder = SnapshotHolder()
        async with Poller(gateway_config_for([bus]), holder):

            def ten_polls_each() -> bool:
                counters = holder.get().counters
                return all(
                    c is not None and c.polls_total >= 10 for c in map(counters.get, ("first", "second"))
                )

            await wait_for_event(ten_polls_each, 10.0, "10 polls of each device", step_s=0.05)
        snap = holder.get()
        async with open_transport(bus) as transport:
            ident = await transport.read_device_identification(2)
    for name in ("first", "second"):
        dev = snap.devices[name]
        c = snap.counters[name]
        assert dev.up, dev.error
        assert c.polls_total >= 10, c
        assert sum(c.read_errors_total.values()) == 0, c.read_errors_total
        assert all(ChannelStatus(s) == ChannelStatus.NO_CONTACT for s in dev.status)
    assert ident["ProductCode"] == "TSA-SIM"


@pytest.mark.slow  # three time-outs through the back-off, then the recovery (about 2.3 s)
async def test_silent_device_on_a_line_times_out_and_the_other_keeps_going(
    pty_pair: tuple[str, str], serial_client: str
) -> None:
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
            serial_client=serial_client,
        )
        holder = SnapshotHolder()
        async with Poller(gateway_config_for([bus]), holder):
            # the events the 3 s sleep stood for: the silent device timed out 3 times and the
            # other was polled 30 times meanwhile (the elapsed time is reported, not judged)
            started = time.monotonic()

            def timed_out_and_polled() -> bool:
                counters = holder.get().counters
                silent_c, alive_c = counters.get("silent"), counters.get("alive")
                return (
                    silent_c is not None
                    and alive_c is not None
                    and silent_c.read_errors_total.get("timeout", 0) >= 3
                    and alive_c.polls_total >= 30
                )

            await wait_for_event(
                timed_out_and_polled, 15.0, "3 time-outs of the silent device, 30 polls of the other"
            )
            elapsed_s = time.monotonic() - started
            snap = holder.get()
            a2.faults.clear()
            recovered = await until(lambda: holder.get().devices["silent"].up, 5.0)
    alive, silent = snap.counters["alive"], snap.counters["silent"]
    assert snap.devices["alive"].up and not snap.devices["silent"].up
    assert silent.read_errors_total["timeout"] >= 3
    assert all(ChannelStatus(s) == ChannelStatus.STALE for s in snap.devices["silent"].status)
    assert alive.polls_total >= 30, alive
    # the back-off keeps the dead one cheap: without it every cycle would spend a 0.1 s
    # time-out on it (as many time-outs as polls of the other); with it, a few in that time
    cost = f"{silent.read_errors_total['timeout']} time-outs, {alive.polls_total} polls in {elapsed_s:.2f} s"
    print(cost)
    assert silent.read_errors_total["timeout"] <= alive.polls_total // 2, cost
    assert recovered, "the device that came back was not picked up again"
