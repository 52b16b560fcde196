"""MQTT frames: one message per poll of a device, as JSON or as a compact binary layout.

A frame carries a per-device sequence number (consecutive polls: a gap means frames were
dropped), the device clock (s, or null), the host's Unix time (s), the array quantities, and
per channel (in index order of the enabled channels) the drift-corrected force (N), the
static force (N), the resistance (ohm) and the status. Absent values are ``null`` in JSON and
NaN in the binary layout. ``docs/mqtt.md`` documents both; ``decode_binary`` reads the binary
layout back into the same dictionary ``frame_dict`` builds.

Every float of a frame is rounded to ``DECIMALS`` (6) decimals, as the page's frames are: 1 µN,
1 µΩ, 1 µs, 1 µm² and 1 nm are far below what a tactile channel or a clock resolves, and no
binary float noise (``15.620000000000001``) reaches a subscriber. Rounding to decimals, not
to significant digits, keeps the Unix time to the microsecond.

Binary layout (little-endian, ``BINARY_VERSION`` 1)::

    offset  type       field
    0       4 bytes    magic b"TGF1"
    4       uint64     sequence
    12      float64    host_time_s (Unix)
    20      float64    device_time_s (NaN: none)
    28      float64    total_force_n
    36      float64    center_of_pressure x_mm (NaN: none)
    44      float64    center_of_pressure y_mm (NaN: none)
    52      float64    contact_area_mm2
    60      uint16     channels in contact
    62      uint16     n, the number of channels
    64      n float32  force_n
            n float32  force_static_n
            n float32  resistance_ohm
            n uint8    status (``ChannelStatus`` values)
"""

from __future__ import annotations

import json
import math
import struct
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from ..errors import GatewayError
from ..runtime.snapshot import STATUS_LABELS, DeviceSnapshot, finite_or_none

__all__ = ["BINARY_MAGIC", "FrameDecodeError", "decode_binary", "encode_binary", "encode_json", "frame_dict"]

BINARY_MAGIC: Final = b"TGF1"
_HEADER: Final = struct.Struct("<4sQdddddd HH")
DECIMALS: Final = 6


class FrameDecodeError(GatewayError):
    """Bytes that are not a binary frame of this layout."""


def _opt(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def _num(value: float) -> float:
    """A published float: rounded to ``DECIMALS`` (finite values only reach here)."""
    return round(float(value), DECIMALS)


def _opt_num(value: float | None) -> float | None:
    v = _opt(value)
    return None if v is None else round(v, DECIMALS)


def _num_values(array: Any) -> list[float | None]:
    return finite_or_none(np.asarray(array, dtype=np.float64), DECIMALS)


def _float32_values(array: NDArray[np.float32]) -> list[float | None]:
    """Received float32 values as published floats: each the shortest decimal that reads back
    as the same float32 (not the float64 it widens to, ``0.10000000149011612`` for 0.1), then
    rounded to ``DECIMALS`` as a JSON frame's are; None where not finite."""
    return [round(float(str(v)), DECIMALS) if np.isfinite(v) else None for v in array]


def frame_dict(snapshot: DeviceSnapshot, sequence: int) -> dict[str, Any]:
    """One poll of a device as the frame's fields (JSON-ready: no NaN, None for absent; every
    float rounded to ``DECIMALS`` decimals)."""
    cop = snapshot.center_of_pressure_mm
    return {
        "sequence": int(sequence),
        "device": snapshot.device,
        "host_time_s": _num(snapshot.timestamp_s),
        "device_time_s": _opt_num(snapshot.device_time_s),
        "up": bool(snapshot.up),
        "total_force_n": _num(snapshot.total_force_n),
        "center_of_pressure_mm": None if cop is None else [_num(cop[0]), _num(cop[1])],
        "contact_area_mm2": _num(snapshot.contact_area_mm2),
        "channels_in_contact": int(snapshot.channels_in_contact),
        "channels": list(snapshot.channel_names),
        "force_n": _num_values(snapshot.force_n),
        "force_static_n": _num_values(snapshot.force_static_n),
        "resistance_ohm": _num_values(snapshot.resistance_ohm),
        "status": [STATUS_LABELS[int(s)] for s in snapshot.status],
    }


def encode_json(frame: dict[str, Any]) -> bytes:
    return json.dumps(frame, separators=(",", ":"), allow_nan=False).encode("utf-8")


def _nan(value: float | None) -> float:
    return math.nan if value is None else float(value)


def encode_binary(frame: dict[str, Any]) -> bytes:
    """The binary layout of a ``frame_dict`` (channel names are in the retained meta message)."""
    n = len(frame["force_n"])
    cop = frame["center_of_pressure_mm"] or (None, None)
    header = _HEADER.pack(
        BINARY_MAGIC,
        frame["sequence"],
        frame["host_time_s"],
        _nan(frame["device_time_s"]),
        frame["total_force_n"],
        _nan(cop[0]),
        _nan(cop[1]),
        frame["contact_area_mm2"],
        min(frame["channels_in_contact"], 0xFFFF),
        n,
    )
    arrays = [np.array([_nan(v) for v in frame[key]], dtype="<f4").tobytes() for key in _FLOAT_KEYS]
    status = np.array([STATUS_LABELS.index(s) for s in frame["status"]], dtype=np.uint8).tobytes()
    return header + b"".join(arrays) + status


_FLOAT_KEYS: Final = ("force_n", "force_static_n", "resistance_ohm")


def decode_binary(data: bytes, device: str = "", channels: list[str] | None = None) -> dict[str, Any]:
    """A binary frame back into the fields of ``frame_dict`` (the per-channel floats to float32
    precision, printed as the shortest decimal of that precision and rounded as in JSON).
    ``device`` and ``channels`` come from the topic and the meta message. ``FrameDecodeError``
    if the bytes are not a frame."""
    if len(data) < _HEADER.size:
        raise FrameDecodeError(f"a binary frame has at least {_HEADER.size} bytes, got {len(data)}")
    magic, seq, host, dev_time, total, cx, cy, area, contact, n = _HEADER.unpack_from(data)
    if magic != BINARY_MAGIC:
        raise FrameDecodeError(f"not a binary frame: magic {magic!r}, expected {BINARY_MAGIC!r}")
    expected = _HEADER.size + n * (3 * 4 + 1)
    if len(data) != expected:
        raise FrameDecodeError(f"a binary frame of {n} channels has {expected} bytes, got {len(data)}")
    offset = _HEADER.size
    values: dict[str, list[float | None]] = {}
    for key in _FLOAT_KEYS:
        values[key] = _float32_values(np.frombuffer(data, dtype="<f4", count=n, offset=offset))
        offset += 4 * n
    codes = np.frombuffer(data, dtype=np.uint8, count=n, offset=offset).tolist()
    if any(c >= len(STATUS_LABELS) for c in codes):
        raise FrameDecodeError(f"status code out of range 0..{len(STATUS_LABELS) - 1}")
    return {
        "sequence": seq,
        "device": device,
        "host_time_s": host,
        "device_time_s": _opt(dev_time),
        "up": all(STATUS_LABELS[c] != "stale" for c in codes),
        "total_force_n": total,
        "center_of_pressure_mm": None if math.isnan(cx) or math.isnan(cy) else [cx, cy],
        "contact_area_mm2": area,
        "channels_in_contact": contact,
        "channels": list(channels) if channels is not None else [str(i) for i in range(n)],
        **values,
        "status": [STATUS_LABELS[c] for c in codes],
    }
