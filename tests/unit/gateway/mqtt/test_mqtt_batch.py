"""Batches (issue 33 §13): several polls of a device in one MQTT message when frames wait.

The layouts (``docs/mqtt.md``): JSON ``{"frames":[<frame>,<frame>,...]}``, each element the
single-frame JSON object byte for byte; binary ``b"TGB1"``, a uint32 count, then that many
binary frames (``TGF1``) back to back. A lone waiting frame is published exactly as before.
The publisher puts at most ``max_batch_frames`` frames in one message; ``subscribe`` reads a
batch as its frames, in order, each with its own sequence number.
"""

from __future__ import annotations

import dataclasses
import json
import math
import struct
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_mqtt_config import parse
from test_mqtt_payload import snapshot
from test_publisher_window import RecordingClient, ack, config, poll

from gateway.config.mqtt import MqttConfig
from gateway.errors import ConfigError
from gateway.mqtt.payload import (
    BATCH_MAGIC,
    FrameDecodeError,
    FrameFields,
    decode_binary,
    decode_binary_batch,
    encode_binary,
    encode_binary_batch,
    encode_json,
    encode_json_batch,
    encode_json_frame,
)
from gateway.mqtt.publisher import INFLIGHT_WINDOW, LOOP_TIMEOUT_S, MqttPublisher
from gateway.mqtt.subscriber import FrameStream
from gateway.runtime.snapshot import STATUS_LABELS, GatewaySnapshot

PREFIX = "tactile"
TOPIC = "tactile/gw/arr/frame"


def publisher_with(
    qos: int = 1, max_batch_frames: int = 8, encoding: str = "json", batch_interval_s: float = 0.0
) -> tuple[MqttPublisher, RecordingClient]:
    cfg = config(qos, 1000)
    assert cfg.mqtt is not None
    mqtt = dataclasses.replace(
        cfg.mqtt, max_batch_frames=max_batch_frames, encoding=encoding, batch_interval_s=batch_interval_s
    )
    clients: list[RecordingClient] = []

    def factory(**kwargs: Any) -> RecordingClient:
        clients.append(RecordingClient(**kwargs))
        return clients[-1]

    publisher = MqttPublisher(dataclasses.replace(cfg, mqtt=mqtt), client_factory=factory)  # type: ignore[arg-type]
    client = clients[0]
    publisher._on_connect(client, None, None, None, None)  # type: ignore[arg-type]
    publisher._drain()  # the meta message
    client.sent.clear()
    return publisher, client


def messages(client: RecordingClient) -> list[bytes]:
    return [
        bytes(p) if isinstance(p, bytes) else p.encode() for t, p, _ in client.sent if t.endswith("/frame")
    ]


def sequences_of(payload: bytes) -> list[int]:
    """The sequence numbers one message carries, read by hand from the documented layouts."""
    if payload[:4] == BATCH_MAGIC:
        (count,) = struct.unpack_from("<I", payload, 4)
        offset, seqs = 8, []
        for _ in range(count):
            (seq,) = struct.unpack_from("<Q", payload, offset + 4)
            (n,) = struct.unpack_from("<H", payload, offset + 62)
            seqs.append(seq)
            offset += 64 + 13 * n
        assert offset == len(payload)
        return seqs
    if payload[:4] == b"TGF1":
        return [struct.unpack_from("<Q", payload, 4)[0]]
    obj = json.loads(payload)
    return [f["sequence"] for f in obj["frames"]] if "frames" in obj else [obj["sequence"]]


