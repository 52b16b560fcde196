"""MQTT's JSON frame from the snapshot's one encoded body (``encode_json_frame``, ``json_body``):
byte for byte the frame ``encode_json(frame_dict(...))`` gives, for snapshots with NaN and
infinite values, stale and no-contact channels, absent clock and centre; literally the JSON
written out by hand for a small one; and the body encoded once per snapshot however many
messages carry it."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from test_mqtt_payload import snapshot as payload_snapshot

from gateway.mqtt import payload
from gateway.mqtt.payload import encode_json, encode_json_frame, frame_dict, json_body
from gateway.runtime.frame import Frame
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot


def snapshot(**changes: object) -> DeviceSnapshot:
    """Four channels: ok at 1.25 N, open (inf ohm, no force), short, stale with NaN values
    (``test_mqtt_payload``'s snapshot with its last channel stale)."""
    fields: dict[str, object] = {
        "force_n": np.array([1.25, math.nan, math.nan, math.nan]),
        "status": np.array(
            [ChannelStatus.OK, ChannelStatus.OPEN, ChannelStatus.SHORT, ChannelStatus.STALE], dtype=np.int8
        ),
    }
    fields.update(changes)
    return payload_snapshot(**fields)


STALE = np.full(4, int(ChannelStatus.STALE), dtype=np.int8)
NO_CONTACT = np.full(4, int(ChannelStatus.NO_CONTACT), dtype=np.int8)

SNAPSHOTS = {
    "mixed": snapshot(),
    "stale, no clock, no centre": snapshot(
        up=False,
        status=STALE,
        device_time_s=None,
        center_of_pressure_mm=None,
        error="no answer",
        force_n=np.full(4, math.nan),
    ),
    "nothing in contact": snapshot(
        status=NO_CONTACT,
        force_n=np.zeros(4),
        resistance_ohm=np.full(4, 1.0e7),
        total_force_n=0.0,
        center_of_pressure_mm=None,
        channels_in_contact=0,
        contact_area_mm2=0.0,
    ),
    "float noise": snapshot(
        timestamp_s=1_700_000_000.1234567,
        force_n=np.array([0.1 + 0.2, -0.0, 1e-9, 123456.7890123]),
        center_of_pressure_mm=(1.0 / 3.0, -2.5),
    ),
}


@pytest.mark.parametrize("name", list(SNAPSHOTS))
@pytest.mark.parametrize("sequence", [0, 1, 7, 123_456_789, 2**53 + 1])
def test_encode_json_frame_is_encode_json_of_frame_dict(name: str, sequence: int) -> None:
    snap = SNAPSHOTS[name]
    expected = encode_json(frame_dict(snap, sequence))
    assert encode_json_frame(snap, sequence) == expected
    # and a fresh copy of the snapshot (its own cache), body computed before the first frame
    copy = dataclasses.replace(snap)
    copy.derived(json_body)
    assert encode_json_frame(copy, sequence) == expected


def test_the_frame_is_valid_json_with_the_sequence_first() -> None:
    data = encode_json_frame(SNAPSHOTS["stale, no clock, no centre"], 42)
    assert data.startswith(b'{"sequence":42,"device":"arr",')
    frame = json.loads(data)
    assert next(iter(frame)) == "sequence" and frame["sequence"] == 42
    assert frame["status"] == ["stale"] * 4 and frame["up"] is False
    assert frame["force_n"] == [None] * 4
    assert b"NaN" not in data and b"Infinity" not in data


def test_a_two_channel_frame_literally() -> None:
    snap = DeviceSnapshot(
        device="arr",
        bus="line",
        channel_index=np.array([0, 1]),
        channel_names=("a", "b"),
        x_mm=np.array([0.0, 2.5]),
        y_mm=np.array([0.0, 0.0]),
        resistance_ohm=np.array([1500.0, math.inf]),
        force_n=np.array([1.25, math.nan]),
        static_estimate=None,
        reference_force_n=np.full(2, math.nan),
        status=np.array([ChannelStatus.STALE, ChannelStatus.NO_CONTACT], dtype=np.int8),
        up=False,
        timestamp_s=1_700_000_000.125,
        last_success_timestamp_s=None,
        device_time_s=None,
        poll_interval_s=0.05,
        total_force_n=1.25,
    )
    body = (
        b'{"device":"arr","host_time_s":1700000000.125,"device_time_s":null,'
        b'"up":false,"total_force_n":1.25,"center_of_pressure_mm":null,"contact_area_mm2":0.0,'
        b'"channels_in_contact":0,"channels":["a","b"],"force_n":[1.25,null],'
        b'"force_static_n":[null,null],"resistance_ohm":[1500.0,null],"status":["stale","no_contact"]}'
    )
    assert json_body(snap) == body
    assert encode_json_frame(snap, 5) == b'{"sequence":5,' + body[1:]


def test_the_body_is_encoded_once_per_snapshot(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[object] = []
    real = payload.frame_dict

    def counted(source: DeviceSnapshot | Frame, sequence: int) -> payload.FrameFields:
        calls.append(source)
        return real(source, sequence)

    monkeypatch.setattr(payload, "frame_dict", counted)
    snap, other = snapshot(), snapshot(up=False, status=STALE)
    frames = [encode_json_frame(snap, seq) for seq in range(5)]
    assert len(calls) == 1
    assert [json.loads(f)["sequence"] for f in frames] == [0, 1, 2, 3, 4]
    body = snap.derived(json_body)
    assert snap.derived(json_body) is body and len(calls) == 1
    assert all(f.endswith(body[1:]) for f in frames)
    encode_json_frame(other, 9)
    encode_json_frame(other, 10)
    assert len(calls) == 2  # one more snapshot, one more encoding


def test_a_body_derived_beforehand_is_not_encoded_again(monkeypatch: pytest.MonkeyPatch) -> None:
    snap = snapshot()
    body = snap.derived(json_body)  # as the poll loop does when MQTT publishes JSON

    def refuse(source: DeviceSnapshot | Frame, sequence: int) -> payload.FrameFields:
        raise AssertionError("the body was encoded again")

    monkeypatch.setattr(payload, "frame_dict", refuse)
    assert encode_json_frame(snap, 3) == b'{"sequence":3,' + body[1:]
