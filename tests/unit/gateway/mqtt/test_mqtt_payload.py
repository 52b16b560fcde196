"""Frame payloads: JSON and the binary layout, round trips from hand-built snapshots, the
documented byte offsets, absent values, and bytes that are not a frame."""

from __future__ import annotations

import json
import math
import re
import struct
from collections.abc import Callable

import numpy as np
import pytest

from gateway.mqtt.payload import (
    BINARY_MAGIC,
    FrameDecodeError,
    decode_binary,
    encode_binary,
    encode_json,
    frame_dict,
)
from gateway.runtime.snapshot import STATUS_LABELS, ChannelStatus, DeviceSnapshot

NAMES = ("a0", "a1", "b0", "b1")


def snapshot(**changes: object) -> DeviceSnapshot:
    fields: dict[str, object] = {
        "device": "arr",
        "bus": "sim",
        "channel_index": np.arange(4),
        "channel_names": NAMES,
        "x_mm": np.array([0.0, 2.5, 0.0, 2.5]),
        "y_mm": np.array([0.0, 0.0, 2.5, 2.5]),
        "resistance_ohm": np.array([1500.0, math.inf, 0.0, math.nan]),
        "force_n": np.array([1.25, math.nan, math.nan, 0.0]),
        "static_estimate": None,
        "reference_force_n": np.full(4, math.nan),
        "status": np.array(
            [ChannelStatus.OK, ChannelStatus.OPEN, ChannelStatus.SHORT, ChannelStatus.NO_CONTACT],
            dtype=np.int8,
        ),
        "up": True,
        "timestamp_s": 1_700_000_000.125,
        "last_success_timestamp_s": 1_700_000_000.125,
        "device_time_s": 12.5,
        "poll_interval_s": 0.05,
        "total_force_n": 1.25,
        "center_of_pressure_mm": (0.0, 0.0),
        "channels_in_contact": 1,
        "contact_area_mm2": 6.25,
    }
    fields.update(changes)
    return DeviceSnapshot(**fields)  # type: ignore[arg-type]


def test_frame_dict_is_json_ready_with_none_for_absent_values() -> None:
    frame = frame_dict(snapshot(), 7)
    assert frame["sequence"] == 7 and frame["device"] == "arr" and frame["channels"] == list(NAMES)
    assert frame["force_n"] == [1.25, None, None, 0.0]
    assert frame["resistance_ohm"] == [1500.0, None, 0.0, None], "inf and NaN are both absent"
    assert frame["force_static_n"] == [None] * 4, "no static estimate"
    assert frame["status"] == ["ok", "open", "short", "no_contact"]
    assert frame["center_of_pressure_mm"] == [0.0, 0.0] and frame["device_time_s"] == 12.5
    back = json.loads(encode_json(frame))
    assert back == frame
    assert b"NaN" not in encode_json(frame) and b"Infinity" not in encode_json(frame)


def test_json_frame_without_device_clock_or_contact() -> None:
    frame = frame_dict(snapshot(device_time_s=None, center_of_pressure_mm=None), 1)
    back = json.loads(encode_json(frame))
    assert back["device_time_s"] is None and back["center_of_pressure_mm"] is None


def test_binary_layout_matches_the_documented_offsets() -> None:
    frame = frame_dict(snapshot(), 0x0102030405)
    data = encode_binary(frame)
    n = 4
    assert len(data) == 64 + n * 13
    assert data[0:4] == BINARY_MAGIC == b"TGF1"
    assert struct.unpack_from("<Q", data, 4)[0] == 0x0102030405
    assert struct.unpack_from("<d", data, 12)[0] == 1_700_000_000.125
    assert struct.unpack_from("<d", data, 20)[0] == 12.5
    assert struct.unpack_from("<d", data, 28)[0] == 1.25
    assert struct.unpack_from("<dd", data, 36) == (0.0, 0.0)
    assert struct.unpack_from("<d", data, 52)[0] == 6.25
    assert struct.unpack_from("<HH", data, 60) == (1, n)
    force = np.frombuffer(data, "<f4", n, 64)
    static = np.frombuffer(data, "<f4", n, 64 + 4 * n)
    resistance = np.frombuffer(data, "<f4", n, 64 + 8 * n)
    status = np.frombuffer(data, np.uint8, n, 64 + 12 * n)
    assert force[0] == np.float32(1.25) and np.isnan(force[1]) and force[3] == 0.0
    assert np.isnan(static).all()
    assert resistance[0] == 1500.0 and np.isnan(resistance[1]) and resistance[2] == 0.0
    assert [STATUS_LABELS[s] for s in status] == ["ok", "open", "short", "no_contact"]


def test_binary_round_trip_to_float32_precision() -> None:
    snap = snapshot(
        resistance_ohm=np.array([1234.5678, 2.0e6, 0.1, 99.0]),
        force_n=np.array([0.123456789, 3.3, math.nan, 0.0]),
    )
    frame = frame_dict(snap, 42)
    back = decode_binary(encode_binary(frame), "arr", list(NAMES))
    for key in ("sequence", "device", "host_time_s", "device_time_s", "up", "total_force_n"):
        assert back[key] == frame[key], key
    assert back["center_of_pressure_mm"] == frame["center_of_pressure_mm"]
    assert back["channels"] == list(NAMES) and back["status"] == frame["status"]
    assert back["channels_in_contact"] == 1 and back["contact_area_mm2"] == 6.25
    # each value as the shortest decimal of its float32: the published value where it has no
    # more significant digits than float32 keeps (1234.5678 has one more)
    assert back["force_n"] == frame["force_n"] == [0.123457, 3.3, None, 0.0]
    assert back["force_static_n"] == frame["force_static_n"]
    assert back["resistance_ohm"] == [1234.5677, 2.0e6, 0.1, 99.0]


