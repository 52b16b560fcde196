"""Issue 33 §1-3: what a hostile publisher cannot do to ``subscribe``.

§1: a channel name (or a gateway or device level of the topic) that a record cannot hold as
written (a comma, a quote, a line break, ...) does not inject rows: the frame is refused for
the record and counted, and the record reads back to exactly the rows of the frames received.
§2: binary frames held for a meta message that never comes are bounded in bytes over all
devices, and what is dropped is counted.
§3: a frame whose host_time_s (or device_time_s) is NaN or infinite is refused and counted.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.analysis.records import RecordError, RecordWriter, parse_record, read_record
from gateway.cli import main, subscribe_cmd
from gateway.mqtt.frame_stream import PENDING_FRAME_OVERHEAD_BYTES
from gateway.mqtt.payload import encode_binary, encode_json
from gateway.mqtt.subscriber import FrameStream

MALICIOUS = "c1,5.0\n0.0,gw/d/c2"  # the exact name of issue 33 §1


def fields(seq: int, **changes: Any) -> dict[str, Any]:
    f: dict[str, Any] = {
        "sequence": seq,
        "device": "d",
        "host_time_s": 1000.0 + seq,
        "device_time_s": None,
        "up": True,
        "total_force_n": 0.0,
        "center_of_pressure_mm": None,
        "contact_area_mm2": 0.0,
        "channels_in_contact": 0,
        "channels": ["c1", "c2"],
        "force_n": [0.0, 0.0],
        "force_static_n": [None, None],
        "resistance_ohm": [1000.0, 1000.0],
        "status": ["no_contact", "no_contact"],
    }
    f.update(changes)
    return f


def _run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, messages: list[tuple[str, bytes]]
) -> tuple[Any, Path]:
    def fake_run_subscriber(
        settings: object, on_message: Callable[[str, bytes], None], *args: object, **kwargs: object
    ) -> None:
        for topic, payload in messages:
            on_message(topic, payload)

    monkeypatch.setattr(subscribe_cmd, "run_subscriber", fake_run_subscriber)
    out = tmp_path / "rec.csv"
    result = CliRunner().invoke(main, ["subscribe", "--broker", "127.0.0.1", "--out", str(out), "-q"])
    return result, out


# ------------------------------------------------------------------------------------ §1


def test_the_issues_malicious_channel_name_injects_no_row(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    topic = "tactile/gw/d/frame"
    messages = [
        (topic, encode_json(fields(1, channels=["c1", MALICIOUS]))),  # type: ignore[arg-type]
        (topic, encode_json(fields(2, resistance_ohm=[2000.0, 3000.0]))),  # type: ignore[arg-type]
    ]
    result, out = _run(tmp_path, monkeypatch, messages)
    assert result.exit_code == 0, result.output
    record = read_record(out)
    # exactly the rows of the one frame that could be recorded (the record's time starts there)
    assert sorted(record.channels) == ["gw/d/c1", "gw/d/c2"]
    for name, r in (("gw/d/c1", 2000.0), ("gw/d/c2", 3000.0)):
        ch = record.channels[name]
        assert ch.time_s.tolist() == [0.0] and ch.resistance_ohm.tolist() == [r]
    assert "2 rows to" in result.output
    assert "1 frame(s) not recorded (a channel name a record cannot hold" in result.output
    assert repr("gw/d/" + MALICIOUS) in result.output  # the notice names it, escaped, on one line


@pytest.mark.parametrize(
    "topic",
    ["tactile/g,w/d/frame", 'tactile/gw/"d/frame', "tactile/gw/d\r/frame", "tactile/gw/d\u2028/frame"],
)
def test_a_topic_level_a_record_cannot_hold_is_refused_too(
    topic: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    good = ("tactile/gw/d/frame", encode_json(fields(1)))  # type: ignore[arg-type]
    result, out = _run(tmp_path, monkeypatch, [good, (topic, encode_json(fields(1)))])  # type: ignore[arg-type]
    assert result.exit_code == 0, result.output
    assert sorted(read_record(out).channels) == ["gw/d/c1", "gw/d/c2"]
    assert "1 frame(s) not recorded" in result.output


def test_two_channels_of_one_name_in_a_frame_are_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    topic = "tactile/gw/d/frame"
    messages = [
        (topic, encode_json(fields(1, channels=["c1", "c1"]))),  # type: ignore[arg-type]
        (topic, encode_json(fields(2))),  # type: ignore[arg-type]
    ]
    result, out = _run(tmp_path, monkeypatch, messages)
    assert result.exit_code == 0, result.output
    assert [c.time_s.tolist() for c in read_record(out).channels.values()] == [[0.0], [0.0]]
    assert "1 frame(s) not recorded" in result.output


@settings(max_examples=300, deadline=None)
@given(name=st.text(min_size=0, max_size=12), t=st.floats(0.0, 1e6), r=st.floats(1e-3, 1e12))
def test_the_writer_refuses_a_channel_name_or_it_reads_back_exactly(name: str, t: float, r: float) -> None:
    import io

    out = io.StringIO()
    writer = RecordWriter(out, {})
    try:
        writer.row(t, name, r)
    except ValueError as exc:
        assert "channel" in str(exc)
        return
    try:
        record = parse_record(out.getvalue())
    except RecordError as exc:  # pragma: no cover - a failure of the property
        pytest.fail(f"{name!r} was written but does not read back: {exc}")
    assert list(record.channels) == [name]
    assert record.channels[name].time_s.tolist() == [t]
    assert record.channels[name].resistance_ohm.tolist() == [r]


def test_the_writer_refuses_the_issues_name() -> None:
    import io

    with pytest.raises(ValueError, match="channel"):
        RecordWriter(io.StringIO(), {}).row(0.0, MALICIOUS, 1000.0)


# ------------------------------------------------------------------------------------ §2


def _binary(seq: int, n: int = 60) -> bytes:
    f = fields(
        seq,
        channels=[f"c{i}" for i in range(n)],
        force_n=[0.0] * n,
        force_static_n=[None] * n,
        resistance_ohm=[1000.0] * n,
        status=["no_contact"] * n,
    )
    return encode_binary(f)  # type: ignore[arg-type]


def test_frames_held_for_a_meta_message_are_bounded_in_bytes_over_all_devices() -> None:
    limit = 200_000
    stream = FrameStream("tactile", pending_bytes_limit=limit)
    size = len(_binary(1))
    fed = 0
    for seq in range(1, 41):
        for dev in range(200):  # 200 device names, none with a meta message
            stream.feed(f"tactile/gw/d{dev}/frame", _binary(seq))
            fed += 1
            held = sum(len(p) for q in stream.pending.values() for p in q)
            assert held <= limit
    assert fed * size > 20 * limit  # the flood is far beyond the bound
    held_frames = sum(len(q) for q in stream.pending.values())
    assert stream.stats.pending_dropped == fed - held_frames > 0
    frames, _notes = stream.flush()
    assert len(frames) == held_frames
    # the frames kept are each device's newest (the dropped ones are older): each device's
    # last frame is its 40th
    last = {f.key: f.sequence for f in frames}
    assert set(last.values()) == {40}


def test_subscribe_counts_the_frames_dropped_while_waiting_for_meta(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    held_frame_bytes = len(_binary(1)) + PENDING_FRAME_OVERHEAD_BYTES
    monkeypatch.setattr(subscribe_cmd, "PENDING_BYTES_LIMIT", 10 * held_frame_bytes)
    messages = [(f"tactile/gw/d{i % 3}/frame", _binary(1 + i // 3)) for i in range(30)]
    result, _ = _run(tmp_path, monkeypatch, messages)
    assert result.exit_code == 0, result.output
    assert "20 frame(s) dropped while waiting for a meta message" in result.output


# ------------------------------------------------------------------------------------ §3


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("key", ["host_time_s", "device_time_s"])
def test_a_json_frame_with_a_time_not_finite_is_refused_and_counted(key: str, value: float) -> None:
    stream = FrameStream("tactile")
    payload = json.dumps(fields(1, **{key: value})).encode()  # NaN, Infinity, -Infinity
    assert b"NaN" in payload or b"Infinity" in payload
    frames, notes = stream.feed("tactile/gw/d/frame", payload)
    assert frames == [] and stream.stats.undecodable == 1
    assert len(notes) == 1 and key in notes[0] and "finite" in notes[0]


def test_a_binary_frame_with_a_host_time_not_finite_is_refused() -> None:
    stream = FrameStream("tactile")
    meta = json.dumps({"channels": [{"name": "c1"}, {"name": "c2"}], "encoding": "binary"}).encode()
    stream.feed("tactile/gw/d/meta", meta)
    frames, _ = stream.feed("tactile/gw/d/frame", encode_binary(fields(1, host_time_s=math.nan)))  # type: ignore[arg-type]
    assert frames == [] and stream.stats.undecodable == 1


def test_a_nan_first_frame_leaves_the_later_rows_their_times(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    topic = "tactile/gw/d/frame"
    messages = [(topic, json.dumps(fields(1, host_time_s=math.nan)).encode())]
    messages += [(topic, json.dumps(fields(seq)).encode()) for seq in (2, 3)]
    result, out = _run(tmp_path, monkeypatch, messages)
    assert result.exit_code == 0, result.output
    record = read_record(out)
    assert record.channels["gw/d/c1"].time_s.tolist() == [0.0, 1.0]
    assert "1 undecodable message(s)" in result.output
