"""The MQTT publisher: every poll of every device as one frame, beside the poll loop.

``on_snapshot`` (subscribed to the poller's ``SnapshotHolder``) only appends the new device
snapshots to a bounded queue, so polling never waits on the broker. One thread owns the
paho client: it connects (TLS, user and password), drives the network loop, turns queued
snapshots into frames (``payload``) and publishes them: one frame per message when one is
waiting, several polls of a device in one message (a batch, at most ``max_batch_frames``)
when more wait; while frames keep coming, messages leave at most every ``batch_interval_s``
so that the polls in between share one (a message costs the client and the broker far more
than the bytes of another frame in it). When the broker is slow or gone the
queue fills and its oldest frames are dropped and counted; the thread reconnects after a
jittered back-off (uniform in ``[0, b]``, b doubling from 0.5 s to 30 s). Sequence numbers
count the polls of a device, so a subscriber sees a dropped frame as a gap. Nothing is
published for a device before its first poll completes (sequence 1 is that poll; a failed
first poll is published, ``up`` false).

Topics (``docs/mqtt.md``): ``<prefix>/<gateway>/status`` (``online``/``offline``, retained,
``offline`` as the last will), ``<prefix>/<gateway>/<device>/meta`` (retained: channels,
positions, units, effects, encoding; republished on reload) and
``<prefix>/<gateway>/<device>/frame``.
"""

from __future__ import annotations

import json
import logging
import math
import random
import ssl
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTProtocolVersion

from ..config import GatewayConfig
from ..config.mqtt import MqttConfig
from ..config.tables import read_text_file
from ..runtime.frame import frame_of
from ..runtime.priority import polls_fast, yield_to_poll_loop
from ..runtime.snapshot import DeviceSnapshot, GatewaySnapshot
from .payload import (
    encode_binary,
    encode_binary_batch,
    encode_json_batch,
    encode_json_frame,
    frame_dict,
    json_body,
)

__all__ = ["MqttPublisher", "MqttStats", "meta_dict"]

log = logging.getLogger(__name__)

BACKOFF_INITIAL_S = 0.5
BACKOFF_MAX_S = 30.0
KEEPALIVE_S = 15
LOOP_TIMEOUT_S = 0.02
STOP_FLUSH_S = 5.0
#: QoS 1 messages (a frame or a batch) sent and not yet acknowledged, at most (paho's default window)
INFLIGHT_WINDOW = 20
#: frames dropped are said at warning level at most this often, with the counts since
DROP_LOG_INTERVAL_S = 10.0


@dataclass(frozen=True)
class MqttStats:
    """Counters for the metrics: frames published (acknowledged at QoS 1) and dropped, per
    device; whether the broker connection is up; frames waiting; frames handed to the client
    (``sent``, per device: published, in flight, or refused) and the messages that carried the
    published frames (``messages``: fewer than the frames when they went out in batches)."""

    published: dict[str, int]
    dropped: dict[str, int]
    connected: bool
    queued: int
    sent: dict[str, int] = field(default_factory=dict)
    messages: int = 0


def meta_dict(config: GatewayConfig, device_name: str, encoding: str) -> dict[str, Any]:
    """The retained description of a device's frames."""
    _, dev = config.find_device(device_name)
    return {
        "device": dev.name,
        "encoding": encoding,
        "channels": [
            {
                "index": ch.index,
                "name": ch.name,
                "x_mm": ch.x_mm,
                "y_mm": ch.y_mm,
                "effects": list(ch.effects),
            }
            for ch in dev.enabled_channels
        ],
        "layout": {
            "columns": dev.layout.columns,
            "rows": dev.layout.rows,
            "pitch_x_mm": dev.layout.pitch_x_mm,
            "pitch_y_mm": dev.layout.pitch_y_mm,
            "origin": dev.layout.origin,
            "order": dev.layout.order,
        },
        "profile": dev.profile,
        "units": {"force": "N", "resistance": "ohm", "position": "mm", "time": "s", "area": "mm^2"},
    }