# ---------------------------------------------------------------------------------- publisher
@pytest.mark.parametrize("encoding", ["json", "binary"])
def test_a_backlog_goes_out_in_batches_of_at_most_max_batch_frames(encoding: str) -> None:
    publisher, client = publisher_with(qos=1, max_batch_frames=8, encoding=encoding)
    poll(publisher, 50)
    publisher._drain()
    sent = messages(client)
    per_message = [sequences_of(m) for m in sent]
    # 50 frames in 8s: 6 batches of 8 and one of 2, all within the window of 20 messages
    assert [len(s) for s in per_message] == [8, 8, 8, 8, 8, 8, 2]
    assert [q for s in per_message for q in s] == list(range(1, 51))
    assert publisher.stats().queued == 0
    ack(publisher, client, range(1, len(sent) + 1))
    stats = publisher.stats()
    assert stats.published == {"arr": 50} and stats.dropped == {}
    assert stats.messages == 7


def test_at_qos_1_a_backlog_beyond_the_window_waits_in_full_batches() -> None:
    publisher, client = publisher_with(qos=1, max_batch_frames=3)
    poll(publisher, 3 * INFLIGHT_WINDOW + 5)
    publisher._drain()
    assert [len(sequences_of(m)) for m in messages(client)] == [3] * INFLIGHT_WINDOW
    assert publisher.stats().queued == 5
    ack(publisher, client, range(1, 3))
    publisher._drain()
    tail = [sequences_of(m) for m in messages(client)[INFLIGHT_WINDOW:]]
    assert tail == [[61, 62, 63], [64, 65]]


def test_a_lone_waiting_frame_is_the_single_frame_message_as_before() -> None:
    publisher, client = publisher_with(qos=1, max_batch_frames=8)
    dev = snapshot(total_force_n=2.0)
    publisher.on_snapshot(GatewaySnapshot.build({"arr": dev}, {}, 1))
    publisher._drain()
    assert messages(client) == [encode_json_frame(dev, 1)]


def test_max_batch_frames_1_publishes_one_frame_per_message() -> None:
    publisher, client = publisher_with(qos=0, max_batch_frames=1)
    poll(publisher, 12)
    publisher._drain()
    assert [sequences_of(m) for m in messages(client)] == [[k] for k in range(1, 13)]


def test_frames_of_two_devices_are_batched_per_device_in_order() -> None:
    publisher, client = publisher_with(qos=0, max_batch_frames=4)
    for k in range(6):  # polls of arr and arr2 interleaved
        devs = {
            "arr": snapshot(total_force_n=float(k)),
            "arr2": dataclasses.replace(snapshot(total_force_n=float(k)), device="arr2"),
        }
        publisher.on_snapshot(GatewaySnapshot.build(devs, {}, k + 1))
    publisher._drain()
    by_topic: dict[str, list[list[int]]] = {}
    for t, p, _ in client.sent:
        by_topic.setdefault(t, []).append(sequences_of(p if isinstance(p, bytes) else p.encode()))
    assert by_topic == {
        "tactile/gw/arr/frame": [[1, 2, 3, 4], [5, 6]],
        "tactile/gw/arr2/frame": [[1, 2, 3, 4], [5, 6]],
    }


def test_while_frames_keep_coming_messages_leave_at_most_every_batch_interval() -> None:
    """A frame right after a publication waits for the interval (and the frames that come
    meanwhile join it); a full batch, or the interval passed, goes out at once."""
    publisher, client = publisher_with(qos=1, max_batch_frames=4, batch_interval_s=0.01)
    assert publisher._drain_due(now=100.0)  # nothing published yet
    poll(publisher, 1)
    publisher._drain(now=100.0)
    assert len(messages(client)) == 1
    poll(publisher, 2)
    assert not publisher._drain_due(now=100.004)
    assert publisher._drain_due(now=100.010)
    poll(publisher, 2)  # 4 waiting: a full batch
    assert publisher._drain_due(now=100.005)
    unbatched, _ = publisher_with(qos=1, max_batch_frames=1, batch_interval_s=0.01)
    unbatched._drain(now=100.0)
    poll(unbatched, 1)
    assert unbatched._drain_due(now=100.001)  # no batching: never held


