"""What subscribers derive from every device snapshot (``SnapshotHolder.subscribe(derive=...)``):
the holder's list of derivations (sequences and callable sources, each function once, a
source's answer read anew each time), and the poll loop computing them once per snapshot, in
its own thread, before the snapshot is published: a subscriber's ``derived(fn)`` then finds
the value and ``fn`` is not called again. On the in-process virtual bus, counted calls."""

from __future__ import annotations

import random
import threading

import pytest

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.model import SensorParams
from gateway.runtime.poller import Derivation, Poller, SnapshotHolder
from gateway.runtime.snapshot import DeviceSnapshot, GatewaySnapshot


def first(snap: DeviceSnapshot) -> object:
    return ("first", snap.device)


def second(snap: DeviceSnapshot) -> object:
    return ("second", snap.device)


def third(snap: DeviceSnapshot) -> object:
    return ("third", snap.device)


def ignore(snapshot: GatewaySnapshot) -> None:
    """A subscriber that does nothing with what is published."""


class Counted:
    """A derivation that records each call: the snapshot, the thread, and its answer (a new
    object each call, so that a cached answer can be told from a recomputed one)."""

    def __init__(self) -> None:
        self.calls: list[tuple[DeviceSnapshot, threading.Thread, object]] = []

    def __call__(self, snap: DeviceSnapshot) -> object:
        value = object()
        self.calls.append((snap, threading.current_thread(), value))
        return value

    def calls_for(self, snap: DeviceSnapshot) -> int:
        return sum(1 for s, _, _ in self.calls if s is snap)


# ---------------------------------------------------------------------------- the holder


def test_no_subscriber_and_a_subscriber_without_derive_derive_nothing() -> None:
    holder = SnapshotHolder()
    assert holder.derivations == ()
    holder.subscribe(ignore)
    assert holder.derivations == ()


def test_sequences_of_several_subscribers_each_function_once_in_order_of_first_mention() -> None:
    holder = SnapshotHolder()
    holder.subscribe(ignore, derive=(first, second))
    holder.subscribe(ignore, derive=[second, third, first])
    holder.subscribe(ignore)
    assert holder.derivations == (first, second, third)


def test_a_function_named_twice_by_one_subscriber_counts_once() -> None:
    holder = SnapshotHolder()
    holder.subscribe(ignore, derive=(second, second, first, second))
    assert holder.derivations == (second, first)


def test_a_callable_source_is_asked_each_time_and_its_answer_can_change() -> None:
    holder = SnapshotHolder()
    now: list[Derivation] = [first]
    asked: list[int] = []

    def source() -> list[Derivation]:
        asked.append(1)
        return list(now)

    holder.subscribe(ignore, derive_now=source)
    holder.subscribe(ignore, derive=(third,))
    assert holder.derivations == (first, third)
    now[:] = [second, third, second]  # the publisher's settings changed
    assert holder.derivations == (second, third)
    now.clear()
    assert holder.derivations == (third,)
    assert len(asked) == 3


# ---------------------------------------------------------------------------- the poll loop


def one_device_poller(holder: SnapshotHolder) -> tuple[Poller, VirtualTransport]:
    device = device_config_for("arr", 1, [SensorParams()] * 4, 2, 2.5)
    bus = bus_config_for("line", "tcp", [device], host="127.0.0.1", port=502, timeout_s=0.2)
    image = VirtualDevice()
    image.set_input(2, [0, 0, 0, 1234])  # device clock: 1.234 s, uint64 ms
    image.set_input(16, [0] * 33)  # the three status bitmaps and every register between them
    image.set_input(100, [4413, 6314, 11518, 32800])  # the ADC counts of 4 channels
    vt = VirtualTransport("line", {1: image}, timeout_s=0.2)
    poller = Poller(
        gateway_config_for([bus]),
        holder,
        transport_factory=lambda _bus: vt,
        rng=random.Random(3),
        wall_clock=lambda: 1_700_000_000.0,
    )
    return poller, vt


async def test_the_poll_loop_derives_once_per_snapshot_before_publishing_it() -> None:
    holder = SnapshotHolder()
    counted = Counted()
    seen_at_publish: list[int] = []

    def subscriber(snapshot: GatewaySnapshot) -> None:
        snap = snapshot.devices.get("arr")
        if snap is not None and snap.polled:
            seen_at_publish.append(counted.calls_for(snap))

    holder.subscribe(subscriber, derive=(counted,))
    poller, vt = one_device_poller(holder)
    await poller.poll_once()
    snap = poller.snapshot().devices["arr"]
    assert snap.polled and snap.up, snap.error
    assert len(vt.requests) == 3
    # computed once, for the published snapshot itself, in the poll loop's thread
    assert [(s, t) for s, t, _ in counted.calls] == [(snap, threading.current_thread())]
    assert seen_at_publish == [1], "the subscriber saw the snapshot before its derivation"
    value = counted.calls[0][2]
    assert snap.derived(counted) is value
    assert snap.derived(counted) is value
    assert len(counted.calls) == 1, "derived() computed again"


async def test_each_poll_derives_for_its_own_snapshot_what_the_subscribers_want_then() -> None:
    holder = SnapshotHolder()
    a, b = Counted(), Counted()
    wanted: list[Derivation] = [a]
    holder.subscribe(ignore, derive_now=lambda: wanted)
    holder.subscribe(ignore, derive=(a,))  # named twice: still computed once
    poller, _ = one_device_poller(holder)
    worker = poller.workers[0]
    try:
        await worker.poll_cycle()
        snap1 = poller.snapshot().devices["arr"]
        wanted[:] = [b]  # the subscriber wants another derivation from now on
        await worker.poll_cycle()
        snap2 = poller.snapshot().devices["arr"]
    finally:
        await worker.close()
    assert snap1 is not snap2 and snap1.up and snap2.up
    assert [s for s, _, _ in a.calls] == [snap1, snap2]  # the second subscriber still wants a
    assert [s for s, _, _ in b.calls] == [snap2]
    assert snap1.derived(a) is a.calls[0][2] and snap2.derived(a) is a.calls[1][2]
    assert snap2.derived(b) is b.calls[0][2]
    assert len(a.calls) == 2 and len(b.calls) == 1
    snap1.derived(b)  # never derived for the first snapshot: computed now, on demand
    assert [s for s, _, _ in b.calls] == [snap2, snap1]


def test_one_function_for_derive_is_refused_at_once() -> None:
    holder = SnapshotHolder()
    with pytest.raises(TypeError, match="derive=\\(fn,\\)"):
        holder.subscribe(ignore, derive=Counted())  # type: ignore[arg-type]
    assert holder.derivations == ()


async def test_a_failing_derivation_does_not_fail_the_poll() -> None:
    holder = SnapshotHolder()

    def broken(snap: DeviceSnapshot) -> object:
        raise ValueError("the subscriber's bug")

    holder.subscribe(ignore, derive=(broken,))
    poller, _ = one_device_poller(holder)
    await poller.poll_once()
    snap = poller.snapshot().devices["arr"]
    counters = poller.snapshot().counters["arr"]
    assert snap.polled and snap.up, snap.error
    assert sum(counters.read_errors_total.values()) == 0, counters.read_errors_total
    with pytest.raises(ValueError, match="the subscriber's bug"):  # where the subscriber asks
        snap.derived(broken)