def test_binary_absent_clock_and_centre_and_default_channel_names() -> None:
    frame = frame_dict(snapshot(device_time_s=None, center_of_pressure_mm=None), 3)
    back = decode_binary(encode_binary(frame))
    assert back["device_time_s"] is None and back["center_of_pressure_mm"] is None
    assert back["channels"] == ["0", "1", "2", "3"] and back["device"] == ""


def test_a_stale_channel_makes_a_binary_frame_down() -> None:
    status = np.full(4, int(ChannelStatus.STALE), dtype=np.int8)
    frame = frame_dict(snapshot(status=status, up=False), 9)
    assert decode_binary(encode_binary(frame))["up"] is False


def test_an_extrapolated_channel_in_json_and_binary_frames() -> None:
    """A force outside the calibrated range: a value (in contact), labelled ``extrapolated``
    in JSON and status code 7 in the binary layout (the codes before it keep their numbers)."""
    status = np.array(
        [ChannelStatus.EXTRAPOLATED, ChannelStatus.OPEN, ChannelStatus.SHORT, ChannelStatus.EXTRAPOLATED],
        dtype=np.int8,
    )
    snap = snapshot(status=status, force_n=np.array([8.0, math.nan, math.nan, 0.3]))
    frame = frame_dict(snap, 5)
    assert frame["status"] == ["extrapolated", "open", "short", "extrapolated"]
    assert frame["force_n"] == [8.0, None, None, 0.3]
    assert json.loads(encode_json(frame))["status"][0] == "extrapolated"
    data = encode_binary(frame)
    codes = np.frombuffer(data, np.uint8, 4, 64 + 12 * 4).tolist()
    assert codes == [7, 3, 4, 7] and STATUS_LABELS[7] == "extrapolated" and len(STATUS_LABELS) == 10
    back = decode_binary(data, "arr", list(NAMES))
    assert back["status"] == frame["status"] and back["up"] is True
    assert back["force_n"] == [8.0, None, None, 0.3]
    assert decode_binary(data[:-1] + bytes([8]))["status"][-1] == "no_zero"
    assert decode_binary(data[:-1] + bytes([9]))["status"][-1] == "uncalibrated"  # the last code
    with pytest.raises(FrameDecodeError, match=r"status code out of range 0\.\.9"):
        decode_binary(data[:-1] + bytes([10]))


@pytest.mark.parametrize(
    ("mutate", "fragment"),
    [
        (lambda d: d[:10], "at least 64 bytes"),
        (lambda d: b"XXXX" + d[4:], "magic"),
        (lambda d: d[:-1], "has 116 bytes, got 115"),
        (lambda d: d + b"\0", "got 117"),
        (lambda d: d[:-1] + bytes([len(STATUS_LABELS)]), "status code out of range"),
        (lambda d: b"", "got 0"),
    ],
    ids=["short", "bad-magic", "truncated", "trailing", "status", "empty"],
)
def test_bytes_that_are_not_a_frame_are_refused(mutate: Callable[[bytes], bytes], fragment: str) -> None:
    data = encode_binary(frame_dict(snapshot(), 1))
    with pytest.raises(FrameDecodeError, match=fragment):
        decode_binary(mutate(data))


def test_published_floats_are_rounded_to_6_decimals_without_float_noise() -> None:
    """Binary float noise (``15.620000000000001``) is not published: every float of a frame is
    rounded to 6 decimals (1 µN, 1 µs, 1 µΩ), the same keys and absent values as before."""
    noisy = 15.620000000000001
    snap = snapshot(
        force_n=np.array([noisy, 0.1234567891, math.nan, 0.0]),
        resistance_ohm=np.array([41230.50000000001, math.inf, 91234567.12345679, 1e-9]),
        total_force_n=noisy,
        center_of_pressure_mm=(noisy, 2.0000000000000004),
        contact_area_mm2=12.500000000000002,
        device_time_s=184.21000000000001 + 1e-12,
        timestamp_s=1_700_000_000.1234567,
    )
    frame = frame_dict(snap, 1)
    assert frame["force_n"] == [15.62, 0.123457, None, 0.0]
    assert frame["resistance_ohm"] == [41230.5, None, 91234567.123457, 0.0]
    assert frame["total_force_n"] == 15.62 and frame["center_of_pressure_mm"] == [15.62, 2.0]
    assert frame["contact_area_mm2"] == 12.5 and frame["device_time_s"] == 184.21
    assert frame["host_time_s"] == 1_700_000_000.123457, "decimals, not significant digits"
    text = encode_json(frame).decode()
    assert "15.620000000000001" not in text and '"force_n":[15.62,0.123457,null,0.0]' in text
    numbers = [float(t) for t in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", text)]
    assert all(round(v, 6) == v for v in numbers)
    assert json.loads(text) == frame
    assert set(frame) == set(frame_dict(snapshot(), 1)), "the same keys"