# ---------------------------------------------------------------------------------- payloads
def _frame(seq: int, n: int, force: float, host: float, device: float | None) -> FrameFields:
    return {
        "sequence": seq,
        "device": "arr",
        "host_time_s": host,
        "device_time_s": device,
        "up": True,
        "total_force_n": force,
        "center_of_pressure_mm": None,
        "contact_area_mm2": 0.0,
        "channels_in_contact": 0,
        "channels": [f"c{k}" for k in range(n)],
        "force_n": [force] * n,
        "force_static_n": [None] * n,
        "resistance_ohm": [1000.0 + k for k in range(n)],
        "status": [STATUS_LABELS[k % len(STATUS_LABELS)] for k in range(n)],
    }


frames_strategy = st.lists(
    st.tuples(
        st.integers(1, 2**53),
        st.floats(0.0, 1e9, allow_nan=False),
        st.floats(0.0, 2e9, allow_nan=False),
        st.one_of(st.none(), st.floats(0.0, 1e6, allow_nan=False)),
    ),
    min_size=1,
    max_size=20,
)


@settings(max_examples=60, deadline=None)
@given(rows=frames_strategy, n=st.integers(0, 12))
def test_batch_encode_decode_round_trip(rows: list[tuple[int, float, float, float | None]], n: int) -> None:
    frames = [
        _frame(seq, n, round(f, 6), round(h, 6), d if d is None else round(d, 6)) for seq, f, h, d in rows
    ]
    decoded = FrameStream(PREFIX)._fields(
        ("gw", "arr"), encode_json_batch([encode_json(f) for f in frames]), None
    )
    assert decoded == [dict(f) for f in frames]
    binary = [encode_binary(f) for f in frames]
    names = [f"c{k}" for k in range(n)]
    expected = [decode_binary(b, "arr", names) for b in binary]
    assert decode_binary_batch(encode_binary_batch(binary), "arr", names) == expected
    assert [f["sequence"] for f in expected] == [seq for seq, *_ in rows]


def test_a_batch_is_read_as_its_frames_in_order_with_gaps_counted() -> None:
    stream = FrameStream(PREFIX)
    stream.feed(
        "tactile/gw/arr/meta", json.dumps({"encoding": "json", "channels": [{"name": "c0"}]}).encode()
    )
    single = encode_json(_frame(1, 1, 1.0, 10.0, None))
    batch = encode_json_batch([encode_json(_frame(s, 1, 1.0, 10.0 + s, None)) for s in (2, 3, 6, 7)])
    frames = stream.feed(TOPIC, single)[0] + stream.feed(TOPIC, batch)[0]
    assert [f.sequence for f in frames] == [1, 2, 3, 6, 7]
    assert [f.missing_before for f in frames] == [0, 0, 0, 2, 0]
    assert [f.fields["host_time_s"] for f in frames] == [10.0, 12.0, 13.0, 16.0, 17.0]
    assert stream.sequences.missing == 2 and stream.stats.frames == 5


def test_a_binary_batch_before_its_meta_message_is_held_then_read() -> None:
    stream = FrameStream(PREFIX)
    batch = encode_binary_batch([encode_binary(_frame(s, 2, 0.5, 10.0, 1.0 * s)) for s in (1, 2, 3)])
    assert stream.feed(TOPIC, batch) == ([], [])
    meta = json.dumps({"encoding": "binary", "channels": [{"name": "x"}, {"name": "y"}]}).encode()
    frames, _ = stream.feed("tactile/gw/arr/meta", meta)
    assert [(f.sequence, f.fields["channels"], f.fields["device_time_s"]) for f in frames] == [
        (1, ["x", "y"], 1.0),
        (2, ["x", "y"], 2.0),
        (3, ["x", "y"], 3.0),
    ]