class MqttPublisher:
    """Publishes the frames of a configuration's devices to ``config.mqtt``'s broker."""

    def __init__(
        self,
        config: GatewayConfig,
        *,
        client_factory: Callable[..., mqtt.Client] = mqtt.Client,
        rng: random.Random | None = None,
    ) -> None:
        if config.mqtt is None:
            raise ValueError("the configuration has no [mqtt] section")
        self.settings: MqttConfig = config.mqtt
        self._config = config
        self._queue: deque[tuple[str, int, DeviceSnapshot]] = deque()
        self._cond = threading.Condition()
        self._seq: dict[str, int] = {}
        self._last: dict[str, DeviceSnapshot] = {}
        self._last_sent: dict[str, float] = {}
        self._published: dict[str, int] = {}
        self._dropped: dict[str, int] = {}
        self._sent: dict[str, int] = {}
        self._messages = 0
        self._in_flight: dict[int, tuple[str, int]] = {}  # message id: device, frames
        self._last_drain_s = -math.inf  # monotonic time frames last went out
        self._connected = False
        self._stopping = False
        self._meta_due = True
        self._rng = rng or random.Random()
        self._logged: set[str] = set()
        self._drops_reported: dict[str, int] = {}
        self._drops_reported_at = -math.inf
        self._client = self._make_client(client_factory)
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ the poll side
    def on_snapshot(self, snapshot: GatewaySnapshot) -> None:
        """Queue the devices' new snapshots (cheap: runs in the poller after each publish)."""
        now = time.monotonic()
        rate = self.settings.max_rate_hz
        with self._cond:
            for name, dev in snapshot.devices.items():
                if self._last.get(name) is dev:
                    continue
                self._last[name] = dev
                if not dev.polled:
                    continue  # listed before its first poll completed: no observation, no frame
                seq = self._seq.get(name, 0) + 1
                self._seq[name] = seq
                if rate > 0 and now - self._last_sent.get(name, -1e300) < 1.0 / rate:
                    continue  # decimated by the configured rate: a gap by design
                self._last_sent[name] = now
                if len(self._queue) >= self.settings.queue_frames:
                    old = self._queue.popleft()[0]
                    self._dropped[old] = self._dropped.get(old, 0) + 1
                self._queue.append((name, seq, dev))
            self._cond.notify()

    def stats(self) -> MqttStats:
        with self._cond:
            return MqttStats(
                dict(self._published),
                dict(self._dropped),
                self._connected,
                len(self._queue),
                dict(self._sent),
                self._messages,
            )

    def reload(self, config: GatewayConfig) -> None:
        """A new configuration of the same broker settings: republish the meta messages."""
        with self._cond:
            self._config = config
            self._meta_due = True
            self._cond.notify()

    @property
    def derivations(self) -> tuple[Callable[[DeviceSnapshot], object], ...]:
        """What this publisher derives from every device snapshot (for ``SnapshotHolder.
        subscribe``'s ``derive``): the frame, and its JSON body when publishing JSON."""
        return (frame_of,) if self.settings.encoding == "binary" else (frame_of, json_body)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="tactile-mqtt", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Say ``offline`` (retained), flush for at most ``STOP_FLUSH_S``, disconnect."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout=STOP_FLUSH_S + 5.0)
            self._thread = None

    # ------------------------------------------------------------------ the client thread
    def _make_client(self, factory: Callable[..., mqtt.Client]) -> mqtt.Client:
        s = self.settings
        protocol = MQTTProtocolVersion.MQTTv5 if s.protocol == "5" else MQTTProtocolVersion.MQTTv311
        client = factory(
            callback_api_version=CallbackAPIVersion.VERSION2,
            client_id=s.client_id,
            protocol=protocol,
            reconnect_on_failure=False,
        )
        client.will_set(s.topic("status"), "offline", qos=1, retain=True)
        if s.username is not None:
            password = None
            if s.password_file is not None:
                password = read_text_file(s.password_file, "password file").rstrip("\r\n")
            client.username_pw_set(s.username, password)
        if s.tls is not None:
            client.tls_set(
                ca_certs=str(s.tls.ca_file) if s.tls.ca_file else None,
                certfile=str(s.tls.cert_file) if s.tls.cert_file else None,
                keyfile=str(s.tls.key_file) if s.tls.key_file else None,
                cert_reqs=ssl.CERT_REQUIRED if s.tls.verify else ssl.CERT_NONE,
            )
            client.tls_insecure_set(not s.tls.verify)
        client.max_queued_messages_set(s.queue_frames)
        client.max_inflight_messages_set(INFLIGHT_WINDOW)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_publish = self._on_publish
        return client

    def _log_once(self, message: str) -> None:
        if message not in self._logged:
            self._logged.add(message)
            log.warning("%s", message)

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if getattr(reason, "is_failure", False):
            self._log_once(f"mqtt: the broker {self._where()} refused the connection: {reason}")
            return
        log.info("mqtt: connected to %s", self._where())
        self._logged.clear()
        client.publish(self.settings.topic("status"), "online", qos=1, retain=True)
        with self._cond:
            self._connected = True
            self._meta_due = True
            self._cond.notify()

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        with self._cond:
            self._connected = False

    def _on_publish(self, client: mqtt.Client, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        with self._cond:
            entry = self._in_flight.pop(mid, None)
            if entry is not None:
                name, frames = entry
                self._published[name] = self._published.get(name, 0) + frames
                self._messages += 1

    def _where(self) -> str:
        return f"{self.settings.host}:{self.settings.port}"

    def _wait(self, seconds: float) -> None:
        with self._cond:
            if not self._stopping:
                self._cond.wait(seconds)

    def _run(self) -> None:
        if polls_fast(self._config):
            yield_to_poll_loop()  # a fast bus: its answers before these frames
        backoff = BACKOFF_INITIAL_S
        socket_open = False
        while True:
            with self._cond:
                stopping = self._stopping
            if stopping:
                break
            if not socket_open:
                try:
                    self._client.connect(self.settings.host, self.settings.port, keepalive=KEEPALIVE_S)
                    socket_open = True
                    backoff = BACKOFF_INITIAL_S
                except (OSError, ValueError) as exc:
                    self._log_once(f"mqtt: cannot connect to {self._where()}: {exc}")
                    self._wait(self._rng.uniform(0.0, backoff))
                    backoff = min(BACKOFF_MAX_S, 2.0 * backoff)
                    continue
            rc = self._client.loop(timeout=self._loop_timeout_s(time.monotonic()))
            if rc != mqtt.MQTT_ERR_SUCCESS:
                socket_open = False
                with self._cond:
                    self._connected = False
                self._log_once(f"mqtt: lost the connection to {self._where()} ({mqtt.error_string(rc)})")
                self._wait(self._rng.uniform(0.0, backoff))
                backoff = min(BACKOFF_MAX_S, 2.0 * backoff)
                continue
            now = time.monotonic()
            if self._drain_due(now):
                self._drain(now)
            self._report_drops(now)
        self._finish(socket_open)
        self._report_drops(time.monotonic(), at_stop=True)  # what the stop itself dropped too

    def _report_drops(self, now: float, at_stop: bool = False) -> None:
        """Say the frames dropped since the last report at warning level, per device and in
        all, at most once per ``DROP_LOG_INTERVAL_S`` (``now``: monotonic seconds) and once
        more ``at_stop``; the first drop is said at once."""
        if now - self._drops_reported_at < DROP_LOG_INTERVAL_S and not at_stop:
            return
        with self._cond:
            dropped = dict(self._dropped)
        new = {n: c - self._drops_reported.get(n, 0) for n, c in sorted(dropped.items())}
        new = {n: c for n, c in new.items() if c > 0}
        if not new:
            return
        since = (
            "since the start"
            if math.isinf(self._drops_reported_at)
            else f"in the last {now - self._drops_reported_at:.0f} s"
        )
        self._drops_reported, self._drops_reported_at = dropped, now
        log.warning(
            "mqtt: %d frame(s) dropped %s (%s; %d in all): the broker %s acknowledged fewer frames than "
            "were polled, or was away, and the queue (queue_frames = %d) was full",
            sum(new.values()),
            since,
            ", ".join(f"{n} {c}" for n, c in new.items()),
            sum(dropped.values()),
            self._where(),
            self.settings.queue_frames,
        )

    def _batching(self) -> bool:
        return self.settings.max_batch_frames > 1 and self.settings.batch_interval_s > 0.0

    def _drain_due(self, now: float) -> bool:
        """Whether to publish now (``now``: monotonic s): always without batching; with it, once
        ``batch_interval_s`` has passed since frames last went out, or a full batch waits (a
        frame arriving after a quiet spell goes out at once), or the meta messages are due."""
        if not self._batching() or now - self._last_drain_s >= self.settings.batch_interval_s:
            return True
        with self._cond:
            return self._meta_due or len(self._queue) >= self.settings.max_batch_frames

    def _loop_timeout_s(self, now: float) -> float:
        """How long the network loop may wait for the socket: until the next drain is due; once
        it is past (the drain found no room: the window is full, or the broker is away), for
        acknowledgements as without batching, never 0 s over and over (a spinning thread)."""
        due = self._last_drain_s + self.settings.batch_interval_s - now
        if not self._batching() or not self._queue or due <= 0.0:
            return LOOP_TIMEOUT_S
        return min(LOOP_TIMEOUT_S, due)

    def _take(self, messages: int) -> list[list[tuple[str, int, DeviceSnapshot]]]:
        """At most ``messages`` groups of queued frames (the caller holds the lock), each of one
        device, at most ``max_batch_frames``, in queue order; a device's frames in sequence
        order; frames of other devices passed over stay at the front, in order."""
        groups: list[list[tuple[str, int, DeviceSnapshot]]] = []
        limit = self.settings.max_batch_frames
        while len(groups) < messages and self._queue:
            name = self._queue[0][0]
            group: list[tuple[str, int, DeviceSnapshot]] = []
            others: list[tuple[str, int, DeviceSnapshot]] = []
            while self._queue and len(group) < limit:
                item = self._queue.popleft()
                (group if item[0] == name else others).append(item)
            self._queue.extendleft(reversed(others))
            groups.append(group)
        return groups

    def _payload(self, group: list[tuple[str, int, DeviceSnapshot]]) -> bytes:
        """One message: the single frame as ever, or a batch of the group's frames."""
        if self.settings.encoding == "binary":
            frames = [encode_binary(frame_dict(frame_of(snap), seq)) for _, seq, snap in group]
            return frames[0] if len(frames) == 1 else encode_binary_batch(frames)
        # built once per snapshot (by the poll loop, see ``derivations``), shared with the page
        bodies = [encode_json_frame(snap, seq) for _, seq, snap in group]
        return bodies[0] if len(bodies) == 1 else encode_json_batch(bodies)

    def _drain(self, now: float | None = None) -> None:
        """Publish what is queued while the connection is up (the meta messages first); ``now``
        (monotonic s) is when, for ``batch_interval_s``."""
        with self._cond:
            if not self._connected:
                return
            meta_due, self._meta_due = self._meta_due, False
            config = self._config
            # at QoS 1 only as many messages as the window has room for: the rest wait in this
            # queue (bounded, oldest dropped), not in paho's, whose every acknowledgement scans
            # all it holds (a backlog there grows the cost of each message with the backlog)
            room = len(self._queue) if self.settings.qos == 0 else INFLIGHT_WINDOW - len(self._in_flight)
            groups = self._take(max(0, room))
        if meta_due:
            for _, device in config.devices():
                payload = json.dumps(meta_dict(config, device.name, self.settings.encoding))
                self._client.publish(self.settings.topic(device.name, "meta"), payload, qos=1, retain=True)
        if groups:
            self._last_drain_s = time.monotonic() if now is None else now
        for group in groups:
            name, frames = group[0][0], len(group)
            info = self._client.publish(
                self.settings.topic(name, "frame"), self._payload(group), qos=self.settings.qos
            )
            with self._cond:
                self._sent[name] = self._sent.get(name, 0) + frames
                if info.rc != mqtt.MQTT_ERR_SUCCESS:
                    self._dropped[name] = self._dropped.get(name, 0) + frames
                elif self.settings.qos == 0:
                    self._published[name] = self._published.get(name, 0) + frames
                    self._messages += 1
                else:
                    self._in_flight[info.mid] = (name, frames)

    def _finish(self, socket_open: bool) -> None:
        if socket_open and self._connected:
            deadline = time.monotonic() + STOP_FLUSH_S
            while True:  # what is queued, a window at a time
                self._drain()
                with self._cond:
                    waiting = bool(self._queue) and self._connected
                if not waiting or time.monotonic() >= deadline:
                    break
                if self._client.loop(timeout=LOOP_TIMEOUT_S) != mqtt.MQTT_ERR_SUCCESS:
                    break
            info = self._client.publish(self.settings.topic("status"), "offline", qos=1, retain=True)
            while time.monotonic() < deadline and (not info.is_published() or self._in_flight):
                if self._client.loop(timeout=LOOP_TIMEOUT_S) != mqtt.MQTT_ERR_SUCCESS:
                    break
            self._client.disconnect()
        with self._cond:
            self._connected = False
            for name, _, _ in self._queue:
                self._dropped[name] = self._dropped.get(name, 0) + 1
            self._queue.clear()
            for (
                name,
                frames,
            ) in self._in_flight.values():  # never acknowledged: not delivered, as far as we know
                self._dropped[name] = self._dropped.get(name, 0) + frames
            self._in_flight.clear()
