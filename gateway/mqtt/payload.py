"""MQTT frames: one message per poll of a device, as JSON or as a compact binary layout, or
several polls of a device in one message (a batch) when frames wait.

A frame carries a per-device sequence number (consecutive polls: a gap means frames were
dropped), the device clock (s, or null), the host's Unix time (s), the array quantities, and
per channel (in index order of the enabled channels) the drift-corrected force (N), the
static force (N), the resistance (ohm) and the status. Absent values are ``null`` in JSON and
NaN in the binary layout. ``docs/mqtt.md`` documents both; ``decode_binary`` reads the binary
layout back into the same dictionary ``frame_dict`` builds.

The JSON is a view of the snapshot's one ``Frame`` (``runtime.frame``, shared with the page
and the stream): every float rounded to ``DECIMALS`` (6) decimals, None where absent (the
frame's reasons, and its one NaN policy, ``finite_or_none``).

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

A batch carries two or more frames of one device, each whole, in the order of their sequence
numbers (``docs/mqtt.md``, "Batches"). JSON: ``{"frames":[<frame>,<frame>,...]}``, each element
the single-frame object byte for byte. Binary (little-endian)::

    offset  type       field
    0       4 bytes    magic b"TGB1"
    4       uint32     count, the number of frames
    8       count binary frames (``TGF1`` above) back to back; each one's length is
            64 + 13 n, n from its own header
"""

from __future__ import annotations

import math
import struct
from typing import Any, Final, NotRequired, TypedDict

import numpy as np
from numpy.typing import NDArray

from ..errors import GatewayError
from ..runtime.frame import DECIMALS, Frame, RoiJson, compact_json, frame_of, roi_json
from ..runtime.snapshot import STATUS_LABELS, DeviceSnapshot, finite_or_none

__all__ = [
    "BATCH_MAGIC",
    "BINARY_MAGIC",
    "DECIMALS",
    "FrameDecodeError",
    "FrameFields",
    "decode_binary",
    "decode_binary_batch",
    "encode_binary",
    "encode_binary_batch",
    "encode_json",
    "encode_json_batch",
    "encode_json_frame",
    "frame_dict",
    "json_body",
]

BINARY_MAGIC: Final = b"TGF1"
BATCH_MAGIC: Final = b"TGB1"
_BATCH_HEADER: Final = struct.Struct("<4sI")
_HEADER: Final = struct.Struct("<4sQdddddd HH")
_LABELS: Final = tuple(STATUS_LABELS)


class FrameFields(TypedDict):
    """A frame's fields as published in JSON (``docs/mqtt.md``), in this order."""

    sequence: int
    device: str
    host_time_s: float
    device_time_s: float | None
    up: bool
    total_force_n: float
    center_of_pressure_mm: list[float] | None
    contact_area_mm2: float
    channels_in_contact: int
    channels: list[str]
    force_n: list[float | None]
    force_static_n: list[float | None]
    resistance_ohm: list[float | None]
    status: list[str]
    #: the device's regions of interest, when it has any (JSON only: the binary layout does
    #: not carry them): the page's frame's ``rois`` (``web.frames.RoiJson``)
    rois: NotRequired[list[RoiJson]]


class FrameDecodeError(GatewayError):
    """Bytes that are not a binary frame of this layout."""


def _float32_values(array: NDArray[np.float32]) -> list[float | None]:
    """Received float32 values as published floats: each the shortest decimal that reads back
    as the same float32 (not the float64 it widens to, ``0.10000000149011612`` for 0.1), then
    rounded to ``DECIMALS`` as a JSON frame's are; None where not finite."""
    return [round(float(str(v)), DECIMALS) if np.isfinite(v) else None for v in array]


def frame_dict(source: DeviceSnapshot | Frame, sequence: int) -> FrameFields:
    """One poll of a device as the frame's fields (JSON-ready: no NaN, None for absent; every
    float rounded to ``DECIMALS`` decimals): a view of the snapshot's shared ``Frame``."""
    f = frame_of(source) if isinstance(source, DeviceSnapshot) else source
    cop = f.center_of_pressure_mm
    out: FrameFields = {
        "sequence": int(sequence),
        "device": f.device,
        "host_time_s": f.host_time_s,
        "device_time_s": f.device_time_s,
        "up": f.up,
        "total_force_n": f.total_force_n,
        "center_of_pressure_mm": None if cop is None else [cop[0], cop[1]],
        "contact_area_mm2": f.contact_area_mm2,
        "channels_in_contact": f.channels_in_contact,
        "channels": list(f.channel_names),
        "force_n": list(f.force_n),
        "force_static_n": list(f.force_static_n),
        "resistance_ohm": list(f.resistance_ohm),
        "status": [_LABELS[s] for s in f.status],
    }
    if f.rois:
        out["rois"] = [roi_json(r) for r in f.rois]
    return out


def encode_json(frame: FrameFields) -> bytes:
    return compact_json(frame)


