"""The hub's fan-out, driven by hand: every poll numbered, streams bounded with drops counted
and visible as gaps, pages newest-frame-wins at a capped rate; no clock, no sleep."""

from __future__ import annotations

import json
import random
from collections.abc import Callable

import pytest
from web_snapshots import device, gateway

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.model import SensorParams
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import ChannelStatus
from gateway.web import hub as hub_module
from gateway.web.hub import FrameHub, PageQueue, StreamQueue


class Scheduled:
    """Stands in for ``loop.call_soon_threadsafe``: collects callbacks, runs them on demand."""

    def __init__(self) -> None:
        self.calls: list[Callable[[], None]] = []

    def __call__(self, fn: Callable[[], None]) -> None:
        self.calls.append(fn)

    def run(self) -> None:
        calls, self.calls = self.calls, []
        for fn in calls:
            fn()


def seqs(q: StreamQueue) -> list[int]:
    return [s for s, _ in q.take()]


def test_stream_queue_drops_the_oldest_and_counts() -> None:
    woken: list[int] = []
    q = StreamQueue("arr", capacity=3, wakeup=lambda: woken.append(1))
    lost = [q.offer(s, b"{}") for s in range(1, 6)]
    assert lost == [0, 0, 0, 1, 1] and q.dropped == 2 and len(woken) == 5
    assert seqs(q) == [3, 4, 5]
    # a gap in the offered sequence counts as dropped too
    assert q.offer(9, b"{}") == 3 and q.dropped == 5
    assert seqs(q) == [9]
    with pytest.raises(ValueError):
        StreamQueue("arr", capacity=0)


def test_page_queue_newest_frame_wins_at_the_capped_rate() -> None:
    p = PageQueue(None, max_fps=10.0)
    assert p.wait_s(0.0) is None
    p.offer("a", b"1")
    assert p.wait_s(0.0) == 0.0
    assert p.take(0.0) == [b"1"]
    for k in range(100):  # a stalled browser: 100 polls of one device arrive
        p.offer("a", b"%d" % k)
    p.offer("b", b"x")
    assert p.superseded == 99
    assert p.wait_s(0.04) == pytest.approx(0.06)  # 10 frames/s: not before 0.1 s
    assert p.take(0.1) == [b"99", b"x"]  # one frame per device, the newest
    assert p.wait_s(0.1) is None


def test_page_queue_filters_devices() -> None:
    p = PageQueue(frozenset({"b"}), max_fps=30.0)
    p.offer("a", b"1")
    assert p.wait_s(0.0) is None
    p.offer("b", b"2")
    assert p.take(0.0) == [b"2"]


def test_hub_numbers_each_device_poll_and_wakes_once_per_batch() -> None:
    holder = SnapshotHolder()
    hub = FrameHub(holder)
    sched = Scheduled()
    hub.attach(sched)
    stream = hub.open_stream("a")
    page = hub.open_page(None, 30.0)
    a, b = device("a"), device("b")
    holder.publish(gateway(a, b))
    holder.publish(gateway(a, b))  # nothing new: no frame
    a2 = device("a", t=1001.0)
    holder.publish(gateway(a2, b))
    assert len(sched.calls) == 1  # one wake for the whole batch
    sched.run()
    assert seqs(stream) == [1, 2]
    latest = hub.latest("a")
    assert latest is not None and latest.seq == 2 and latest.snapshot is a2
    frames = [json.loads(f) for f in page.take(0.0)]
    assert {(f["device"], f["seq"]) for f in frames} == {("a", 2), ("b", 1)}


def test_a_slow_stream_client_sees_a_gap_and_the_hub_counts_its_drops() -> None:
    hub = FrameHub(stream_capacity=4)
    sched = Scheduled()
    hub.attach(sched)
    slow, fast = hub.open_stream("a"), hub.open_stream("a")
    got_fast: list[int] = []
    for k in range(10):
        hub.on_snapshot(gateway(device("a", t=float(k))))
        sched.run()
        got_fast += seqs(fast)
    assert got_fast == list(range(1, 11))
    got_slow = seqs(slow)
    assert got_slow == [7, 8, 9, 10] and slow.dropped == 6
    assert hub.dropped_total == {"a": 6}
    data = [json.loads(f) for f in hub.open_page(None, 30.0).take(0.0)]
    assert data == []  # a page opened later gets only what comes after


