"""The Foxglove publisher: every poll of the served devices, live over Foxglove's WebSocket
protocol (the ``foxglove-sdk`` server), beside the poll loop.

``on_snapshot`` (subscribed to the poller's ``SnapshotHolder``) only appends the new device
snapshots to a bounded queue, so polling never waits on the server or its clients: when the
queue is full the oldest frame is dropped and counted, and the drops are said at warning
level at most every ``DROP_LOG_INTERVAL_S``. One thread turns queued snapshots into messages
and hands them to the SDK, whose own threads serve the clients; a region's grid is built
only while a client is subscribed to it.

Topics, per served device ``<d>`` (``docs/foxglove.md``):

- ``/tactile/<d>/<region>``: ``foxglove.Grid`` (protobuf), one per region and poll: the
  region's forces in N as one float32 field ``force_n``, rows x columns, in the frame
  ``<d>`` (x to the right, y down the drawing, metres as Foxglove wants them), posed so
  that each cell sits where the page draws its taxel; stamped with the poll's wall time.
- ``/tactile/<d>/layout``: JSON, the regions' names, groups, grid shapes, pitches and places
  (mm), and each cell's channel name; sent to a client when it subscribes (and to every
  subscriber of the topic then), as a latched message would be.
- ``/tactile/<d>/summary``: JSON per poll: up, error, total force and the sum per group (N),
  channels in contact, contact area (mm^2), and the count of channels per status.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Final

import foxglove
import numpy as np
from foxglove.channels import GridChannel
from foxglove.messages import (
    Grid,
    PackedElementField,
    PackedElementFieldNumericType,
    Pose,
    Quaternion,
    Timestamp,
    Vector2,
    Vector3,
)
from foxglove.websocket import ChannelView, Client, ServerListener, WebSocketServer

from ..config import GatewayConfig
from ..config.foxglove import FoxgloveConfig
from ..config.schema import DeviceConfig
from ..runtime.priority import polls_fast, yield_to_poll_loop
from ..runtime.snapshot import IN_CONTACT, DeviceSnapshot, GatewaySnapshot
from .grids import RegionPlace, region_grids, region_places

__all__ = ["FoxglovePublisher", "FoxgloveStats", "layout_dict", "region_topic"]

log = logging.getLogger(__name__)

#: frames dropped are said at warning level at most this often, with the counts since
DROP_LOG_INTERVAL_S: Final = 10.0
STOP_JOIN_S: Final = 5.0
_MM: Final = 1e-3  # m per mm: Foxglove's scene is in metres
_FORCE_FIELD: Final = [
    PackedElementField(name="force_n", offset=0, type=PackedElementFieldNumericType.Float32)
]

LAYOUT_SCHEMA: Final[dict[str, Any]] = {
    "title": "tactile.Layout",
    "type": "object",
    "description": "Where each region of a tactile device is drawn (mm; x right, y down) and its grid",
    "properties": {
        "device": {"type": "string"},
        "frame_id": {"type": "string"},
        "units": {"type": "object"},
        "regions": {"type": "array", "items": {"type": "object"}},
    },
}
SUMMARY_SCHEMA: Final[dict[str, Any]] = {
    "title": "tactile.Summary",
    "type": "object",
    "description": "One poll of a tactile device: totals in N, contact area in mm^2, status counts",
    "properties": {
        "timestamp": {"type": "object"},
        "device": {"type": "string"},
        "up": {"type": "boolean"},
        "total_force_n": {"type": "number"},
        "group_force_n": {"type": "object"},
    },
}


def region_topic(device: str, region: str) -> str:
    return f"/tactile/{device}/{region}"


def layout_dict(device: DeviceConfig, places: list[RegionPlace]) -> dict[str, Any]:
    """The layout message of ``device`` (module docstring): places in mm, pitches in mm."""
    names = {ch.index: ch.name for ch in device.channels}
    return {
        "device": device.name,
        "frame_id": device.name,
        "units": {"position": "mm", "pitch": "mm", "force": "N", "rotation": "deg clockwise as drawn"},
        "regions": [
            {
                "name": p.name,
                "group": p.group,
                "topic": region_topic(device.name, p.name),
                "rows": p.rows,
                "columns": p.columns,
                "pitch_x_mm": p.pitch_x_mm,
                "pitch_y_mm": p.pitch_y_mm,
                "corner_x_mm": p.corner_x_mm,
                "corner_y_mm": p.corner_y_mm,
                "rotation_deg": p.rotation_deg,
                "channels": [[names.get(int(k)) for k in row] for row in p.indices],
            }
            for p in places
        ],
    }


def split_time_s(seconds: float) -> tuple[int, int]:
    """Unix time in s as (whole seconds, nanoseconds), rounded to the nanosecond."""
    sec = math.floor(seconds)
    nsec = round((seconds - sec) * 1e9)
    return (sec + 1, nsec - 1_000_000_000) if nsec >= 1_000_000_000 else (sec, nsec)


@dataclass(frozen=True)
class FoxgloveStats:
    """Frames handed to the server per device (``published``) and dropped from a full queue."""

    published: dict[str, int]
    dropped: dict[str, int]
    queued: int


class _Device:
    """One served device: its channels and the parts of its messages that never change."""

    def __init__(self, device: DeviceConfig, context: foxglove.Context) -> None:
        self.config = device
        self.places = region_places(device)
        self.grids = [GridChannel(region_topic(device.name, p.name), context=context) for p in self.places]
        self.layout = foxglove.Channel(
            f"/tactile/{device.name}/layout", schema=LAYOUT_SCHEMA, context=context
        )
        self.summary = foxglove.Channel(
            f"/tactile/{device.name}/summary", schema=SUMMARY_SCHEMA, context=context
        )
        self.layout_bytes = json.dumps(layout_dict(device, self.places)).encode("utf-8")
        self.poses = []
        self.cell_sizes = []
        for p in self.places:
            half = math.radians(p.rotation_deg) / 2
            self.poses.append(
                Pose(
                    position=Vector3(x=p.corner_x_mm * _MM, y=p.corner_y_mm * _MM, z=0.0),
                    orientation=Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)),
                )
            )
            self.cell_sizes.append(Vector2(x=p.pitch_x_mm * _MM, y=p.pitch_y_mm * _MM))
        self.groups = sorted({p.group for p in self.places})
        self.group_of = [self.groups.index(p.group) for p in self.places]

    def close(self) -> None:
        for grid in self.grids:
            grid.close()
        self.layout.close()
        self.summary.close()

    def publish(self, snap: DeviceSnapshot) -> None:
        sec, nsec = split_time_s(snap.timestamp_s)
        ns = sec * 1_000_000_000 + nsec
        stamp = Timestamp(sec, nsec)
        wanted = [channel.has_sinks() for channel in self.grids]
        if any(wanted):
            grids = region_grids(snap, self.config, self.places)
            for k, (_, _rows, columns, force) in enumerate(grids):
                if not wanted[k]:
                    continue
                self.grids[k].log(
                    Grid(
                        timestamp=stamp,
                        frame_id=self.config.name,
                        pose=self.poses[k],
                        column_count=columns,
                        cell_size=self.cell_sizes[k],
                        row_stride=4 * columns,
                        cell_stride=4,
                        fields=_FORCE_FIELD,
                        data=force.astype("<f4", copy=False).tobytes(),
                    ),
                    log_time=ns,
                )
        if self.summary.has_sinks():
            self.summary.log(json.dumps(self.summary_dict(snap)).encode("utf-8"), log_time=ns)

    def summary_dict(self, snap: DeviceSnapshot) -> dict[str, Any]:
        force = np.asarray(snap.force_n, dtype=np.float64)
        contact = IN_CONTACT[np.asarray(snap.status)] & (force > 0.0)
        where = np.full(self.config.n_channels + 1, -1, dtype=np.intp)
        where[np.asarray(snap.channel_index, dtype=np.intp)] = np.arange(snap.n_channels)
        in_contact = np.append(np.where(contact, force, 0.0), 0.0)
        sums = [0.0] * len(self.groups)
        for k, place in enumerate(self.places):
            sums[self.group_of[k]] += float(in_contact[where[place.indices]].sum())
        sec, nsec = split_time_s(snap.timestamp_s)
        return {
            "timestamp": {"sec": sec, "nsec": nsec},
            "device": snap.device,
            "up": snap.up,
            "error": snap.error,
            "total_force_n": snap.total_force_n,
            "group_force_n": dict(zip(self.groups, sums, strict=True)),
            "channels_in_contact": snap.channels_in_contact,
            "contact_area_mm2": snap.contact_area_mm2,
            "status_counts": snap.status_counts(),
        }


class _Listener(ServerListener):
    """The server's callbacks (run on the SDK's threads): a client subscribing to a layout
    topic is sent the layout. Nothing here may log or ask for ``threading.current_thread()``
    (a foreign thread would be registered as a Python thread for ever)."""

    def __init__(self) -> None:
        self.layouts: dict[int, tuple[foxglove.Channel, bytes]] = {}

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        entry = self.layouts.get(channel.id)
        if entry is not None:
            entry[0].log(entry[1])

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        return None


class FoxglovePublisher:
    """Serves the frames of a configuration's devices on ``config.foxglove``'s address."""

    def __init__(self, config: GatewayConfig) -> None:
        if config.foxglove is None:
            raise ValueError("the configuration has no [foxglove] section")
        self.settings: FoxgloveConfig = config.foxglove
        self._config = config
        self._queue: deque[tuple[str, DeviceSnapshot]] = deque()
        self._cond = threading.Condition()
        self._last: dict[str, DeviceSnapshot] = {}
        self._published: dict[str, int] = {}
        self._dropped: dict[str, int] = {}
        self._drops_reported: dict[str, int] = {}
        self._drops_reported_at = -math.inf
        self._stopping = False
        self._thread: threading.Thread | None = None
        self._server: WebSocketServer | None = None
        self._devices: dict[str, _Device] = {}
        self._context: foxglove.Context | None = None

    @property
    def port(self) -> int:
        """The port the server listens on (the system's pick when configured as 0)."""
        if self._server is None:
            raise RuntimeError("the Foxglove server is not running")
        return self._server.port

    # ------------------------------------------------------------------ the poll side
    def on_snapshot(self, snapshot: GatewaySnapshot) -> None:
        """Queue the served devices' new snapshots (cheap: runs in the poller after each publish)."""
        with self._cond:
            for name, dev in snapshot.devices.items():
                if self._last.get(name) is dev or name not in self._devices:
                    continue
                self._last[name] = dev
                if not dev.polled:
                    continue  # listed before its first poll completed: no observation, no frame
                if len(self._queue) >= self.settings.queue_frames:
                    old = self._queue.popleft()[0]
                    self._dropped[old] = self._dropped.get(old, 0) + 1
                self._queue.append((name, dev))
            self._cond.notify()

    def stats(self) -> FoxgloveStats:
        with self._cond:
            return FoxgloveStats(dict(self._published), dict(self._dropped), len(self._queue))

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> FoxglovePublisher:
        """Listen (``OSError`` if the address is taken) and start the publishing thread."""
        s = self.settings
        # kept for as long as the server runs: the server holds the context weakly
        self._context = context = foxglove.Context()
        listener = _Listener()
        try:
            self._server = foxglove.start_server(
                name="tactile-gateway", host=s.host, port=s.port, context=context, server_listener=listener
            )
        except RuntimeError as exc:  # the SDK says a bind failure so
            raise OSError(f"cannot serve Foxglove on {s.host}:{s.port}: {exc}") from None
        for _, device in self._config.devices():
            if s.serves(device.name):
                served = _Device(device, context)
                self._devices[device.name] = served
                listener.layouts[served.layout.id()] = (served.layout, served.layout_bytes)
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="tactile-foxglove", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread (what is queued is dropped) and the server (its clients are closed)."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout=STOP_JOIN_S)
            self._thread = None
        if self._server is not None:
            self._server.stop()
            self._server = None
        for served in self._devices.values():
            served.close()
        self._context = None
        self._report_drops(time.monotonic(), at_stop=True)

    # ------------------------------------------------------------------ the publishing thread
    def _run(self) -> None:
        if polls_fast(self._config):
            yield_to_poll_loop()  # a fast bus: its answers before these frames
        while True:
            with self._cond:
                while not self._queue and not self._stopping:
                    self._cond.wait(DROP_LOG_INTERVAL_S)
                if self._stopping:
                    return
                batch = list(self._queue)
                self._queue.clear()
            for name, snap in batch:
                try:
                    self._devices[name].publish(snap)
                except Exception:  # a bug must not end the stream of the other devices
                    log.exception("foxglove: cannot publish a frame of %s", name)
                    continue
                with self._cond:
                    self._published[name] = self._published.get(name, 0) + 1
            self._report_drops(time.monotonic())

    def _report_drops(self, now: float, at_stop: bool = False) -> None:
        """Say the frames dropped since the last report at warning level, at most once per
        ``DROP_LOG_INTERVAL_S`` (``now``: monotonic s) and once more ``at_stop``."""
        if now - self._drops_reported_at < DROP_LOG_INTERVAL_S and not at_stop:
            return
        with self._cond:
            dropped = dict(self._dropped)
        new = {n: c - self._drops_reported.get(n, 0) for n, c in sorted(dropped.items())}
        new = {n: c for n, c in new.items() if c > 0}
        if not new:
            return
        self._drops_reported, self._drops_reported_at = dropped, now
        log.warning(
            "foxglove: %d frame(s) dropped (%s; %d in all): the publishing thread fell behind the polls "
            "and the queue (queue_frames = %d) was full",
            sum(new.values()),
            ", ".join(f"{n} {c}" for n, c in new.items()),
            sum(dropped.values()),
            self.settings.queue_frames,
        )