@pytest.mark.parametrize(
    ("payload", "fragment"),
    [
        (b'{"frames": []}', "a batch of no frames"),
        (b'{"frames": 3}', "a batch whose frames are not a list"),
        (b'{"frames": [{"sequence": 1}]}', "a JSON frame without"),
        (b'{"frames": [[1]]}', "not an object"),
        (BATCH_MAGIC + struct.pack("<I", 0), "a batch of no frames"),
        (BATCH_MAGIC + struct.pack("<I", 2) + b"TGF1", "binary frame"),
        (BATCH_MAGIC + b"\x01", "at least 8 bytes"),
    ],
)
def test_malformed_batches_are_refused_and_counted(payload: bytes, fragment: str) -> None:
    stream = FrameStream(PREFIX)
    frames, notices = stream.feed(TOPIC, payload)
    if not notices:  # a binary batch without meta is held first
        frames, notices = stream.flush()
    assert frames == [] and stream.stats.undecodable == 1
    assert fragment in notices[-1], notices


def test_a_binary_batch_with_trailing_bytes_is_refused() -> None:
    one = encode_binary(_frame(1, 2, 0.5, 10.0, None))
    with pytest.raises(FrameDecodeError, match="bytes after"):
        decode_binary_batch(encode_binary_batch([one]) + b"\0", "arr", ["a", "b"])


# ---------------------------------------------------------------------------------- config
def test_batch_settings_default_and_parse(tmp_path: Path) -> None:
    default = parse('host = "b"', tmp_path)
    assert default is not None and default.max_batch_frames > 1 and 0.0 < default.batch_interval_s <= 0.1
    set_ = parse('host = "b"\nmax_batch_frames = 1\nbatch_interval_s = 0', tmp_path)
    assert set_ == dataclasses.replace(default, max_batch_frames=1, batch_interval_s=0.0)


@pytest.mark.parametrize(
    ("line", "fragment"),
    [
        ("max_batch_frames = 0", "max_batch_frames: 0 is out of range; allowed: 1..1000"),
        ("max_batch_frames = 1001", "max_batch_frames: 1001 is out of range; allowed: 1..1000"),
        ("max_batch_frames = 2.5", "an integer in 1..1000"),
        ('max_batch_frames = "10"', "an integer in 1..1000"),
        ("batch_interval_s = -0.001", "batch_interval_s"),
        ("batch_interval_s = 1.5", "batch_interval_s"),
        ("batch_interval_s = nan", "batch_interval_s"),
    ],
)
def test_bad_batch_settings_are_refused_with_the_range(tmp_path: Path, line: str, fragment: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse(f'host = "b"\n{line}', tmp_path)
    assert fragment in str(info.value)
    if "interval" in line:
        assert "0..1" in str(info.value) or "[0, 1]" in str(info.value)


def test_a_config_object_refuses_a_batch_size_out_of_range() -> None:
    with pytest.raises(ConfigError, match=r"max_batch_frames: 0 .*1\.\.1000"):
        MqttConfig("h", 1883, None, None, None, "c", "p", "g", max_batch_frames=0)
    assert not math.isnan(MqttConfig("h", 1883, None, None, None, "c", "p", "g").batch_interval_s)


def test_the_network_loop_never_spins_while_frames_wait_for_the_window() -> None:
    """With the interval passed but no room (every message of the window in flight), the
    client waits on its socket for acknowledgements (``LOOP_TIMEOUT_S``), not for 0 s over
    and over: a spinning publisher thread would take the poll loop's CPU."""
    publisher, _client = publisher_with(qos=1, max_batch_frames=2, batch_interval_s=0.01)
    poll(publisher, 2 * INFLIGHT_WINDOW + 3)
    publisher._drain(now=100.0)
    assert publisher.stats().queued == 3  # the window is full
    assert publisher._loop_timeout_s(now=100.004) == pytest.approx(0.006)  # wake for the next drain
    assert publisher._drain_due(now=100.02)
    publisher._drain(now=100.02)  # no room: nothing goes out
    assert publisher.stats().queued == 3
    assert publisher._loop_timeout_s(now=100.02) == LOOP_TIMEOUT_S