def test_an_overflowing_inbox_shows_as_a_gap() -> None:
    hub = FrameHub(inbox_capacity=3)
    sched = Scheduled()
    hub.attach(sched)
    q = hub.open_stream("a")
    for k in range(8):  # the server loop is busy: 8 polls, one drain
        hub.on_snapshot(gateway(device("a", t=float(k))))
    sched.run()
    assert seqs(q) == [6, 7, 8] and q.dropped == 5 and hub.inbox_dropped == 5


def test_a_burst_longer_than_a_stream_queue_encodes_only_what_can_reach_a_client(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    encoded: list[int] = []
    real = hub_module.encode_frame

    def counting(frame: object, seq: int, counters: object) -> bytes:
        encoded.append(seq)
        return real(frame, seq, counters)  # type: ignore[arg-type]

    monkeypatch.setattr(hub_module, "encode_frame", counting)
    hub = FrameHub(stream_capacity=4)
    sched = Scheduled()
    hub.attach(sched)
    q, waiting = hub.open_stream("a"), hub.open_stream("a")
    b0 = device("b", t=0.0)
    hub.on_snapshot(gateway(device("a", t=0.0), b0))
    sched.run()
    # "waiting" keeps its frame 1, unread; b has no stream and no page yet: not encoded
    assert seqs(q) == [1] and encoded == [1]
    page = hub.open_page(None, 30.0)
    for k in range(1, 11):  # the server loop is held up: 10 polls of a and 2 of b, one drain
        b = device("b", t=float(k)) if k > 8 else b0  # the same snapshot: not a new poll
        hub.on_snapshot(gateway(device("a", t=float(k)), b))
    encoded.clear()
    sched.run()
    # a's polls 2..7 can reach no client (4 fit in a queue): not encoded, counted lost; b
    # has no stream, so of its polls 2 and 3 only the newest is encoded, for the page
    assert sorted(encoded) == [3, 8, 9, 10, 11]
    assert seqs(q) == [8, 9, 10, 11] and q.dropped == 6
    assert seqs(waiting) == [8, 9, 10, 11] and waiting.dropped == 7  # and its unread frame 1
    assert hub.dropped_total == {"a": 13}
    newest = {f["device"]: f["seq"] for f in map(json.loads, page.take(0.0))}
    assert newest == {"a": 11, "b": 3}


def test_a_detached_hub_keeps_the_latest_and_queues_nothing() -> None:
    hub = FrameHub()
    hub.on_snapshot(gateway(device("a")))
    hub.on_snapshot(gateway(device("a", t=2.0)))
    latest = hub.latest("a")
    assert latest is not None and latest.seq == 2
    sched = Scheduled()
    hub.attach(sched)
    assert sched.calls == []
    hub.open_stream("b")
    hub.on_snapshot(gateway(device("b")))  # "a" is gone from the gateway
    assert hub.latest("a") is None and [e.snapshot.device for e in hub.devices()] == ["b"]
    hub.detach()
    hub.on_snapshot(gateway(device("b", t=3.0)))
    assert len(sched.calls) == 1


def test_a_hub_nobody_follows_numbers_polls_but_wakes_nothing() -> None:
    """No stream, no page, no history: a poll costs the server's loop nothing (no wake, no
    encoding); the sequence goes on, so a client that comes later starts where it stands."""
    hub = FrameHub()
    sched = Scheduled()
    hub.attach(sched)
    for k in range(5):
        hub.on_snapshot(gateway(device("a", t=float(k))))
    assert sched.calls == []
    latest = hub.latest("a")
    assert latest is not None and latest.seq == 5
    q = hub.open_stream("a")
    hub.on_snapshot(gateway(device("a", t=5.0)))
    assert len(sched.calls) == 1
    sched.run()
    assert seqs(q) == [6] and q.dropped == 0  # no gap: it expected 6
    hub.close_stream(q)
    hub.close_stream(q)  # twice: counted once
    assert hub.clients() == (0, 0)
    hub.on_snapshot(gateway(device("a", t=6.0)))
    assert sched.calls == []
    page = hub.open_page(None, 30.0)
    hub.on_snapshot(gateway(device("a", t=7.0)))
    assert len(sched.calls) == 1
    hub.close_page(page)


def test_a_hub_that_keeps_history_is_woken_with_nobody_following() -> None:
    hub = FrameHub(history_s=10.0)
    sched = Scheduled()
    hub.attach(sched)
    hub.on_snapshot(gateway(device("a", t=1000.0)))
    hub.on_snapshot(gateway(device("a", t=1001.0)))
    assert len(sched.calls) == 1
    sched.run()
    past = hub.history("a")
    assert past is not None and len(past.points(10.0)) == 2


def test_a_page_gets_the_newest_poll_of_a_drain_encoded_once() -> None:
    """Five polls of a device no stream follows, one drain: the page gets the newest, the
    only one encoded; with a stream, every poll is encoded once, and the page shares it."""
    encoded: list[int] = []
    real = hub_module.encode_frame

    def counting(frame: object, seq: int, counters: object) -> bytes:
        encoded.append(seq)
        return real(frame, seq, counters)  # type: ignore[arg-type]

    hub = FrameHub()
    sched = Scheduled()
    hub.attach(sched)
    page = hub.open_page(None, 30.0)
    with pytest.MonkeyPatch.context() as m:
        m.setattr(hub_module, "encode_frame", counting)
        for k in range(5):
            hub.on_snapshot(gateway(device("a", t=float(k))))
        sched.run()
        assert encoded == [5] and page.superseded == 0
        assert [json.loads(f)["seq"] for f in page.take(0.0)] == [5]
        q = hub.open_stream("a")
        for k in range(5, 8):
            hub.on_snapshot(gateway(device("a", t=float(k))))
        sched.run()
    assert encoded == [5, 6, 7, 8] and seqs(q) == [6, 7, 8]
    assert [json.loads(f)["seq"] for f in page.take(1.0)] == [8]


def test_closing_ends_every_client() -> None:
    hub = FrameHub()
    woken: list[str] = []
    s = hub.open_stream("a", lambda: woken.append("s"))
    p = hub.open_page(None, 30.0, lambda: woken.append("p"))
    assert hub.clients() == (1, 1)
    hub.close_all()
    assert s.closed and p.closed and sorted(woken) == ["p", "s"] and hub.clients() == (0, 0)


def _polled_poller(fail_first: bool) -> Poller:
    """A 4-channel device on the in-process virtual bus (whose first poll fails if asked)."""
    dev = VirtualDevice()
    dev.set_input(2, [0, 0, 0, 1234])
    dev.set_input(16, [0] * 33)
    dev.set_input(100, [4413, 6314, 11518, 32800])
    device_cfg = device_config_for("arr", 1, [SensorParams()] * 4, 2, 2.5)
    bus = bus_config_for("line", "tcp", [device_cfg], host="127.0.0.1", port=502, retries=1,
                         backoff_initial_s=0.1, backoff_max_s=2.0, timeout_s=0.2)  # fmt: skip
    vt = VirtualTransport("line", {1: dev}, timeout_s=0.2)
    if fail_first:
        vt.fail_next("timeout", times=10)
    return Poller(gateway_config_for([bus]), transport_factory=lambda _bus: vt, rng=random.Random(7),
                  wall_clock=lambda: 1_700_000_000.0)  # fmt: skip


async def test_nothing_is_streamed_for_a_device_before_its_first_poll_completes() -> None:
    # sequence 1 is the first poll, not a stale "outage" published at start
    poller = _polled_poller(fail_first=False)
    hub, sched = FrameHub(poller.holder), Scheduled()
    hub.attach(sched)
    q = hub.open_stream("arr")
    page = hub.open_page(None, max_fps=1000.0)
    await poller.poll_once()
    sched.run()
    frames = [json.loads(f) for _, f in q.take()]
    assert [f["seq"] for f in frames] == [1]
    assert frames[0]["up"] is True and ChannelStatus.STALE not in frames[0]["status"]
    assert [json.loads(f)["seq"] for f in page.take(0.0)] == [1]
    assert q.dropped == 0 and hub.latest("arr").seq == 1  # type: ignore[union-attr]
    hub.close_all()


async def test_a_device_that_fails_its_first_poll_is_streamed_as_down() -> None:
    poller = _polled_poller(fail_first=True)
    hub, sched = FrameHub(poller.holder), Scheduled()
    hub.attach(sched)
    q = hub.open_stream("arr")
    await poller.poll_once()
    sched.run()
    frames = [json.loads(f) for _, f in q.take()]
    assert [f["seq"] for f in frames] == [1]
    assert frames[0]["up"] is False and frames[0]["status"] == [ChannelStatus.STALE] * 4
    assert frames[0]["error"] and "not polled yet" not in frames[0]["error"]
    hub.close_all()
