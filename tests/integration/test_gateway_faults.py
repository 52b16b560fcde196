"""Faults: timeouts, exception responses, garbled frames, dropped connections, power cycles.

Two simulated arrays on two TCP buses. Faults are injected into device "a"; each must show
in the metrics (device up, error counter by reason, stale channels), the gateway must
recover by itself, and device "b" on the other bus must keep being polled at its rate.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass

import pytest
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families
from test_gateway_tcp import array_device

from gateway.config import BusConfig, DeviceConfig, bus_config_for, gateway_config_for
from gateway.metrics.collector import make_registry
from gateway.runtime.poller import Poller, SnapshotHolder
from sim_device import ArrayConfig, SimArray, serve_tcp

POLL_S = 0.05


@dataclass
class Rig:
    a: SimArray
    b: SimArray
    port_a: int
    holder: SnapshotHolder
    registry: CollectorRegistry
    poller: Poller
    server_a: contextlib.AsyncExitStack

    async def power_off(self) -> None:
        """Stop device a's server: nothing listens on its port any more."""
        await self.server_a.aclose()

    async def power_on(self) -> None:
        """Start device a's server again on the same port."""
        await self.server_a.enter_async_context(serve_tcp([self.a], host="127.0.0.1", port=self.port_a))

    def metric(self, name: str, **labels: str) -> float | None:
        text = generate_latest(self.registry).decode()
        for fam in text_string_to_metric_families(text):
            for s in fam.samples:
                if s.name == name and all(s.labels.get(k) == v for k, v in labels.items()):
                    return float(s.value)
        return None

    def errors(self, reason: str) -> float:
        return self.metric("tactile_read_errors_total", device="a", reason=reason) or 0.0

    def status(self, channel: str = "ch00") -> str:
        dev = self.holder.get().devices["a"]
        return next(c.status.label for c in dev.channels() if c.name == channel)

    def b_polls(self) -> int:
        c = self.holder.get().counters.get("b")
        return 0 if c is None else c.polls_total


async def wait_for(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s} s waiting for: {what}")
        await asyncio.sleep(0.02)


def _array(device_id: int) -> SimArray:
    cfg = ArrayConfig(channels=4, columns=2, pitch_mm=2.5, seed=device_id, scenario="holds", speed=1.0)
    return SimArray(cfg, device_id=device_id)


@pytest.fixture
async def rig() -> AsyncIterator[Rig]:
    a, b = _array(1), _array(2)
    server_a = contextlib.AsyncExitStack()
    sa = await server_a.enter_async_context(serve_tcp([a], host="127.0.0.1", port=0))
    threads_before = set(threading.enumerate())
    async with server_a, serve_tcp([b], host="127.0.0.1", port=0) as sb:

        def bus(name: str, device: DeviceConfig, port: int) -> BusConfig:
            return bus_config_for(
                name, "tcp", [device], host="127.0.0.1", port=port, poll_interval_s=POLL_S,
                timeout_s=0.2, retries=1, backoff_initial_s=0.1, backoff_max_s=0.5,
            )  # fmt: skip

        bus_a = bus("bus-a", array_device(a, "a", bench=False), sa.port)
        bus_b = bus("bus-b", array_device(b, "b", 2, bench=False), sb.port)
        holder = SnapshotHolder()
        registry = make_registry(holder.get, CollectorRegistry())
        poller = Poller(gateway_config_for([bus_a, bus_b]), holder)
        rig = Rig(a, b, sa.port, holder, registry, poller, server_a)
        async with poller:
            await wait_for(lambda: rig.metric("tactile_device_up", device="a") == 1.0, 5, "a up")
            await wait_for(lambda: rig.metric("tactile_device_up", device="b") == 1.0, 5, "b up")
            yield rig
    # clean shutdown: no bus task, no converter thread, nothing else pending
    assert poller.workers and all(w.task is None for w in poller.workers)
    pending = [t for t in asyncio.all_tasks() if t is not asyncio.current_task() and not t.done()]
    assert not pending, pending
    leaked = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    assert not leaked, leaked


async def _fault_cycle(rig: Rig, reason: str, set_fault: Callable[[], None], window_s: float = 1.5) -> None:
    """Inject a fault into "a": it goes down with errors of ``reason``, "b" keeps its rate,
    then the fault is cleared and "a" comes back by itself."""
    before = rig.errors(reason)
    set_fault()
    await wait_for(lambda: rig.metric("tactile_device_up", device="a") == 0.0, 5, f"a down ({reason})")
    await wait_for(lambda: rig.errors(reason) > before, 5, f"{reason} errors counted")
    assert rig.status() == "stale"
    polls0, t0 = rig.b_polls(), time.monotonic()
    await asyncio.sleep(window_s)
    rate = (rig.b_polls() - polls0) / (time.monotonic() - t0)
    assert rate >= 0.6 / POLL_S, f"device b polled at {rate:.1f}/s during the {reason} fault"
    assert rig.metric("tactile_device_up", device="b") == 1.0
    rig.a.faults.clear()
    await wait_for(lambda: rig.metric("tactile_device_up", device="a") == 1.0, 5, f"a back up after {reason}")
    assert rig.status() in ("ok", "no_contact")


async def test_timeouts(rig: Rig) -> None:
    await _fault_cycle(rig, "timeout", lambda: setattr(rig.a.faults, "no_response", True))


async def test_slow_device(rig: Rig) -> None:
    await _fault_cycle(rig, "timeout", lambda: setattr(rig.a.faults, "delay_s", 0.5))


async def test_exception_responses(rig: Rig) -> None:
    await _fault_cycle(rig, "exception", lambda: setattr(rig.a.faults, "exception_code", 4))


async def test_garbled_frames(rig: Rig) -> None:
    await _fault_cycle(rig, "decode", lambda: setattr(rig.a.faults, "garble", True))


async def test_dropped_connections(rig: Rig) -> None:
    await _fault_cycle(rig, "connection", lambda: setattr(rig.a.faults, "drop_connection", True))


async def test_device_switched_off_and_on(rig: Rig) -> None:
    worker = next(w for w in rig.poller.workers if w.name == "bus-a")
    before = rig.errors("connection")
    await rig.power_off()
    await wait_for(lambda: rig.metric("tactile_device_up", device="a") == 0.0, 5, "a down (off)")
    await wait_for(lambda: rig.errors("connection") > before + 2, 5, "connection errors while off")
    assert rig.status() == "stale"
    failures0, polls0, t0 = worker.connect_failures, rig.b_polls(), time.monotonic()
    await asyncio.sleep(1.5)
    elapsed = time.monotonic() - t0
    rate = (rig.b_polls() - polls0) / elapsed
    assert rate >= 0.6 / POLL_S, f"device b polled at {rate:.1f}/s while a was off"
    # reconnects are spaced by the jittered back-off (0.1 s doubling to 0.5 s): no busy loop
    attempts = worker.connect_failures - failures0
    assert attempts >= 1, attempts
    assert attempts <= elapsed / 0.01 / 2, attempts
    await rig.power_on()
    await wait_for(lambda: rig.metric("tactile_device_up", device="a") == 1.0, 5, "a back up after power on")
    assert rig.status() in ("ok", "no_contact")
