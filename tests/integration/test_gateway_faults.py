"""Faults: timeouts, exception responses, garbled frames, dropped connections, power cycles.

Two simulated arrays on two TCP buses. Faults are injected into device "a"; each must show
in the metrics (device up, error counter by reason, stale channels), the gateway must
recover by itself, and device "b" on the other bus must keep being polled at its rate.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
import threading
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass

import pytest
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families
from test_gateway_tcp import array_device

from gateway.config import BusConfig, DeviceConfig, bus_config_for, device_config_for, gateway_config_for
from gateway.metrics.collector import make_registry
from gateway.model import SensorParams
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


async def _wrong_mbap_length(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, delta: int) -> None:
    """A Modbus/TCP device whose read answers are whole, but whose MBAP header's length field
    is off by ``delta`` bytes from what follows it."""
    try:
        while True:
            transaction, _, length, unit = struct.unpack(">HHHB", await reader.readexactly(7))
            pdu = await reader.readexactly(length - 1)
            function, _, count = struct.unpack(">BHH", pdu[:5])
            body = bytes([function, 2 * count]) + b"\x01\x00" * count
            writer.write(struct.pack(">HHHB", transaction, 0, len(body) + 1 + delta, unit) + body)
            await writer.drain()
    except (asyncio.IncompleteReadError, ConnectionError):
        pass
    finally:
        writer.close()


@pytest.mark.parametrize("delta", [-2, 3], ids=["length-short", "length-long"])
async def test_a_wrong_mbap_length_is_a_decode_error_logged_once(
    delta: int, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.CRITICAL, logger="pymodbus")  # as the CLI: its errors reach us as ours
    caplog.set_level(logging.INFO)  # after: this one sets the capturing handler's level
    server = await asyncio.start_server(lambda r, w: _wrong_mbap_length(r, w, delta), "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    device = device_config_for("a", 1, [SensorParams()] * 4, 2, 2.5)
    bus = bus_config_for(
        "bus-a", "tcp", [device], host="127.0.0.1", port=port, poll_interval_s=POLL_S,
        timeout_s=0.2, retries=0, backoff_initial_s=0.02, backoff_max_s=0.05,
    )  # fmt: skip
    holder = SnapshotHolder()

    def decode_errors() -> int:
        counters = holder.get().counters.get("a")
        return 0 if counters is None else counters.read_errors_total["decode"]

    async with server, Poller(gateway_config_for([bus]), holder):
        await wait_for(lambda: decode_errors() >= 5, 10, "five decode errors")
    counters = holder.get().counters["a"]
    assert dict(counters.read_errors_total) == {
        **dict.fromkeys(counters.read_errors_total, 0),
        "decode": counters.reads_total,
    }
    snap = holder.get().devices["a"]
    assert not snap.up and snap.error is not None
    assert {c.status.label for c in snap.channels()} == {"stale"}
    assert "Traceback" not in caplog.text
    assert [r for r in caplog.records if r.exc_info or r.exc_text] == []
    about_a = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(about_a) == 1, caplog.text
    assert about_a[0].name == "gateway.runtime.bus" and "device a on bus bus-a" in about_a[0].getMessage()
