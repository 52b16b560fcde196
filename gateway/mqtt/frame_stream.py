"""Received messages into frames (pure, no broker): ``FrameStream`` turns the messages of the
``meta`` and ``frame`` topics into ``Frame`` objects (JSON frames as they are; binary frames
decoded with the channel names and encoding of the device's retained meta message, held back
until that message has arrived; a batch, JSON or binary, into its frames in order) and
``SequenceTracker`` notices gaps, duplicates and restarts in the per-device sequence numbers.
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Final

from .payload import BATCH_MAGIC, BINARY_MAGIC, FrameDecodeError, decode_binary, split_binary_batch

#: the first bytes of a binary message: a frame or a batch of frames
_BINARY_MAGICS: Final = (BINARY_MAGIC, BATCH_MAGIC)

#: Binary messages (frames or batches) of a device kept while its retained meta message has
#: not arrived (binary frames need its channel names); beyond that the oldest are decoded
#: with index names.
PENDING_LIMIT: Final = 2000
#: Bytes held for meta messages over all devices: a flood of binary frames under ever new
#: device names cannot fill the memory. Beyond it a device's oldest held frames are dropped
#: (counted in ``StreamStats.pending_dropped``; they show as a gap in its sequence).
PENDING_BYTES_LIMIT: Final = 64 * 1024 * 1024
#: What a held frame costs beyond its payload (the bytes object and its queue slot), so that
#: tiny frames are bounded too.
PENDING_FRAME_OVERHEAD_BYTES: Final = 100


@dataclass(frozen=True)
class Frame:
    """One received frame: the fields of ``payload.frame_dict`` and where it came from.
    ``missing_before`` counts the frames of this device lost just before it (a gap);
    ``restarted`` says its sequence started again (a restarted gateway or publisher)."""

    gateway: str
    device: str
    fields: dict[str, Any]
    missing_before: int = 0
    restarted: bool = False

    @property
    def sequence(self) -> int:
        return int(self.fields["sequence"])

    @property
    def key(self) -> tuple[str, str]:
        return self.gateway, self.device

    def as_json(self) -> dict[str, Any]:
        return {"gateway": self.gateway, **self.fields}


_FRAME_KEYS: Final = ("sequence", "host_time_s", "channels", "force_n", "resistance_ohm", "status")


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _check_json_fields(fields: dict[str, Any]) -> None:
    """The types a subscriber relies on (printing, contacts, record rows): a frame that has
    others is refused here, not half-way through the record."""
    missing = [k for k in _FRAME_KEYS if k not in fields]
    if missing:
        raise FrameDecodeError(f"a JSON frame without {', '.join(missing)}")
    seq = fields["sequence"]
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
        raise FrameDecodeError(f"a JSON frame with sequence {str(seq)[:40]!r}")
    for key in ("host_time_s", "device_time_s", "total_force_n"):
        value = fields.get(key)
        if value is not None and not _is_number(value):
            raise FrameDecodeError(f"a JSON frame whose {key} is not a number")
    if fields["host_time_s"] is None:
        raise FrameDecodeError("a JSON frame whose host_time_s is not a number")
    _check_times(fields)
    if not isinstance(fields.get("up", True), bool):
        raise FrameDecodeError("a JSON frame whose up is not true or false")
    lists = ("channels", "force_n", "resistance_ohm", "status")
    if not all(isinstance(fields[k], list) for k in lists):
        raise FrameDecodeError(f"a JSON frame whose {', '.join(lists)} are not all lists")
    n = len(fields["channels"])
    if any(len(fields[k]) != n for k in lists):
        raise FrameDecodeError("a JSON frame whose channel lists differ in length")
    if not all(isinstance(c, str | int) and not isinstance(c, bool) for c in fields["channels"]):
        raise FrameDecodeError("a JSON frame whose channel names are not strings")
    if not all(isinstance(c, str) for c in fields["status"]):
        raise FrameDecodeError("a JSON frame whose statuses are not strings")
    for key in ("force_n", "resistance_ohm"):
        if not all(v is None or _is_number(v) for v in fields[key]):
            raise FrameDecodeError(f"a JSON frame whose {key} holds values that are not numbers or null")


def _check_times(fields: dict[str, Any]) -> None:
    """A frame's clock must be a finite time: NaN or an infinity (``NaN``, ``Infinity`` in
    JSON, as Python writes them; NaN in a binary frame's host_time_s) would be a record's
    time and every later row's origin."""
    for key in ("host_time_s", "device_time_s"):
        value = fields.get(key)
        if value is not None and not math.isfinite(value):
            raise FrameDecodeError(f"a frame whose {key} is {value}, not a finite time")


