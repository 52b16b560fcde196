"""How the server's loop hands polls to the clients: at most once a drain interval when polls
come faster (``_Paced``, on a loop whose clock the test moves), at once after a pause; and a
client's one keepalive timer (``_Wake``) on a real loop."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any, cast

from web_snapshots import device, gateway

from gateway.web.app import _Paced, _Wake
from gateway.web.hub import FrameHub, StreamQueue


class SteppedLoop:
    """The three loop methods ``_Paced`` uses, on a clock the test sets."""

    def __init__(self) -> None:
        self.now_s = 0.0
        self.soon: list[Callable[[], None]] = []
        self.timers: list[tuple[float, Callable[[], None]]] = []

    def time(self) -> float:
        return self.now_s

    def call_soon_threadsafe(self, fn: Callable[..., None], *args: Any) -> None:
        self.soon.append(lambda: fn(*args))

    def call_later(self, delay_s: float, fn: Callable[..., None], *args: Any) -> None:
        self.timers.append((self.now_s + delay_s, lambda: fn(*args)))

    def run_until(self, t_s: float) -> None:
        """Run what is due up to ``t_s``, then stand at ``t_s``."""
        while True:
            if self.soon:
                self.soon.pop(0)()
                continue
            due = sorted((w, i) for i, (w, _) in enumerate(self.timers) if w <= t_s)
            if not due:
                break
            when, i = due[0]
            self.now_s = max(self.now_s, when)
            self.timers.pop(i)[1]()
        self.now_s = t_s


def seqs(q: StreamQueue) -> list[int]:
    return [s for s, _ in q.take()]


def test_polls_faster_than_the_interval_reach_a_stream_together() -> None:
    loop = SteppedLoop()
    hub = FrameHub()
    hub.attach(_Paced(cast(asyncio.AbstractEventLoop, loop), 0.010).schedule)
    q = hub.open_stream("a")
    hub.on_snapshot(gateway(device("a", t=1.0)))  # after a pause: at once
    loop.run_until(0.0)
    assert seqs(q) == [1] and loop.timers == []
    for k, t in enumerate((0.002, 0.004, 0.006), start=2):  # every 2 ms
        loop.run_until(t)
        hub.on_snapshot(gateway(device("a", t=1.0 + k)))
    loop.run_until(0.0099)
    assert seqs(q) == []  # held until the interval since the last hand-over ends
    loop.run_until(0.010)
    assert seqs(q) == [2, 3, 4]  # one hand-over for the three
    assert len(loop.timers) == 0
    loop.run_until(0.500)  # a pause: the next poll goes at once
    hub.on_snapshot(gateway(device("a", t=9.0)))
    loop.run_until(0.500)
    assert seqs(q) == [5]


def test_polls_slower_than_the_interval_are_never_held() -> None:
    loop = SteppedLoop()
    hub = FrameHub()
    hub.attach(_Paced(cast(asyncio.AbstractEventLoop, loop), 0.010).schedule)
    q = hub.open_stream("a")
    for k in range(1, 6):  # every 25 ms
        loop.run_until(0.025 * k)
        hub.on_snapshot(gateway(device("a", t=float(k))))
        loop.run_until(0.025 * k)
        assert seqs(q) == [k] and loop.timers == []


async def test_a_client_idle_for_the_keepalive_is_woken_once_for_it() -> None:
    loop = asyncio.get_running_loop()
    keepalive_s = 0.05
    wake = _Wake(keepalive_s)
    try:
        t0 = loop.time()
        await wake.wait()
        assert wake.keepalive_due and loop.time() - t0 >= keepalive_s
        wake.wrote()
        t1 = loop.time()
        assert not wake.keepalive_due
        loop.call_later(keepalive_s / 5, wake.set)  # a frame
        await wake.wait()
        assert not wake.keepalive_due
        await wake.wait()  # the keepalive counts from the last write, not from the frame
        assert wake.keepalive_due and loop.time() - t1 >= keepalive_s
    finally:
        wake.close()


async def test_a_reminder_wakes_once_at_the_earliest_time_asked_and_a_write_spends_it() -> None:
    loop = asyncio.get_running_loop()
    wake = _Wake(keepalive_s=60.0)
    try:
        t0 = loop.time()
        wake.remind(5.0)
        wake.remind(0.05)  # earlier: it stands
        wake.remind(3.0)  # later: the earlier one stands
        await wake.wait()
        woken_s = loop.time() - t0
        assert 0.05 <= woken_s < 3.0 and not wake.keepalive_due
        wake.remind(0.05)
        wake.wrote()  # the frame went out: nothing left to be reminded of
        loop.call_later(0.2, wake.set)
        t1 = loop.time()
        await wake.wait()
        assert loop.time() - t1 >= 0.2  # woken by the frame, not by the spent reminder
    finally:
        wake.close()
