"""The MQTT side of a running gateway: one publisher for the current ``[mqtt]`` settings
(restarted when they change on reload, stopped when the section goes), and its counters as
Prometheus metrics."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector, CollectorRegistry

from ..config import GatewayConfig
from ..runtime.snapshot import DeviceSnapshot, GatewaySnapshot
from .publisher import MqttPublisher, MqttStats

__all__ = ["MqttLink"]

log = logging.getLogger(__name__)


class MqttLink(Collector):
    """Owns the publisher; ``on_snapshot`` goes to the poller's holder, ``collect`` to the
    metrics registry. Counters survive a publisher restart."""

    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self._lock = threading.Lock()
        self._publisher: MqttPublisher | None = None
        self._carried = MqttStats({}, {}, False, 0)
        if registry is not None:
            registry.register(self)

    def apply(self, config: GatewayConfig) -> None:
        """Start, restart, reload or stop the publisher for ``config``."""
        with self._lock:
            old = self._publisher
        if old is not None and config.mqtt == old.settings:
            old.reload(config)
            return
        if old is not None:
            old.stop()
            stats = old.stats()
            with self._lock:
                self._carried = _add(self._carried, stats)
                self._publisher = None
        if config.mqtt is not None:
            publisher = MqttPublisher(config)
            publisher.start()
            log.info(
                "publishing frames to mqtt %s:%s under %s",
                config.mqtt.host,
                config.mqtt.port,
                config.mqtt.topic(),
            )
            with self._lock:
                self._publisher = publisher

    @property
    def derivations(self) -> tuple[Callable[[DeviceSnapshot], object], ...]:
        """What the current publisher derives from every device snapshot (none without one)."""
        publisher = self._publisher
        return () if publisher is None else publisher.derivations

    def on_snapshot(self, snapshot: GatewaySnapshot) -> None:
        publisher = self._publisher
        if publisher is not None:
            publisher.on_snapshot(snapshot)

    def stop(self) -> None:
        """Stop the publisher (it says ``offline`` and flushes what it can)."""
        with self._lock:
            old, self._publisher = self._publisher, None
        if old is not None:
            old.stop()
            with self._lock:
                self._carried = _add(self._carried, old.stats())

    def stats(self) -> MqttStats:
        with self._lock:
            publisher, carried = self._publisher, self._carried
        if publisher is None:
            return MqttStats(
                dict(carried.published), dict(carried.dropped), False, 0, dict(carried.sent), carried.messages
            )
        return _add(carried, publisher.stats(), live=True)

    def collect(self) -> Iterable[Metric]:
        stats = self.stats()
        published = CounterMetricFamily(
            "tactile_mqtt_frames_published",
            "Frames delivered to the MQTT broker (count; acknowledged at QoS 1), per device",
            labels=["device"],
        )
        dropped = CounterMetricFamily(
            "tactile_mqtt_frames_dropped",
            "Frames not delivered to the MQTT broker (count): the oldest of a full queue while the broker "
            "was slow or gone, or refused by the client, per device",
            labels=["device"],
        )
        for name in sorted(set(stats.published) | set(stats.dropped)):
            published.add_metric([name], float(stats.published.get(name, 0)))
            dropped.add_metric([name], float(stats.dropped.get(name, 0)))
        connected = GaugeMetricFamily(
            "tactile_mqtt_connected",
            "1 if the gateway is connected to its MQTT broker, else 0 (dimensionless)",
        )
        connected.add_metric([], 1.0 if stats.connected else 0.0)
        queued = GaugeMetricFamily("tactile_mqtt_queue_frames", "Frames waiting for the MQTT broker (count)")
        queued.add_metric([], float(stats.queued))
        return [published, dropped, connected, queued]


def _add(a: MqttStats, b: MqttStats, live: bool = False) -> MqttStats:
    published = dict(a.published)
    for k, v in b.published.items():
        published[k] = published.get(k, 0) + v
    dropped = dict(a.dropped)
    for k, v in b.dropped.items():
        dropped[k] = dropped.get(k, 0) + v
    sent = dict(a.sent)
    for k, v in b.sent.items():
        sent[k] = sent.get(k, 0) + v
    return MqttStats(
        published,
        dropped,
        b.connected if live else False,
        b.queued if live else 0,
        sent,
        a.messages + b.messages,
    )
