"""The reconnect back-off of a bus grows until a poll succeeds, not merely a connect (issue 33 §5).

A device that accepts TCP, takes the configured set-up write and then drops the connection
reconnected at once (the back-off restarted from ``backoff_initial_s`` on every successful
connect): 55 set-up writes in 15 s on a real socket, about 14,000 an hour to the device's
registers. The bus task's own ``run`` loop is driven here on the in-process virtual bus with
a simulated clock: every sleep of the loop advances the clock instead of waiting.
"""

from __future__ import annotations

import asyncio
import random
from pathlib import Path

import pytest

from gateway.config import GatewayConfig, parse_config
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.bus import BusWorker
from gateway.runtime.poller import Poller

BACKOFF_INITIAL_S = 0.1
BACKOFF_MAX_S = 30.0
CONFIG = f"""\
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
retries = 0
timeout_s = 0.2
poll_interval_s = 0.05
backoff_initial_s = {BACKOFF_INITIAL_S}
backoff_max_s = {BACKOFF_MAX_S}

[[bus.device]]
name = "arr"
device_id = 1
channels = 4
[bus.device.registers]
adc_address = 100
[bus.device.front_end]
kind = "low_side"
supply_v = 3.3
reference_ohm = 10000.0
adc_bits = 12

[[bus.device.setup]]
what = "output mode: raw counts"
address = 2
value = 0
"""


class DropsAfterSetup(VirtualTransport):
    """A device that takes every set-up write, then drops the connection at the next request;
    with ``healthy`` set it stays connected."""

    healthy = False

    async def _write_single(self, device_id: int, address: int, value: int, what: str) -> None:
        await super()._write_single(device_id, address, value, what)
        if not self.healthy:
            self.fail_next("disconnect")


class SimClock:
    """Monotonic time that only moves when the bus task sleeps."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


def device() -> VirtualDevice:
    dev = VirtualDevice()
    dev.set_input(100, [2000] * 4)
    dev.set_holding(2, [7])
    return dev


def config() -> GatewayConfig:
    return parse_config(CONFIG, source=Path("/cfg/gateway.toml"))


async def run_for(worker: BusWorker, clock: SimClock, until_s: float) -> None:
    """Run the bus task's loop until the simulated clock passes ``until_s``."""
    done = asyncio.Event()

    async def sleep(delay_s: float) -> None:
        clock.now_s += max(delay_s, 0.0)
        if clock.now_s >= until_s:
            done.set()
        await asyncio.sleep(0)

    worker.sleep = sleep
    worker.start()
    await asyncio.wait_for(done.wait(), timeout=60.0)
    await worker.stop()


def build() -> tuple[Poller, BusWorker, DropsAfterSetup, SimClock]:
    vt = DropsAfterSetup("line", {1: device()}, timeout_s=0.2)
    clock = SimClock()
    poller = Poller(
        config(),
        transport_factory=lambda _bus: vt,
        rng=random.Random(3),
        wall_clock=lambda: 1_700_000_000.0,
        monotonic=clock,
    )
    return poller, poller.workers[0], vt, clock


async def test_a_device_that_drops_after_the_setup_write_is_written_to_ever_less_often(
    caplog: pytest.LogCaptureFixture,
) -> None:
    poller, worker, vt, clock = build()
    hour_s = 3600.0
    with caplog.at_level("INFO"):
        await run_for(worker, clock, clock.now_s + hour_s)
    # full jitter: attempt k waits uniform(0, min(30, 0.1 * 2^(k-1))) s, 15 s on average once the
    # cap is reached (after 9 attempts, 25.5 s of caps in all): about 9 + 3600 / 15 = 249 writes
    # an hour; restarting the back-off at every connect gave one every 0.05 s on average
    # (72,000 an hour). 500 leaves room for the jitter.
    assert 0 < len(vt.writes) < 500, len(vt.writes)
    assert all(w == (1, 2, (0,)) for w in vt.writes)
    # the log says so once, not once per connection
    assert len(caplog.records) < 30, [r.getMessage() for r in caplog.records][:40]
    assert not poller.snapshot().devices["arr"].up


async def test_a_successful_poll_restarts_the_back_off() -> None:
    poller, worker, vt, clock = build()
    await run_for(worker, clock, clock.now_s + 600.0)
    assert worker.failed_connections > 5  # grown: the polls never succeeded
    vt.healthy = True
    before = len(vt.writes)
    # at most one back-off (<= 30 s) until the next connect, then polls every 0.05 s
    await run_for(worker, clock, clock.now_s + 60.0)
    snap = poller.snapshot().devices["arr"]
    assert snap.up and worker.failed_connections == 0
    assert len(vt.writes) == before + 1  # one connect, one set-up write


SECOND_DEVICE = """
[[bus.device]]
name = "good"
device_id = 2
channels = 4
[bus.device.registers]
adc_address = 100
[bus.device.front_end]
kind = "low_side"
supply_v = 3.3
reference_ohm = 10000.0
adc_bits = 12
"""


async def test_a_healthy_neighbour_on_the_bus_does_not_restart_a_dropping_devices_back_off() -> None:
    # the gap left by the fix above: any device's successful poll restarted the bus's back-off,
    # so a device that drops the connection after its set-up write was written to once per
    # reconnect (every 0.05 s on average) as long as a neighbour on its bus polled fine
    vt = DropsAfterSetup("line", {1: device(), 2: device()}, timeout_s=0.2)
    clock = SimClock()
    poller = Poller(
        parse_config(CONFIG + SECOND_DEVICE, source=Path("/cfg/gateway.toml")),
        transport_factory=lambda _bus: vt,
        rng=random.Random(3),
        wall_clock=lambda: 1_700_000_000.0,
        monotonic=clock,
    )
    worker = poller.workers[0]
    await run_for(worker, clock, clock.now_s + 600.0)
    # the dropping device waits its own back-off: caps of 0.1 * 2^(k-1) s up to 30 s, 15 s on
    # average once capped, about 9 + 575 / 15 = 47 writes in 10 min; once per reconnect
    # would be one every 0.05 s or so (12,000)
    assert 0 < len(vt.writes) < 100, len(vt.writes)
    # and its neighbour is polled between the drops (before, the dropping device came first
    # on every connection and its neighbour was never polled at all)
    snaps = poller.snapshot().devices
    assert snaps["good"].up and not snaps["arr"].up
    good = next(r for r in worker.runners if r.config.name == "good")
    assert good.counters.polls_total > 100 * len(vt.writes), (good.counters.polls_total, len(vt.writes))
