"""``BusWorker.run`` keeps its schedule: a cycle starts every ``poll_interval_s`` from the first,
however long the conversions run between two cycles take.

The worker runs for real on the in-process virtual bus, on a clock of the test's own: the
clock moves only when the worker sleeps (by what it asked for) and when the conversions
settle (by ``SETTLE_S``, a slow conversion). Cycle starts are read off that clock, so the
check is exact and does not depend on the machine's load.
"""

from __future__ import annotations

import asyncio
import random

import pytest

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.model import SensorParams
from gateway.runtime.poller import Poller

INTERVAL_S = 0.1
SETTLE_S = 0.03
CYCLES = 6


def _device() -> VirtualDevice:
    dev = VirtualDevice()
    dev.set_input(2, [0, 0, 0, 1234])  # device clock, uint64 ms
    dev.set_input(16, [0] * 33)  # the status bitmaps and the registers between them
    dev.set_input(100, [4413, 6314, 11518, 32800])  # ADC counts of 4 channels
    return dev


async def test_cycles_start_on_schedule_however_long_conversions_take(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    clock = [1000.0]
    config = device_config_for("dev1", 1, [SensorParams()] * 4, 2, 2.5)
    bus = bus_config_for("line", "tcp", [config], host="127.0.0.1", port=502, poll_interval_s=INTERVAL_S)
    vt = VirtualTransport("line", {1: _device()}, timeout_s=0.2)
    poller = Poller(
        gateway_config_for([bus]),
        transport_factory=lambda _bus: vt,
        rng=random.Random(7),
        monotonic=lambda: clock[0],
    )
    worker = poller.workers[0]
    starts: list[float] = []
    enough = asyncio.Event()
    real_cycle, real_settle, real_sleep = worker.poll_cycle, worker.settle_all, asyncio.sleep

    async def cycle(*, settle: bool = True) -> None:
        starts.append(clock[0])
        if len(starts) >= CYCLES:
            enough.set()
        await real_cycle(settle=settle)

    def slow_settle() -> None:
        real_settle()
        clock[0] += SETTLE_S

    async def sleep(delay: float, result: object = None) -> object:
        clock[0] += max(0.0, delay)
        return await real_sleep(0, result)

    monkeypatch.setattr(worker, "poll_cycle", cycle)
    monkeypatch.setattr(worker, "settle_all", slow_settle)
    monkeypatch.setattr(worker, "sleep", sleep)
    worker.start()
    try:
        await asyncio.wait_for(enough.wait(), 10.0)
    finally:
        monkeypatch.undo()
        await worker.stop()
    assert worker.runners[0].counters.polls_total >= CYCLES - 1  # the device answered
    first = starts[0]
    # on the schedule exactly (a float's rounding), not SETTLE_S after it
    expected = [first + k * INTERVAL_S for k in range(CYCLES)]
    assert starts[:CYCLES] == pytest.approx(expected, abs=1e-9), [s - first for s in starts]