def json_body(snap: DeviceSnapshot) -> bytes:
    """The JSON frame of ``snap`` without its leading ``sequence`` member (``{"device":...}``):
    encoded once per snapshot (``DeviceSnapshot.derived``; the poll loop computes it while it
    waits for the next answer when MQTT publishes JSON), the sequence spliced in per message
    by ``encode_json_frame``."""
    fields: dict[str, Any] = dict(frame_dict(frame_of(snap), 0))
    del fields["sequence"]
    return compact_json(fields)


def encode_json_frame(snap: DeviceSnapshot, sequence: int) -> bytes:
    """``encode_json(frame_dict(snap, sequence))``, byte for byte, from the snapshot's one
    ``json_body``."""
    return b'{"sequence":%d,%s' % (int(sequence), snap.derived(json_body)[1:])


def _nan(value: float | None) -> float:
    return math.nan if value is None else float(value)


def encode_binary(frame: FrameFields) -> bytes:
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
    per_channel = (frame["force_n"], frame["force_static_n"], frame["resistance_ohm"])
    arrays = [np.array([_nan(v) for v in values], dtype="<f4").tobytes() for values in per_channel]
    status = np.array([STATUS_LABELS.index(s) for s in frame["status"]], dtype=np.uint8).tobytes()
    return header + b"".join(arrays) + status


def decode_binary(data: bytes, device: str = "", channels: list[str] | None = None) -> dict[str, Any]:
    """A binary frame back into the fields of ``frame_dict``, as a received JSON frame's are
    (the per-channel floats to float32 precision, printed as the shortest decimal of that
    precision and rounded as in JSON).
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
    values: list[list[float | None]] = []  # force_n, force_static_n, resistance_ohm
    for _ in range(3):
        values.append(_float32_values(np.frombuffer(data, dtype="<f4", count=n, offset=offset)))
        offset += 4 * n
    codes = np.frombuffer(data, dtype=np.uint8, count=n, offset=offset).tolist()
    if any(c >= len(STATUS_LABELS) for c in codes):
        raise FrameDecodeError(f"status code out of range 0..{len(STATUS_LABELS) - 1}")
    return {
        "sequence": seq,
        "device": device,
        "host_time_s": host,
        "device_time_s": finite_or_none(dev_time),
        "up": all(STATUS_LABELS[c] != "stale" for c in codes),
        "total_force_n": total,
        "center_of_pressure_mm": None if math.isnan(cx) or math.isnan(cy) else [cx, cy],
        "contact_area_mm2": area,
        "channels_in_contact": contact,
        "channels": list(channels) if channels is not None else [str(i) for i in range(n)],
        "force_n": values[0],
        "force_static_n": values[1],
        "resistance_ohm": values[2],
        "status": [STATUS_LABELS[c] for c in codes],
    }


def encode_json_batch(frames: list[bytes]) -> bytes:
    """A JSON batch of encoded single-frame JSON messages (``encode_json``,
    ``encode_json_frame``): ``{"frames":[...]}``, each frame byte for byte as alone."""
    return b'{"frames":[' + b",".join(frames) + b"]}"


def encode_binary_batch(frames: list[bytes]) -> bytes:
    """A binary batch of encoded binary frames (``encode_binary``): magic, count, the frames."""
    return _BATCH_HEADER.pack(BATCH_MAGIC, len(frames)) + b"".join(frames)


def split_binary_batch(data: bytes) -> list[bytes]:
    """The binary frames of a binary batch, each checked for its magic and its length
    (``FrameDecodeError`` if the bytes are not such a batch)."""
    if len(data) < _BATCH_HEADER.size:
        raise FrameDecodeError(f"a binary batch has at least {_BATCH_HEADER.size} bytes, got {len(data)}")
    magic, count = _BATCH_HEADER.unpack_from(data)
    if magic != BATCH_MAGIC:
        raise FrameDecodeError(f"not a binary batch: magic {magic!r}, expected {BATCH_MAGIC!r}")
    if count == 0:
        raise FrameDecodeError("a batch of no frames")
    offset, frames = _BATCH_HEADER.size, []
    for k in range(count):
        if len(data) - offset < _HEADER.size:
            raise FrameDecodeError(f"a binary batch of {count} frames ends inside binary frame {k + 1}")
        n = struct.unpack_from("<H", data, offset + _HEADER.size - 2)[0]
        end = offset + _HEADER.size + n * (3 * 4 + 1)
        if end > len(data):
            raise FrameDecodeError(f"a binary batch of {count} frames ends inside binary frame {k + 1}")
        frames.append(data[offset:end])
        offset = end
    if offset != len(data):
        raise FrameDecodeError(f"a binary batch of {count} frames has {len(data) - offset} bytes after them")
    return frames


def decode_binary_batch(
    data: bytes, device: str = "", channels: list[str] | None = None
) -> list[dict[str, Any]]:
    """A binary batch back into its frames' fields, in order (``decode_binary`` of each)."""
    return [decode_binary(frame, device, channels) for frame in split_binary_batch(data)]
