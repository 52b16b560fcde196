"""The MQTT publisher's in-flight window, with a client that records what it is asked to send.

At QoS 1 the publisher hands paho at most ``INFLIGHT_WINDOW`` frames that the broker has not
acknowledged; the others wait in the publisher's own bounded queue (its oldest dropped and
counted when full), in order, and go out as acknowledgements come back. At QoS 0 nothing is
acknowledged and everything queued goes out at once. Frames keep their sequence numbers and
bytes whichever way they wait. These run with ``max_batch_frames = 1`` (one frame per message,
so a message is a frame); batches are tested in ``test_mqtt_batch.py``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import threading
from typing import Any

import pytest
from test_mqtt_payload import snapshot

from gateway.config import GatewayConfig, bus_config_for, device_config_for, gateway_config_for
from gateway.config.mqtt import MqttConfig
from gateway.model import SensorParams
from gateway.mqtt.publisher import DROP_LOG_INTERVAL_S, INFLIGHT_WINDOW, MqttPublisher
from gateway.runtime.priority import BACKGROUND_NICE
from gateway.runtime.snapshot import GatewaySnapshot

SUCCESS = 0


@dataclasses.dataclass
class Info:
    rc: int
    mid: int


class RecordingClient:
    """What ``MqttPublisher`` uses of a paho client; ``publish`` records and never sends."""

    def __init__(self, **kwargs: Any) -> None:
        self.sent: list[tuple[str, bytes | str, int]] = []
        self.inflight_limit: int | None = None
        self.on_connect: Any = None
        self.on_disconnect: Any = None
        self.on_publish: Any = None

    def will_set(self, *args: Any, **kwargs: Any) -> None: ...

    def max_queued_messages_set(self, n: int) -> None: ...

    def max_inflight_messages_set(self, n: int) -> None:
        self.inflight_limit = n

    def publish(self, topic: str, payload: bytes | str, qos: int = 0, retain: bool = False) -> Info:
        self.sent.append((topic, payload, qos))
        return Info(SUCCESS, len(self.sent))

    def frames(self) -> list[dict[str, Any]]:
        return [json.loads(p) for t, p, _ in self.sent if t.endswith("/frame")]


def config(qos: int, queue_frames: int) -> GatewayConfig:
    device = device_config_for("arr", 1, [SensorParams()] * 4, 2, 2.5)
    bus = bus_config_for("sim", "tcp", [device], host="127.0.0.1", port=5020)
    mqtt = MqttConfig(
        "127.0.0.1", 1883, None, None, None, "t", "tactile", "gw", qos=qos, queue_frames=queue_frames,
        max_batch_frames=1,
    )  # fmt: skip
    return dataclasses.replace(gateway_config_for([bus]), mqtt=mqtt)


def connected_publisher(qos: int, queue_frames: int = 1000) -> tuple[MqttPublisher, RecordingClient]:
    clients: list[RecordingClient] = []

    def factory(**kwargs: Any) -> RecordingClient:
        clients.append(RecordingClient(**kwargs))
        return clients[-1]

    publisher = MqttPublisher(config(qos, queue_frames), client_factory=factory)  # type: ignore[arg-type]
    client = clients[0]
    publisher._on_connect(client, None, None, None, None)  # type: ignore[arg-type]
    publisher._drain()  # the meta message
    client.sent.clear()
    return publisher, client


def poll(publisher: MqttPublisher, n: int) -> None:
    """``n`` polls of the device, each a new snapshot (total force 1, 2, ... N)."""
    for k in range(n):
        dev = snapshot(total_force_n=float(k + 1))
        publisher.on_snapshot(GatewaySnapshot.build({"arr": dev}, {}, k + 1))


def ack(publisher: MqttPublisher, client: RecordingClient, mids: range) -> None:
    for mid in mids:
        publisher._on_publish(client, None, mid, None, None)  # type: ignore[arg-type]


def test_at_qos_1_at_most_the_window_is_unacknowledged_and_the_rest_follow_in_order() -> None:
    publisher, client = connected_publisher(qos=1)
    assert client.inflight_limit == INFLIGHT_WINDOW == 20
    poll(publisher, 50)
    publisher._drain()
    assert [f["sequence"] for f in client.frames()] == list(range(1, 21))
    assert publisher.stats().queued == 30
    publisher._drain()  # nothing acknowledged: nothing more goes out
    assert len(client.frames()) == 20
    ack(publisher, client, range(1, 6))  # 5 acknowledged: 5 more
    publisher._drain()
    assert [f["sequence"] for f in client.frames()] == list(range(1, 26))
    ack(publisher, client, range(6, 26))
    publisher._drain()
    ack(publisher, client, range(26, 46))
    publisher._drain()
    ack(publisher, client, range(46, 51))
    frames = client.frames()
    assert [f["sequence"] for f in frames] == list(range(1, 51))
    assert [f["total_force_n"] for f in frames] == [float(k) for k in range(1, 51)]
    stats = publisher.stats()
    assert stats.published == {"arr": 50} and stats.dropped == {} and stats.queued == 0


def test_a_full_queue_drops_its_oldest_frames_while_the_window_is_full() -> None:
    publisher, client = connected_publisher(qos=1, queue_frames=10)
    poll(publisher, 20)  # the queue holds 10: polls 1-10 dropped
    publisher._drain()  # 11-20 sent: 10 in flight
    poll(publisher, 15)  # 21-25 dropped, 26-35 queued
    publisher._drain()  # room for 10 more: 26-35 sent, the window is full
    poll(publisher, 15)  # 36-40 dropped, 41-50 queued
    publisher._drain()  # nothing acknowledged: nothing sent
    assert [f["sequence"] for f in client.frames()] == [*range(11, 21), *range(26, 36)]
    assert publisher.stats().dropped == {"arr": 20} and publisher.stats().queued == 10
    ack(publisher, client, range(1, 11))
    publisher._drain()
    assert [f["sequence"] for f in client.frames()][20:] == list(range(41, 51))


def test_at_qos_0_everything_queued_goes_out_at_once() -> None:
    publisher, client = connected_publisher(qos=0)
    poll(publisher, 50)
    publisher._drain()
    assert [f["sequence"] for f in client.frames()] == list(range(1, 51))
    assert publisher.stats().published == {"arr": 50} and publisher.stats().queued == 0


@pytest.mark.parametrize(
    ("poll_interval_s", "lowered"), [(0.0, True), (0.005, True), (0.01, False), (0.1, False)]
)
def test_the_publisher_thread_yields_to_the_poll_loop_only_beside_a_fast_bus(
    poll_interval_s: float, lowered: bool
) -> None:
    cfg = config(qos=1, queue_frames=10)
    bus = dataclasses.replace(cfg.buses[0], poll_interval_s=poll_interval_s)
    cfg = dataclasses.replace(cfg, buses=(bus,))
    seen: list[int] = []
    publisher: MqttPublisher | None = None

    class Client(RecordingClient):
        def connect(self, host: str, port: int, keepalive: int) -> None:
            """The thread's niceness when it first connects; then ends the run."""
            seen.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
            assert publisher is not None
            with publisher._cond:
                publisher._stopping = True
            raise OSError("no broker in this test")

    publisher = MqttPublisher(cfg, client_factory=Client)  # type: ignore[arg-type]
    before = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    publisher.start()
    publisher.stop()
    assert seen == [min(19, before + BACKGROUND_NICE) if lowered else before]
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == before