def _json_object(data: bytes) -> Any:
    try:
        return json.loads(data)
    except RecursionError:
        raise FrameDecodeError("not a JSON frame: nested too deeply") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, an integer too long
        raise FrameDecodeError(f"not a JSON frame: {str(exc).split(';')[0][:200]}") from None


def _json_fields(fields: Any, device: str) -> dict[str, Any]:
    if not isinstance(fields, dict):
        raise FrameDecodeError("not a JSON frame: not an object")
    _check_json_fields(fields)
    fields.setdefault("device", device)
    return fields


def decode_json_frame(data: bytes, device: str) -> dict[str, Any]:
    """A JSON frame, checked for the fields a subscriber uses (``FrameDecodeError`` if not:
    also for JSON Python cannot read, such as arrays nested 100,000 deep or an integer of
    more than 4300 digits)."""
    return _json_fields(_json_object(data), device)


def decode_json_message(data: bytes, device: str) -> list[dict[str, Any]]:
    """The frames of a JSON message: one frame, or a batch ``{"frames":[...]}`` (in order),
    each checked as ``decode_json_frame`` checks one. A batch is taken whole or refused whole."""
    obj = _json_object(data)
    if not (isinstance(obj, dict) and "frames" in obj and "sequence" not in obj):
        return [_json_fields(obj, device)]
    frames = obj["frames"]
    if not isinstance(frames, list):
        raise FrameDecodeError("a batch whose frames are not a list")
    if not frames:
        raise FrameDecodeError("a batch of no frames")
    return [_json_fields(f, device) for f in frames]


class SequenceTracker:
    """Per stream (gateway, device): the last sequence number, and what a new one means.

    The next number is in order; a larger one follows a gap of the numbers in between; 1
    after a larger number is a restart (the publisher counts from 1); any other smaller or
    equal number is a duplicate (QoS 1 may deliver twice) or late, and is dropped.
    """

    def __init__(self) -> None:
        self.last: dict[tuple[str, str], int] = {}
        self.missing = 0
        self.gaps = 0
        self.duplicates = 0
        self.restarts = 0

    def observe(self, key: tuple[str, str], seq: int) -> tuple[bool, int, bool]:
        """(accept, missing before it, restarted)."""
        last = self.last.get(key)
        if last is None or seq == last + 1:
            self.last[key] = seq
            return True, 0, False
        if seq > last + 1:
            missing = seq - last - 1
            self.missing += missing
            self.gaps += 1
            self.last[key] = seq
            return True, missing, False
        if seq == 1:
            self.restarts += 1
            self.last[key] = seq
            return True, 0, True
        self.duplicates += 1
        return False, 0, False


@dataclass
class StreamStats:
    frames: int = 0
    undecodable: int = 0
    meta: int = 0
    devices: set[tuple[str, str]] = field(default_factory=set)
    last_error: str | None = None
    pending_dropped: int = 0  # binary frames dropped while held for a meta message


