"""The subscriber's protocol side without a broker: topics, decoding with the retained meta,
gaps, duplicates and restarts in sequence numbers, record rows, options."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from gateway.errors import ConfigError
from gateway.mqtt.payload import encode_binary, encode_json
from gateway.mqtt.subscriber import (
    FrameStream,
    SequenceTracker,
    SubscribeSettings,
    frame_clock_s,
    in_contact,
    parse_broker,
    read_password_file,
    recordable,
)

PREFIX = "lab/tactile"
NAMES = ["a0", "a1", "b0"]


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
        "force_n": [1.5, 0.0, None],
        "force_static_n": [None, None, None],
        "resistance_ohm": [1200.0, 5.0e5, None],
        "status": ["ok", "no_contact", "open"],
    }
    f.update(changes)
    return f


def meta(encoding: str, names: list[str] = NAMES) -> bytes:
    return json.dumps(
        {"device": "arr", "encoding": encoding, "channels": [{"name": n} for n in names]}
    ).encode()


def topic(kind: str, gateway: str = "gw1", device: str = "arr") -> str:
    return f"{PREFIX}/{gateway}/{device}/{kind}"


# ------------------------------------------------------------------------------ sequences


def test_in_order_sequences_have_no_gap() -> None:
    t = SequenceTracker()
    assert [t.observe(("g", "d"), s) for s in (5, 6, 7)] == [(True, 0, False)] * 3
    assert (t.missing, t.gaps, t.duplicates, t.restarts) == (0, 0, 0, 0)


def test_a_jump_is_a_gap_of_the_numbers_between() -> None:
    t = SequenceTracker()
    t.observe(("g", "d"), 1)
    assert t.observe(("g", "d"), 5) == (True, 3, False)
    assert t.observe(("g", "d"), 6) == (True, 0, False)
    assert t.observe(("g", "d"), 10) == (True, 3, False)
    assert (t.missing, t.gaps) == (6, 2)


def test_duplicates_and_late_frames_are_dropped_and_counted() -> None:
    t = SequenceTracker()
    for s in (3, 4):
        t.observe(("g", "d"), s)
    assert t.observe(("g", "d"), 4) == (False, 0, False)
    assert t.observe(("g", "d"), 2) == (False, 0, False)
    assert t.duplicates == 2 and t.missing == 0


def test_sequence_one_after_more_is_a_restart_not_a_duplicate() -> None:
    t = SequenceTracker()
    for s in (1, 2, 3):
        t.observe(("g", "d"), s)
    assert t.observe(("g", "d"), 1) == (True, 0, True)
    assert t.observe(("g", "d"), 2) == (True, 0, False)
    assert t.restarts == 1 and t.duplicates == 0


def test_streams_are_tracked_per_gateway_and_device() -> None:
    t = SequenceTracker()
    t.observe(("g1", "d"), 10)
    t.observe(("g2", "d"), 1)
    t.observe(("g1", "e"), 100)
    assert t.observe(("g1", "d"), 11) == (True, 0, False)
    assert t.observe(("g2", "d"), 2) == (True, 0, False)
    assert t.missing == 0


# ------------------------------------------------------------------------------ the stream


def test_json_frames_pass_and_gaps_are_marked_on_the_frame_after() -> None:
    stream = FrameStream(PREFIX)
    out = [stream.feed(topic("frame"), encode_json(fields(s)))[0] for s in (1, 2, 5)]
    frames = [f for batch in out for f in batch]
    assert [f.sequence for f in frames] == [1, 2, 5]
    assert [f.missing_before for f in frames] == [0, 0, 2]
    assert frames[0].gateway == "gw1" and frames[0].device == "arr"
    assert frames[0].as_json()["gateway"] == "gw1"
    assert stream.sequences.missing == 2 and stream.stats.frames == 3


def test_binary_frames_wait_for_the_meta_and_take_its_channel_names() -> None:
    stream = FrameStream(PREFIX)
    assert stream.feed(topic("frame"), encode_binary(fields(1))) == ([], [])
    assert stream.feed(topic("frame"), encode_binary(fields(2))) == ([], [])
    frames, notes = stream.feed(topic("meta"), meta("binary"))
    assert notes == [] and [f.sequence for f in frames] == [1, 2]
    assert frames[0].fields["channels"] == NAMES and frames[0].fields["device"] == "arr"
    assert frames[0].fields["resistance_ohm"] == [1200.0, 5.0e5, None]
    later, _ = stream.feed(topic("frame"), encode_binary(fields(3)))
    assert [f.sequence for f in later] == [3]


def test_binary_frames_of_a_device_without_meta_are_flushed_with_index_names() -> None:
    stream = FrameStream(PREFIX)
    stream.feed(topic("frame"), encode_binary(fields(1)))
    frames, notes = stream.flush()
    assert [f.fields["channels"] for f in frames] == [["0", "1", "2"]]
    assert len(notes) == 1 and "no meta message" in notes[0]


def test_the_pending_queue_is_bounded() -> None:
    stream = FrameStream(PREFIX, pending_limit=2)
    got = [stream.feed(topic("frame"), encode_binary(fields(s)))[0] for s in (1, 2, 3)]
    assert [len(g) for g in got] == [0, 0, 1] and got[2][0].sequence == 1


def test_a_frame_that_disagrees_with_its_meta_is_reported_not_raised() -> None:
    stream = FrameStream(PREFIX)
    stream.feed(topic("meta"), meta("binary", ["x", "y"]))
    frames, notes = stream.feed(topic("frame"), encode_binary(fields(1)))
    assert frames == [] and "3 channels" in notes[0] and stream.stats.undecodable == 1
    frames, notes = stream.feed(topic("frame"), b"TGF1garbage")
    assert frames == [] and "could not be decoded" in notes[0]


@pytest.mark.parametrize(
    "payload",
    [b"not json", b"[1, 2]", json.dumps({"sequence": 1}).encode(), encode_json(fields(-1)),
     encode_json(fields(1, status=["ok"]))],
    ids=["text", "list", "missing-keys", "negative-seq", "ragged"],
)  # fmt: skip
def test_bad_json_frames_are_counted(payload: bytes) -> None:
    stream = FrameStream(PREFIX)
    frames, notes = stream.feed(topic("frame"), payload)
    assert frames == [] and len(notes) == 1 and stream.stats.undecodable == 1


def test_the_meta_decides_the_encoding_and_a_cleared_meta_is_forgotten() -> None:
    stream = FrameStream(PREFIX)
    stream.feed(topic("meta"), meta("json"))
    frames, _ = stream.feed(topic("frame"), encode_json(fields(1)))
    assert len(frames) == 1
    stream.feed(topic("meta"), b"")
    assert ("gw1", "arr") not in stream.meta
    _, notes = stream.feed(topic("meta"), b"{not json")
    assert "unreadable meta" in notes[0]


def test_other_topics_are_ignored() -> None:
    stream = FrameStream(PREFIX)
    for t in ("lab/tactile/gw1/status", "lab/other/gw1/arr/frame", "lab/tactile/gw1/arr/frame/x", "x"):
        assert stream.feed(t, encode_json(fields(1))) == ([], [])
    assert stream.split_topic("lab/tactile/gw1/arr/meta") == ("gw1", "arr", "meta")


# ------------------------------------------------------------------------------ record rows


def test_record_rows_follow_the_record_format() -> None:
    rows, skipped = recordable(
        fields(1, channels=["a", "b", "c", "d", "e", "f"], force_n=[1.0] * 6,
               resistance_ohm=[1200.0, None, None, 0.0, 7.0, None],
               status=["ok", "no_contact", "open", "short", "stale", "error"])
    )  # fmt: skip
    assert rows == [("a", 1200.0), ("b", math.inf), ("c", math.inf)]
    assert skipped == 3


def test_a_frame_of_a_device_that_is_down_has_no_rows() -> None:
    assert recordable(fields(1, up=False)) == ([], 3)


def test_frame_time_is_the_device_clock_else_the_host_clock() -> None:
    assert frame_clock_s(fields(2)) == pytest.approx(0.1)
    assert frame_clock_s(fields(2, device_time_s=None)) == 1002.0


def test_in_contact_is_ok_saturated_or_extrapolated_with_force() -> None:
    f = fields(1, channels=["a", "b", "c", "d", "e"], force_n=[1.0, 2.0, 0.0, 3.0, 8.0],
               status=["ok", "saturated", "ok", "no_contact", "extrapolated"],
               resistance_ohm=[1.0] * 5)  # fmt: skip
    assert in_contact(f) == ["a", "b", "e"]


def test_an_extrapolated_channel_keeps_its_record_row() -> None:
    rows, skipped = recordable(
        fields(1, channels=["a", "b"], force_n=[8.0, 0.3], resistance_ohm=[900.0, None],
               status=["extrapolated", "extrapolated"])
    )  # fmt: skip
    assert rows == [("a", 900.0), ("b", math.inf)] and skipped == 0


# ------------------------------------------------------------------------------ options


@pytest.mark.parametrize(
    ("text", "tls", "want"),
    [
        ("broker", False, ("broker", 1883)),
        ("broker", True, ("broker", 8883)),
        ("10.0.0.1:1884", False, ("10.0.0.1", 1884)),
        ("[::1]:1885", False, ("::1", 1885)),
        ("[::1]", True, ("::1", 8883)),
    ],
)
def test_broker_addresses(text: str, tls: bool, want: tuple[str, int]) -> None:
    assert parse_broker(text, tls) == want


@pytest.mark.parametrize("text", ["", ":1883", "b:0", "b:70000", "b:x", "[::1", "[::1]x", "a b"])
def test_bad_broker_addresses(text: str) -> None:
    with pytest.raises(ConfigError, match="--broker"):
        parse_broker(text, False)


def test_topics_put_meta_first_and_share_only_the_frames() -> None:
    s = SubscribeSettings("b", 1883, prefix=PREFIX, gateway="gw1")
    assert s.topics() == ["lab/tactile/gw1/+/meta", "lab/tactile/gw1/+/frame"]
    shared = SubscribeSettings("b", 1883, prefix=PREFIX, share_group="recorders")
    assert shared.topics() == ["lab/tactile/+/+/meta", "$share/recorders/lab/tactile/+/+/frame"]
    assert SubscribeSettings("::1", 1883).where() == "[::1]:1883"


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"prefix": "a/#"}, "--prefix"),
        ({"prefix": "$SYS"}, "--prefix"),
        ({"gateway": "a/b"}, "--gateway"),
        ({"device": "#"}, "--device"),
        ({"device": ""}, "--device"),
        ({"share_group": "a/b"}, "--share"),
    ],
)
def test_bad_topic_options(changes: dict[str, Any], fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        SubscribeSettings("b", 1883, **changes)


def test_password_files(tmp_path: Path) -> None:
    pw = tmp_path / "pw"
    pw.write_text("secret\nignored\n")
    pw.chmod(0o600)
    assert read_password_file(pw) == "secret"
    pw.chmod(0o640)
    with pytest.raises(ConfigError, match="chmod 600"):
        read_password_file(pw)
    with pytest.raises(ConfigError, match="does not exist"):
        read_password_file(tmp_path / "nope")


def test_a_stop_during_the_reconnect_back_off_ends_the_wait_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C while the broker is away: the back-off (up to 10 s) is slept in 0.1 s steps that
    each look at the stop flag, not in one sleep that a SIGINT does not cut short."""
    from gateway.mqtt import subscriber

    slept: list[float] = []
    monkeypatch.setattr(subscriber.time, "sleep", slept.append)
    calls = iter([False, False, False, True])
    assert subscriber._wait(10.0, lambda: next(calls)) is True
    assert slept == [0.1, 0.1, 0.1]
    # without a stop the whole wait is slept, in steps no longer than 0.1 s
    slept.clear()
    clock = iter(x * 0.1 for x in range(1000))
    monkeypatch.setattr(subscriber.time, "monotonic", lambda: next(clock))
    assert subscriber._wait(0.35, lambda: False) is False
    assert len(slept) == 3 and max(slept) <= 0.1