def test_dropped_frames_are_logged_at_warning_level_with_counts_at_most_every_interval(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Issue 33 §13: drops were counted in a metric only; now also said at warning level,
    at most once per ``DROP_LOG_INTERVAL_S``, with the counts since the last report."""
    publisher, _client = connected_publisher(qos=1, queue_frames=10)
    caplog.set_level("WARNING", logger="gateway.mqtt.publisher")
    poll(publisher, 20)  # polls 1-10 dropped
    publisher._report_drops(now=100.0)
    assert len(caplog.records) == 1 and caplog.records[0].levelname == "WARNING"
    assert "10 frame(s) dropped" in caplog.messages[0] and "arr 10" in caplog.messages[0]
    publisher._drain()  # 11-20 in flight
    poll(publisher, 15)  # 21-25 dropped
    publisher._report_drops(now=100.0 + DROP_LOG_INTERVAL_S / 2)  # too soon: nothing said yet
    assert len(caplog.records) == 1
    poll(publisher, 3)  # 26-28 dropped
    publisher._report_drops(now=100.0 + DROP_LOG_INTERVAL_S)
    assert len(caplog.records) == 2
    assert "8 frame(s) dropped" in caplog.messages[1] and "18 in all" in caplog.messages[1]
    publisher._report_drops(now=100.0 + 5 * DROP_LOG_INTERVAL_S)  # no new drop: nothing said
    assert len(caplog.records) == 2
