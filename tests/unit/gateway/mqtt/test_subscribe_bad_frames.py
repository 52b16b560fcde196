"""Issue 24 §2: one hostile MQTT message does not crash ``subscribe``: a frame that cannot be
decoded (arrays nested 100,000 deep, an integer of 5,001 digits, fields of the wrong type)
is counted and reported, and the record is still written, whole, with the good frames."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from gateway.cli import main, subscribe_cmd
from gateway.mqtt.payload import encode_binary, encode_json
from gateway.mqtt.subscriber import FrameStream

NAMES = ["a0", "a1"]


def fields(seq: int, **changes: Any) -> dict[str, Any]:
    f: dict[str, Any] = {
        "sequence": seq,
        "device": "arr",
        "host_time_s": 1000.0 + seq,
        "device_time_s": 0.05 * seq,
        "up": True,
        "total_force_n": 1.5,
        "center_of_pressure_mm": [0.0, 0.0],
        "contact_area_mm2": 6.25,
        "channels_in_contact": 1,
        "channels": list(NAMES),
        "force_n": [1.5, 0.0],
        "force_static_n": [None, None],
        "resistance_ohm": [1200.0, 5.0e5],
        "status": ["ok", "no_contact"],
    }
    f.update(changes)
    return f


TOPIC = "tactile/gw1/arr/frame"
DEEP = b"[" * 100_000 + b"]" * 100_000
HOSTILE = {
    "nested-100000-deep": DEEP,
    "nested-in-a-field": json.dumps(fields(2))
    .replace('"up": true', '"up": true, "x": XX')
    .encode()
    .replace(b"XX", DEEP),
    "5001-digits": json.dumps(fields(2)).replace('"sequence": 2', '"sequence": ' + "1" * 5001).encode(),
    "channels-a-number": json.dumps(fields(2, channels=5)).encode(),
    "force-a-string": json.dumps(fields(2, force_n=["x", 0.0])).encode(),
    "resistance-a-list": json.dumps(fields(2, resistance_ohm=[[1.0], 2.0])).encode(),
    "host-time-a-string": json.dumps(fields(2, host_time_s="now")).encode(),
    "status-a-number": json.dumps(fields(2, status=[1, 2])).encode(),
    "up-a-string": json.dumps(fields(2, up="no")).encode(),
}


@pytest.mark.parametrize("payload", HOSTILE.values(), ids=HOSTILE.keys())
def test_a_hostile_frame_is_counted_and_reported(payload: bytes) -> None:
    stream = FrameStream("tactile")
    frames, notes = stream.feed(TOPIC, payload)
    assert frames == [] and len(notes) == 1 and "could not be decoded" in notes[0]
    assert stream.stats.undecodable == 1
    meta_frames, meta_notes = stream.feed("tactile/gw1/arr/meta", payload)
    assert meta_frames == [] and len(meta_notes) == 1 and stream.stats.undecodable == 2


def test_subscribe_records_the_good_frames_around_a_hostile_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    messages = [encode_json(fields(1)), *HOSTILE.values(), encode_json(fields(2))]

    def fake_run_subscriber(
        settings: object, on_message: Callable[[str, bytes], None], *args: object, **kwargs: object
    ) -> None:
        for payload in messages:
            on_message(TOPIC, payload)

    monkeypatch.setattr(subscribe_cmd, "run_subscriber", fake_run_subscriber)
    out = tmp_path / "rec.csv"
    result = CliRunner().invoke(main, ["subscribe", "--broker", "127.0.0.1", "--out", str(out), "-q"])
    assert result.exit_code == 0, result.output
    assert f"{len(HOSTILE)} undecodable message(s)" in result.output
    assert result.output.count("a frame could not be decoded") == len(HOSTILE)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"]  # no temporary file left
    rows = [line for line in out.read_text().splitlines() if line and not line.startswith("#")]
    assert rows[0].startswith("time_s,channel,resistance_ohm")
    assert len(rows) == 1 + 2 * len(NAMES)  # the header, and both channels of both good frames


def test_subscribe_json_prints_binary_frames_rounded_as_the_published_json(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # float32 values widened to float64 would print as 0.10000000149011612 and 46901.69921875
    sent = fields(
        1,
        force_n=[0.1, 2.123456789],
        force_static_n=[0.3, None],
        resistance_ohm=[46901.7, 1234567.8],
    )
    meta = json.dumps({"channels": [{"name": n} for n in NAMES], "encoding": "binary"}).encode()
    messages = [("tactile/gw1/arr/meta", meta), (TOPIC, encode_binary(sent))]

    def fake_run_subscriber(
        settings: object, on_message: Callable[[str, bytes], None], *args: object, **kwargs: object
    ) -> None:
        for topic, payload in messages:
            on_message(topic, payload)

    monkeypatch.setattr(subscribe_cmd, "run_subscriber", fake_run_subscriber)
    result = CliRunner().invoke(main, ["subscribe", "--broker", "127.0.0.1", "--json"])
    assert result.exit_code == 0, result.output
    line = next(line for line in result.output.splitlines() if line.startswith("{"))
    printed = json.loads(line)
    # float32 keeps about 7 significant digits: the shortest decimal of that precision (1234567.8
    # is the float32 1234567.75), then the published JSON's 6 decimals
    assert printed["force_n"] == [0.1, 2.123457]
    assert printed["force_static_n"] == [0.3, None]
    assert printed["resistance_ohm"] == [46901.7, 1234567.8]
    assert '"force_n":[0.1,2.123457]' in line and "0000000" not in line
