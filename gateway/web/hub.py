"""Fan-out of every poll to the page and stream clients, without ever holding up the poller.

The poller publishes a ``GatewaySnapshot`` after each device poll (in its own thread and
loop); ``FrameHub.on_snapshot`` only notes which device changed, numbers that poll (a per-
device sequence from 1) and hands it to the server's loop through a bounded inbox, waking
that loop at most once per batch. A device's placeholder before its first poll completes
(``DeviceSnapshot.polled`` false) is listed with ``seq`` 0 but is not a frame: nothing is
sent for a device until a poll of it has completed (a failed first poll is sent, ``up``
false). In the server's loop ``drain`` encodes each frame once (a view of the snapshot's
shared ``Frame``, which MQTT encodes too: whichever needs it first builds it) and offers it
to the clients:

* ``StreamQueue``: every frame of one device for a program, bounded; when full the oldest
  frame is dropped and counted, so a client that falls behind sees a gap in ``seq`` and the
  hub counts the frames dropped for it (``dropped_total``). A gap already in the offered
  sequence (the inbox overflowed) counts the same way.
* ``PageQueue``: the newest frame per device for a browser, at most ``max_fps`` batches a
  second; a frame not yet sent is replaced by a newer one (newest frame wins), so a slow or
  stalled browser never grows a queue.

Nothing here sleeps or reads a clock by itself: times are passed in, so the logic is driven
deterministically in tests.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass

from ..runtime.counters import DeviceCounters
from ..runtime.frame import frame_of
from ..runtime.poller import SnapshotHolder
from ..runtime.snapshot import DeviceSnapshot, GatewaySnapshot
from .frames import encode_frame
from .history import DeviceHistory

Wakeup = Callable[[], None]
Schedule = Callable[[Callable[[], None]], object]


def _noop() -> None:
    return None


class StreamQueue:
    """Every frame of one device for one client; at most ``capacity`` waiting."""

    def __init__(self, device: str, capacity: int = 256, wakeup: Wakeup = _noop) -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.device = device
        self.capacity = capacity
        self.dropped = 0
        self._frames: deque[tuple[int, bytes]] = deque()
        self._next_seq: int | None = None
        self._wakeup = wakeup
        self.closed = False

    def offer(self, seq: int, frame: bytes) -> int:
        """Queue one frame; returns how many frames this offer dropped (gap + evicted)."""
        lost = 0
        if self._next_seq is not None and seq > self._next_seq:
            lost += seq - self._next_seq  # never offered: the hub's inbox overflowed
        self._next_seq = max(seq + 1, self._next_seq or 0)
        self._frames.append((seq, frame))
        while len(self._frames) > self.capacity:
            self._frames.popleft()
            lost += 1
        self.dropped += lost
        self._wakeup()
        return lost

    def expect(self, seq: int) -> None:
        """The sequence number of the next frame: fewer than that later is a gap."""
        self._next_seq = seq

    def take(self) -> list[tuple[int, bytes]]:
        """Everything waiting, oldest first."""
        out = list(self._frames)
        self._frames.clear()
        return out

    def __len__(self) -> int:
        return len(self._frames)


class PageQueue:
    """The newest frame of each device for one browser, at most ``max_fps`` batches/s."""

    def __init__(self, devices: frozenset[str] | None = None, max_fps: float = 30.0, wakeup: Wakeup = _noop):
        self.devices = devices  # None: every device
        self.min_interval_s = 1.0 / max_fps
        self.superseded = 0  # frames replaced before they were sent
        self._pending: dict[str, bytes] = {}
        self._last_sent: float | None = None
        self._wakeup = wakeup
        self.closed = False

    def offer(self, device: str, frame: bytes) -> None:
        if self.devices is not None and device not in self.devices:
            return
        if device in self._pending:
            self.superseded += 1
        self._pending[device] = frame
        self._wakeup()

    def wait_s(self, now: float) -> float | None:
        """None when nothing is pending, else how long to wait before ``take`` (0: now)."""
        if not self._pending:
            return None
        if self._last_sent is None:
            return 0.0
        return max(0.0, self._last_sent + self.min_interval_s - now)

    def take(self, now: float) -> list[bytes]:
        """The pending frames (one per device) and the send time noted."""
        out = list(self._pending.values())
        self._pending.clear()
        self._last_sent = now
        return out


@dataclass(frozen=True)
class Latest:
    """The newest poll of one device as the hub last saw it (``seq`` 0: no poll of it has
    completed yet, so it has no frame; the snapshot only gives its layout)."""

    seq: int
    snapshot: DeviceSnapshot
    counters: DeviceCounters | None


class FrameHub:
    """Numbers every device poll and offers its encoded frame to the attached clients."""

    def __init__(
        self,
        holder: SnapshotHolder | None = None,
        *,
        stream_capacity: int = 256,
        inbox_capacity: int = 4096,
        history_s: float = 0.0,
        export_s: float = 0.0,
    ) -> None:
        DeviceHistory(history_s, export_s)  # the spans' check, before anything is started
        #: what the hub keeps of each device's past (``web.history``; s, 0: nothing)
        self.history_s = float(history_s)
        self.export_s = float(export_s)
        self._history: dict[str, DeviceHistory] = {}
        self.stream_capacity = stream_capacity
        self.inbox_capacity = inbox_capacity
        self._lock = threading.Lock()
        self._latest: dict[str, Latest] = {}
        self._inbox: deque[tuple[str, Latest]] = deque()
        self._schedule: Schedule | None = None
        self._wake_pending = False
        self._streams: dict[str, set[StreamQueue]] = {}
        self._pages: set[PageQueue] = set()  # both changed under the lock: the poller reads them
        self.dropped_total: dict[str, int] = {}
        self.inbox_dropped = 0
        if holder is not None:
            holder.subscribe(self.on_snapshot, derive=(frame_of,))
            self.on_snapshot(holder.get())

    # ------------------------------------------------------------------ poller side (any thread)
    def on_snapshot(self, snap: GatewaySnapshot) -> None:
        """Note the devices polled since the last call; cheap, never blocks on clients."""
        wake: Schedule | None = None
        with self._lock:
            wanted = self.keeps_past or bool(self._pages) or any(self._streams.values())
            for name, dev in snap.devices.items():
                old = self._latest.get(name)
                if old is not None and old.snapshot is dev:
                    continue
                if not dev.polled:
                    # a placeholder before the first poll completes: listed (seq 0), never a
                    # frame, and it does not replace what a finished poll said
                    if old is None or old.seq == 0:
                        self._latest[name] = Latest(0, dev, snap.counters.get(name))
                    continue
                entry = Latest(old.seq + 1 if old is not None else 1, dev, snap.counters.get(name))
                self._latest[name] = entry
                if self._schedule is not None and wanted:
                    if len(self._inbox) >= self.inbox_capacity:
                        self._inbox.popleft()
                        self.inbox_dropped += 1
                    self._inbox.append((name, entry))
            for name in [n for n in self._latest if n not in snap.devices]:
                del self._latest[name]
            if self._inbox and self._schedule is not None and not self._wake_pending:
                self._wake_pending = True
                wake = self._schedule
        if wake is not None:
            wake(self.drain)

    @property
    def keeps_past(self) -> bool:
        """Whether the hub keeps a past of every device (``history_s`` or ``export_s`` > 0):
        then every poll is handed over, followed or not."""
        return self.history_s > 0 or self.export_s > 0

    def latest(self, device: str) -> Latest | None:
        with self._lock:
            return self._latest.get(device)

    def devices(self) -> list[Latest]:
        with self._lock:
            return [self._latest[n] for n in sorted(self._latest)]

    # ------------------------------------------------------------------ server side (its loop)
    def attach(self, schedule: Schedule) -> None:
        """From now on, hand polls to ``schedule(drain)`` (``loop.call_soon_threadsafe``)."""
        with self._lock:
            self._schedule = schedule
            self._wake_pending = False

    def detach(self) -> None:
        with self._lock:
            self._schedule = None
            self._inbox.clear()
            self._wake_pending = False

    def drain(self) -> None:
        """Encode the waiting polls once each and offer them to every client.

        Of a device's waiting polls only the newest ``stream_capacity`` can reach a client (a
        stream queue holds no more, a page only the newest): the older ones are not encoded,
        and every stream counts them lost through the gap in its sequence, as it would have
        counted them evicted. A flood of polls (or a burst after the loop was held up) thus
        costs at most one queue's worth of encoding per drain, and the senders keep their
        share of the loop."""
        with self._lock:
            batch = list(self._inbox)
            self._inbox.clear()
            self._wake_pending = False
            gone = [name for name in self._history if name not in self._latest]
        for name in gone:  # a device a reload removed: its past goes with it
            del self._history[name]
        skip = {name: n - self.stream_capacity for name, n in Counter(n for n, _ in batch).items()}
        newest: dict[str, tuple[Latest, bytes | None]] = {}  # what the pages get: one a device
        for name, entry in batch:
            if self.keeps_past:
                past = self._history.get(name)
                if past is None:
                    past = self._history[name] = DeviceHistory(self.history_s, self.export_s)
                past.add(entry.snapshot)
            if skip[name] > 0:
                skip[name] -= 1
                continue
            streams = self._streams.get(name)
            frame = None
            if streams:
                frame = encode_frame(frame_of(entry.snapshot), entry.seq, entry.counters)
                for q in streams:
                    lost = q.offer(entry.seq, frame)
                    if lost:
                        self.dropped_total[name] = self.dropped_total.get(name, 0) + lost
            newest[name] = (entry, frame)
        if self._pages:
            for name, (entry, frame) in newest.items():
                if frame is None:  # no stream wanted it: only a device's newest is encoded
                    frame = encode_frame(frame_of(entry.snapshot), entry.seq, entry.counters)
                for p in self._pages:
                    p.offer(name, frame)

    def history(self, device: str) -> DeviceHistory | None:
        """What the hub keeps of ``device``'s past (server loop only), None when it keeps
        nothing (``history_s`` and ``export_s`` 0) or the device is not listed."""
        if not self.keeps_past:
            return None
        if self.latest(device) is None:
            self._history.pop(device, None)  # a device a reload removed
            return None
        past = self._history.get(device)
        if past is None:
            past = self._history[device] = DeviceHistory(self.history_s, self.export_s)
        return past

    def open_stream(self, device: str, wakeup: Wakeup = _noop) -> StreamQueue:
        """A new stream client of ``device``: it gets every poll from the next one on."""
        q = StreamQueue(device, self.stream_capacity, wakeup)
        with self._lock:
            latest = self._latest.get(device)
            q.expect(1 if latest is None else latest.seq + 1)
            self._streams.setdefault(device, set()).add(q)
        return q

    def close_stream(self, q: StreamQueue) -> None:
        with self._lock:
            q.closed = True
            self._streams.get(q.device, set()).discard(q)
        q._wakeup()

    def open_page(self, devices: frozenset[str] | None, max_fps: float, wakeup: Wakeup = _noop) -> PageQueue:
        p = PageQueue(devices, max_fps, wakeup)
        with self._lock:
            self._pages.add(p)
        return p

    def close_page(self, p: PageQueue) -> None:
        with self._lock:
            p.closed = True
            self._pages.discard(p)
        p._wakeup()

    def close_all(self) -> None:
        """End every client (server shutdown): their senders see ``closed`` and return."""
        for qs in list(self._streams.values()):
            for q in list(qs):
                self.close_stream(q)
        for p in list(self._pages):
            self.close_page(p)

    def clients(self) -> tuple[int, int]:
        """(stream clients, page clients) now connected."""
        return sum(len(s) for s in self._streams.values()), len(self._pages)
