"""``poll_interval_s = 0`` (back to back) on the in-process virtual bus: a bus whose every device
backs off does not spin between its attempts, and a device that answers is still polled back to
back while another one on its bus backs off.

``BusWorker.run`` runs for real (its task, the event loop's clock); the test waits on events
(a request logged) and compares counts: poll cycles against requests sent, not time windows.
"""

from __future__ import annotations

import asyncio
import random
from collections.abc import Callable

import pytest

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.model import SensorParams
from gateway.runtime.bus import BusWorker
from gateway.runtime.poller import Poller

#: a logged request of the virtual bus: kind, device id, address, count
Request = tuple[str, int, int, int]
#: 3 requests per poll: the clock (2+4), the status bitmaps (16+33), the counts (100+4)
REQUESTS_PER_POLL = 3


class Signalling(VirtualTransport):
    """The virtual bus, setting ``event`` once ``until(requests)`` holds after a request."""

    def __init__(self, devices: dict[int, VirtualDevice]) -> None:
        super().__init__("line", devices, timeout_s=0.2)
        self.event = asyncio.Event()
        self.until: Callable[[list[Request]], bool] = lambda requests: False

    def _answer(self, kind: str, device_id: int, address: int, count: int, what: str) -> None:
        try:
            super()._answer(kind, device_id, address, count, what)
        finally:
            if self.until(self.requests):
                self.event.set()


def image() -> VirtualDevice:
    dev = VirtualDevice()
    dev.set_input(2, [0, 0, 0, 1234])  # device clock: 1.234 s, uint64 ms
    dev.set_input(16, [0] * 33)  # the three status bitmaps and every register between them
    dev.set_input(100, [4413, 6314, 11518, 32800])  # ADC counts of 4 channels
    return dev


def back_to_back(devices: dict[int, VirtualDevice], ids: list[int]) -> tuple[Poller, BusWorker, Signalling]:
    configs = [device_config_for(f"dev{i}", i, [SensorParams()] * 4, 2, 2.5) for i in ids]
    bus = bus_config_for(
        "line", "tcp", configs, host="127.0.0.1", port=502, timeout_s=0.2, retries=0,
        poll_interval_s=0.0, backoff_initial_s=0.2, backoff_max_s=0.2,
    )  # fmt: skip
    assert bus.poll_interval_s == 0.0
    vt = Signalling(devices)
    poller = Poller(gateway_config_for([bus]), transport_factory=lambda _bus: vt, rng=random.Random(7))
    return poller, poller.workers[0], vt


def count_cycles(monkeypatch: pytest.MonkeyPatch, worker: BusWorker) -> list[int]:
    """A counter (one element) of the worker's poll cycles."""
    cycles = [0]
    real = worker.poll_cycle

    async def counted(*, settle: bool = True) -> None:
        cycles[0] += 1
        await real(settle=settle)

    monkeypatch.setattr(worker, "poll_cycle", counted)
    return cycles


async def test_a_bus_whose_devices_all_back_off_does_not_spin(monkeypatch: pytest.MonkeyPatch) -> None:
    poller, worker, vt = back_to_back({1: image()}, [1])
    vt.fail_next("timeout", 1_000_000)  # the device never answers
    attempts = 5
    vt.until = lambda requests: len(requests) >= attempts
    cycles = count_cycles(monkeypatch, worker)
    async with poller:
        await asyncio.wait_for(vt.event.wait(), 10.0)  # 5 attempts: at most 1 s of back-off
        done, sent = cycles[0], len(vt.requests)
    assert sent == attempts  # one request per attempt (retries = 0), then the back-off
    assert vt.requests == [("input", 1, 2, 4)] * attempts
    # one cycle per attempt; a wake-up a hair before the device is due may add an empty one.
    # Spinning (a cycle per event-loop pass while the device backs off) makes thousands.
    assert attempts <= done <= 2 * attempts + 1, f"{done} poll cycles for {sent} requests"
    runner = worker.runners[0]
    assert runner.failures >= attempts - 1 and not poller.snapshot().devices["dev1"].up


async def test_an_answering_device_is_polled_back_to_back_while_another_backs_off(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    poller, worker, vt = back_to_back({1: image()}, [1, 2])  # device 2 is not there: no answer

    def silent_asked(requests: list[Request]) -> int:
        return sum(1 for r in requests if r[1] == 2)

    vt.until = lambda requests: silent_asked(requests) >= 3
    cycles = count_cycles(monkeypatch, worker)
    async with poller:
        await asyncio.wait_for(vt.event.wait(), 10.0)
        requests = list(vt.requests)
    asked = [k for k, r in enumerate(requests) if r[1] == 2]
    assert len(asked) == 3
    # between two attempts at the silent device (its back-off, 0.02 s at least), the answering
    # one is polled back to back, not once per back-off
    between = requests[asked[0] + 1 : asked[1]]
    assert all(r[1] == 1 for r in between)
    assert len(between) >= 2 * REQUESTS_PER_POLL, f"{len(between)} requests to device 1 meanwhile"
    assert len(between) % REQUESTS_PER_POLL == 0
    assert cycles[0] >= len(between) // REQUESTS_PER_POLL
    assert poller.snapshot().devices["dev1"].up and not poller.snapshot().devices["dev2"].up