class FrameStream:
    """Messages in, frames out, in the order of each device's sequence numbers."""

    def __init__(
        self, prefix: str, pending_limit: int = PENDING_LIMIT, pending_bytes_limit: int = PENDING_BYTES_LIMIT
    ) -> None:
        self.prefix_levels = prefix.split("/")
        self.pending_limit = pending_limit
        self.pending_bytes_limit = pending_bytes_limit
        self.pending_bytes = 0  # payloads held plus PENDING_FRAME_OVERHEAD_BYTES each
        self.meta: dict[tuple[str, str], dict[str, Any]] = {}
        self.pending: dict[tuple[str, str], deque[bytes]] = {}
        self.sequences = SequenceTracker()
        self.stats = StreamStats()

    def split_topic(self, topic: str) -> tuple[str, str, str] | None:
        """(gateway, device, kind) of ``<prefix>/<gateway>/<device>/<kind>``, else None."""
        levels = topic.split("/")
        n = len(self.prefix_levels)
        if len(levels) != n + 3 or levels[:n] != self.prefix_levels:
            return None
        gateway, device, kind = levels[n:]
        return (gateway, device, kind) if kind in ("frame", "meta") else None

    def feed(self, topic: str, payload: bytes) -> tuple[list[Frame], list[str]]:
        """The frames a message completes (none, one, or those held for a meta message) and
        notices for the user (a frame that could not be decoded)."""
        parts = self.split_topic(topic)
        if parts is None:
            return [], []
        gateway, device, kind = parts
        key = (gateway, device)
        if kind == "meta":
            return self._meta(key, payload)
        meta = self.meta.get(key)
        if meta is None and payload[:4] in _BINARY_MAGICS:
            return self._hold(key, payload)
        return self._decode(key, [payload], meta)

    def _hold(self, key: tuple[str, str], payload: bytes) -> tuple[list[Frame], list[str]]:
        """Hold a binary frame for its meta message; beyond the byte bound over all devices
        drop this device's oldest held frames (the flooding device pays), counted."""
        held = self.pending.setdefault(key, deque())
        held.append(payload)
        self.pending_bytes += len(payload) + PENDING_FRAME_OVERHEAD_BYTES
        notices: list[str] = []
        while self.pending_bytes > self.pending_bytes_limit and held:
            dropped = held.popleft()
            self.pending_bytes -= len(dropped) + PENDING_FRAME_OVERHEAD_BYTES
            self.stats.pending_dropped += 1
            if self.stats.pending_dropped == 1:
                notices.append(
                    f"{key[0]}/{key[1]}: frames held for meta messages reached "
                    f"{self.pending_bytes_limit} bytes: the oldest are dropped (counted)"
                )
        if not held:
            del self.pending[key]
        if len(held) <= self.pending_limit:
            return [], notices
        oldest = held.popleft()
        self.pending_bytes -= len(oldest) + PENDING_FRAME_OVERHEAD_BYTES
        frames, more = self._decode(key, [oldest], None)
        return frames, notices + more

    def flush(self) -> tuple[list[Frame], list[str]]:
        """Frames still held for a meta message that never came (index names as channels)."""
        frames: list[Frame] = []
        notices: list[str] = []
        for key, held in sorted(self.pending.items()):
            if held:
                notices.append(
                    f"{key[0]}/{key[1]}: no meta message arrived; {len(held)} binary frame(s) decoded "
                    "with channel numbers as names"
                )
            f, n = self._decode(key, list(held), None)
            frames += f
            notices += n
        self.pending.clear()
        self.pending_bytes = 0
        return frames, notices

    def _meta(self, key: tuple[str, str], payload: bytes) -> tuple[list[Frame], list[str]]:
        if not payload:
            self.meta.pop(key, None)  # a retained message cleared
            return [], []
        try:
            meta = json.loads(payload)
            names = [str(c["name"]) for c in meta["channels"]]
            encoding = str(meta.get("encoding", "json"))
        except RecursionError:
            self.stats.undecodable += 1
            return [], [f"{key[0]}/{key[1]}: an unreadable meta message (nested too deeply)"]
        except (ValueError, KeyError, TypeError) as exc:  # ValueError: JSON, UTF-8, a long integer
            self.stats.undecodable += 1
            return [], [f"{key[0]}/{key[1]}: an unreadable meta message ({exc!r})"]
        self.stats.meta += 1
        self.meta[key] = {"channels": names, "encoding": encoding}
        held = self.pending.pop(key, deque())
        self.pending_bytes -= sum(len(p) + PENDING_FRAME_OVERHEAD_BYTES for p in held)
        return self._decode(key, list(held), self.meta[key]) if held else ([], [])

    def _decode(
        self, key: tuple[str, str], payloads: list[bytes], meta: dict[str, Any] | None
    ) -> tuple[list[Frame], list[str]]:
        frames: list[Frame] = []
        notices: list[str] = []
        for payload in payloads:
            try:
                message = self._fields(key, payload, meta)
            except FrameDecodeError as exc:
                self.stats.undecodable += 1
                self.stats.last_error = str(exc)
                notices.append(f"{key[0]}/{key[1]}: a frame could not be decoded: {exc}")
                continue
            for fields in message:  # a batch's frames in order, each with its own sequence
                accept, missing, restarted = self.sequences.observe(key, int(fields["sequence"]))
                if not accept:
                    continue
                self.stats.frames += 1
                self.stats.devices.add(key)
                frames.append(Frame(key[0], key[1], fields, missing, restarted))
        return frames, notices

    @staticmethod
    def _fields(key: tuple[str, str], payload: bytes, meta: dict[str, Any] | None) -> list[dict[str, Any]]:
        """The frames of one message (one, or a batch's in order); ``FrameDecodeError`` if any
        of them cannot be decoded (a batch is taken whole or not at all)."""
        binary = payload[:4] in _BINARY_MAGICS if meta is None else meta["encoding"] == "binary"
        if not binary:
            return decode_json_message(payload, key[1])
        names = None if meta is None else list(meta["channels"])
        parts = split_binary_batch(payload) if payload[:4] == BATCH_MAGIC else [payload]
        out = []
        for part in parts:
            fields = decode_binary(part, key[1], names)
            _check_times(fields)
            if names is not None and len(fields["force_n"]) != len(names):
                raise FrameDecodeError(
                    f"the frame has {len(fields['force_n'])} channels, its meta message names {len(names)}"
                )
            out.append(fields)
        return out