def test_the_default_client_id_is_fixed_for_the_host_and_the_filters() -> None:
    """A persistent session needs the same client id on every connect and every run."""
    from gateway.mqtt.subscribe_settings import SESSION_EXPIRY_S, default_client_id

    a = SubscribeSettings("b", 1883, prefix="lab/tactile", gateway="gw1", device="arr")
    again = SubscribeSettings("b", 1883, prefix="lab/tactile", gateway="gw1", device="arr")
    other = SubscribeSettings("b", 1883, prefix="lab/tactile", gateway="gw1", device="+")
    assert a.client_id == again.client_id != other.client_id
    assert a.client_id.startswith("tactile-sub-") and a.session_expiry_s == SESSION_EXPIRY_S == 3600
    assert default_client_id("p", "+", "+", None, host="my host.lab").startswith("tactile-sub-my-host-lab-")
    assert SubscribeSettings("b", 1883, client_id="rec-1").client_id == "rec-1"
    with pytest.raises(ConfigError, match="--client-id"):
        SubscribeSettings("b", 1883, client_id="x" * 65)
    with pytest.raises(ConfigError, match="--session-expiry"):
        SubscribeSettings("b", 1883, session_expiry_s=-1)


def test_the_command_line_passes_the_client_id_and_the_session_expiry(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from click.testing import CliRunner

    from gateway.cli import main, subscribe_cmd
    from gateway.mqtt.subscriber import SubscribeError

    seen: list[SubscribeSettings] = []

    def stop(settings: SubscribeSettings, *args: object, **kwargs: object) -> None:
        seen.append(settings)
        raise SubscribeError("stopped by the test")

    monkeypatch.setattr(subscribe_cmd, "run_subscriber", stop)
    args = ["subscribe", "--broker", "127.0.0.1:1", "--client-id", "bench-7", "--session-expiry", "120"]
    out = CliRunner().invoke(main, args)
    assert "stopped by the test" in out.output and "Traceback" not in out.output
    assert seen and seen[0].client_id == "bench-7" and seen[0].session_expiry_s == 120
    bad = CliRunner().invoke(main, ["subscribe", "--broker", "127.0.0.1:1", "--session-expiry", "-1"])
    assert bad.exit_code == 2 and "--session-expiry" in bad.output
