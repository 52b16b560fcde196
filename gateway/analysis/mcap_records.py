"""Measurement records as MCAP (``docs/record-format.md``, "MCAP records"): the writer, and
the reader of what it writes.

The CSV record holds one row per sample per channel; the MCAP record holds one message per
poll of a device, on the topic ``/tactile_record`` (``/tactile_record/DEVICE`` when the
record holds several devices), with one entry per channel in each array. The message is a
ROS 2 message definition (schema encoding ``ros2msg``, message encoding ``cdr``,
``tactile_gateway/msg/RecordSample``, the text of ``SCHEMA_TEXT``), so that Foxglove, ROS 2
tooling (``ros2 bag`` with the MCAP storage plugin) and ``mcap-ros2-support`` decode it from
the file alone: a robotics user needs no code of ours. The columns and their units are those
of the CSV record (``time_s`` in s since the record's start, ``resistance_ohm`` with ``inf``
for an open circuit, ``force_n`` the reference force in N, ``temperature_c`` in degC); a
record without a reference force or temperature leaves those arrays empty. The CSV
metadata lines (``# key: value``) are an MCAP metadata record named ``tactile_record``.

The CDR is written and read here (little-endian XCDR1, as ROS 2 writes it): the gateway
needs no ROS package at run time. The reader returns plain columns per channel
(``McapColumns``); ``records.read_record`` makes them the same ``Record`` as a CSV record's,
with the same checks (at most ``MAX_RECORD_CHANNELS`` channels, finite non-decreasing time
per channel, resistance > 0 or inf, finite force and temperature). Every problem, a damaged
file included, is a one-line ``RecordError``; the file's chunks are decompressed only up to
the record size limit, however large their headers say they are.
"""

from __future__ import annotations

import io
import math
import struct
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import IO, BinaryIO, Final, Literal, cast

import lz4.frame  # type: ignore[import-untyped]
import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer
from numpy.typing import NDArray

from ..atomic import AtomicFile
from ..errors import RecordError
from .record_common import channel_name_problem, names_text

MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
SCHEMA_NAME: Final = "tactile_gateway/msg/RecordSample"
TOPIC: Final = "/tactile_record"
METADATA_NAME: Final = "tactile_record"
#: The Header record's library string starts with this: how ``is_mcap_record`` knows our file.
LIBRARY: Final = "tactile-gateway record"
Compression = Literal["zstd", "lz4", "none"]
COMPRESSIONS: Final[tuple[Compression, ...]] = ("zstd", "lz4", "none")
_COMPRESSION_TYPE = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}

SCHEMA_TEXT: Final = """\
# One poll of one device in a tactile-gateway measurement record (docs/record-format.md):
# entry k of every array belongs to channel[k].
# header.stamp: wall clock of the sample; header.frame_id: the device
std_msgs/Header header
# s since the start of the record (the device clock where it has one)
float64 time_s
string[] channel
# ohm, > 0; inf: open circuit
float64[] resistance_ohm
# N, the reference force applied (a load cell); empty when the record has none
float64[] force_n
# degC; empty when the record has none
float64[] temperature_c
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""

FloatArray = NDArray[np.float64]
_CDR_LE = b"\x00\x01\x00\x00"
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_F64 = struct.Struct("<d")


def _pad(buf: bytearray, size: int) -> None:
    """Align ``buf`` to ``size`` bytes counted after the 4-byte encapsulation header."""
    buf += b"\0" * (-(len(buf) - 4) % size)


def _cdr_string(buf: bytearray, text: bytes) -> None:
    _pad(buf, 4)
    buf += _U32.pack(len(text) + 1)
    buf += text
    buf += b"\0"


def _names_block(names: Sequence[str]) -> bytes:
    """A ``string[]`` in CDR, to be placed at an offset that is a multiple of 4 (so that its
    content does not depend on where it is)."""
    buf = bytearray(_CDR_LE)
    buf += _U32.pack(len(names))
    for name in names:
        _cdr_string(buf, name.encode("utf-8"))
    return bytes(buf[4:])


def _float_seq(buf: bytearray, values: Sequence[float]) -> None:
    _pad(buf, 4)
    buf += _U32.pack(len(values))
    if values:  # CDR aligns a sequence's elements only when it has some (as Fast-CDR does)
        _pad(buf, 8)
        buf += np.asarray(values, dtype="<f8").tobytes()


def encode_sample(
    stamp_ns: int,
    frame_id: str,
    time_s: float,
    names_block: bytes,
    resistance_ohm: Sequence[float],
    force_n: Sequence[float],
    temperature_c: Sequence[float],
) -> bytes:
    """One ``RecordSample`` message in CDR; ``names_block`` from ``_names_block``."""
    buf = bytearray(_CDR_LE)
    sec, nsec = divmod(max(stamp_ns, 0), 1_000_000_000)
    buf += _STAMP.pack(min(sec, 2**31 - 1), nsec)
    _cdr_string(buf, frame_id.encode("utf-8"))
    _pad(buf, 8)
    buf += _F64.pack(time_s)
    buf += names_block  # starts at a multiple of 8
    _float_seq(buf, resistance_ohm)
    _float_seq(buf, force_n)
    _float_seq(buf, temperature_c)
    return bytes(buf)


class McapRecordWriter:
    """The MCAP form of ``records.RecordWriter``: the same ``row`` / ``flush``, and ``close``
    (which must come before the file is committed: it writes the summary and the index).

    Rows of one time and one device in a row make one message; a new time, another device or
    ``flush`` starts the next. The device is the first ``device_levels`` parts of a channel
    label split at ``/`` (a record of several devices labels ``device/channel``: 1; ``subscribe``
    labels ``gateway/device/channel``: 2); 0 (the default), one device: the topic is
    ``/tactile_record``, else ``/tactile_record/DEVICE``. ``out`` is an
    ``AtomicFile`` (the record appears whole at its commit) or a binary stream.
    ``compression``: ``zstd`` (the default: smallest, and what Foxglove and rosbag2 read),
    ``lz4`` or ``none``. ``start_ns``: the wall clock (ns since the Unix epoch) of
    ``time_s`` = 0, for the messages' log time and header stamp (default: now)."""

    def __init__(
        self,
        out: AtomicFile | BinaryIO,
        metadata: Mapping[str, str] | None = None,
        *,
        has_force: bool = False,
        has_temperature: bool = False,
        compression: Compression = "zstd",
        device_levels: int = 0,
        start_ns: int | None = None,
        chunk_bytes: int = 1024 * 1024,
    ) -> None:
        self.has_force = has_force
        self.has_temperature = has_temperature
        self._levels = device_levels
        self._start_ns = time.time_ns() if start_ns is None else start_ns
        stream = _Stream(out)
        self._mcap = Writer(
            cast(IO[bytes], stream), chunk_size=chunk_bytes, compression=_COMPRESSION_TYPE[compression]
        )
        self._mcap.start(profile="ros2", library=LIBRARY)
        self._schema_id = self._mcap.register_schema(SCHEMA_NAME, "ros2msg", SCHEMA_TEXT.encode("utf-8"))
        if metadata:
            self._mcap.add_metadata(METADATA_NAME, {k: " ".join(str(v).split()) for k, v in metadata.items()})
        self._topics: dict[str, tuple[int, list[int]]] = {}  # device -> (channel id, [sequence])
        self._blocks: dict[str, tuple[tuple[str, ...], bytes]] = {}  # device -> last names, CDR
        self._channels_ok: set[str] = set()
        self._device: str | None = None
        self._time_s = math.nan
        self._names: list[str] = []
        self._seen: set[str] = set()
        self._r: list[float] = []
        self._f: list[float] = []
        self._t: list[float] = []
        self._closed = False

    def row(
        self,
        time_s: float,
        channel: str,
        resistance_ohm: float,
        force_n: float | None = None,
        temperature_c: float | None = None,
        extra: Sequence[float | str] = (),
    ) -> None:
        """One sample of one channel (as ``RecordWriter.row``; no extra columns)."""
        if extra:
            raise ValueError("an MCAP record has no extra columns")
        if channel not in self._channels_ok:
            problem = channel_name_problem(channel)
            if problem is not None:
                raise ValueError(f"channel name {channel[:80]!r}: {problem}")
            self._channels_ok.add(channel)
        if self.has_force and force_n is None:
            raise ValueError("this record has a force_n column: give force_n")
        if self.has_temperature and temperature_c is None:
            raise ValueError("this record has a temperature_c column: give temperature_c")
        device = "/".join(channel.split("/", self._levels)[: self._levels]) if self._levels else ""
        t = float(time_s)
        if device != self._device or t != self._time_s or channel in self._seen:
            self.flush()
            self._device, self._time_s = device, t
        self._names.append(channel)
        self._seen.add(channel)
        self._r.append(float(resistance_ohm))
        if self.has_force:
            self._f.append(float(force_n))  # type: ignore[arg-type]
        if self.has_temperature:
            self._t.append(float(temperature_c))  # type: ignore[arg-type]

    def flush(self) -> None:
        """Write the rows given since the last message as one message."""
        if not self._names or self._device is None:
            return
        device = self._device
        if device not in self._topics:
            topic = f"{TOPIC}/{device}" if device else TOPIC
            channel_id = self._mcap.register_channel(topic, "cdr", self._schema_id)
            self._topics[device] = (channel_id, [0])
        channel_id, sequence = self._topics[device]
        names = tuple(self._names)
        cached = self._blocks.get(device)
        if cached is None or cached[0] != names:
            cached = (names, _names_block(names))
            self._blocks[device] = cached
        stamp_ns = self._start_ns + round(self._time_s * 1e9) if math.isfinite(self._time_s) else 0
        stamp_ns = min(max(stamp_ns, 0), 2**63 - 1)
        data = encode_sample(stamp_ns, device or "record", self._time_s, cached[1], self._r, self._f, self._t)
        sequence[0] += 1
        self._mcap.add_message(channel_id, stamp_ns, data, stamp_ns, sequence[0] % 2**32)
        self._names, self._r, self._f, self._t = [], [], [], []
        self._seen = set()

    def close(self) -> None:
        """Write the last message, the summary (schemas, channels, statistics, chunk and
        message indexes) and the closing magic. The stream itself is not closed."""
        if not self._closed:
            self.flush()
            self._mcap.finish()
            self._closed = True


class _Stream:
    """What ``mcap.writer.Writer`` needs of its output: ``write`` and ``tell``."""

    def __init__(self, out: AtomicFile | BinaryIO) -> None:
        self._write = out.write_bytes if isinstance(out, AtomicFile) else out.write
        self._count = 0

    def write(self, data: bytes) -> int:
        self._write(data)
        self._count += len(data)
        return len(data)

    def tell(self) -> int:
        return self._count


def is_mcap_record(head: bytes) -> bool:
    """True when ``head`` (a file's first bytes) starts an MCAP file this project wrote (its
    Header record names ``LIBRARY``): a record that ``--out`` may replace."""
    if not head.startswith(MCAP_MAGIC) or len(head) < 22 or head[8] != 0x01:
        return False
    try:
        stream = StreamReader(io.BytesIO(head), record_size_limit=len(head))
        for record in stream.records:
            return isinstance(record, Header) and record.library.startswith(LIBRARY)
    except (McapError, ValueError, struct.error, UnicodeDecodeError, IndexError):
        return False
    return False


@dataclass(frozen=True)
class McapChannel:
    """One channel of an MCAP record: its columns, and ``message``, the 1-based number (in
    file order) of the message each sample came from: a position for messages, as a CSV
    record's line."""

    time_s: FloatArray
    resistance_ohm: FloatArray
    force_n: FloatArray | None
    temperature_c: FloatArray | None
    message: NDArray[np.int64]


@dataclass(frozen=True)
class McapColumns:
    """An MCAP record read into plain columns, before ``records`` makes it a ``Record``:
    ``channels`` in order of first appearance."""

    metadata: dict[str, str]
    channels: dict[str, McapChannel]
    has_force: bool


@dataclass
class _Sample:
    number: int
    topic: str
    time_s: float
    names: tuple[str, ...]
    values: dict[str, FloatArray]


def read_mcap_columns(
    data: bytes | bytearray, where: str, *, max_channels: int, max_bytes: int
) -> McapColumns:
    """The samples of an MCAP record (``data``, the whole file) with the checks of the module
    docstring; ``where`` names the file in messages. ``RecordError`` for any problem."""
    try:
        return _read(data, where, max_channels, max_bytes)
    except RecordError:
        raise
    except (
        McapError,
        zstandard.ZstdError,
        ValueError,  # UnicodeDecodeError too
        struct.error,
        IndexError,
        KeyError,
        EOFError,
        OverflowError,
        RuntimeError,  # lz4's errors
    ) as exc:
        text = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise RecordError(f"{where}: not a readable MCAP record (damaged or cut short?): {text}") from None
    except MemoryError:
        raise RecordError(f"{where}: not a readable MCAP record: it does not fit in memory") from None


def _read(data: bytes | bytearray, where: str, max_channels: int, max_bytes: int) -> McapColumns:
    reader = StreamReader(io.BytesIO(data), emit_chunks=True, validate_crcs=True, record_size_limit=max_bytes)
    schemas: dict[int, Schema] = {}
    ours: dict[int, str] = {}  # channel id -> topic, of the channels of our schema
    metadata: dict[str, str] = {}
    samples: list[_Sample] = []
    budget = [max_bytes]
    for record in reader.records:
        for inner in _unchunk(record, where, budget):
            if isinstance(inner, Schema):
                schemas[inner.id] = inner
            elif isinstance(inner, Channel):
                schema = schemas.get(inner.schema_id)
                if (
                    schema is not None
                    and schema.name == SCHEMA_NAME
                    and schema.encoding == "ros2msg"
                    and inner.message_encoding == "cdr"
                ):
                    ours[inner.id] = inner.topic
            elif isinstance(inner, Message) and inner.channel_id in ours:
                number = len(samples) + 1
                try:
                    time_s, names, values = decode_sample(inner.data)
                except ValueError as exc:
                    raise RecordError(
                        f"{where}: message {number} ({ours[inner.channel_id]}): {exc}"
                    ) from None
                samples.append(_Sample(number, ours[inner.channel_id], time_s, names, values))
            elif isinstance(inner, Metadata) and inner.name == METADATA_NAME:
                metadata.update(inner.metadata)
    if not samples:
        raise RecordError(
            f"{where}: an MCAP file without record samples (no messages of schema {SCHEMA_NAME}); "
            "a record written by tactile-gateway record or subscribe has them"
        )
    return _columns(samples, metadata, where, max_channels)


def _unchunk(record: object, where: str, budget: list[int]) -> list[object]:
    """The records inside a chunk (decompressed within the remaining ``budget`` of bytes, its
    CRC checked), or the record itself."""
    if not isinstance(record, Chunk):
        return [record]
    size = record.uncompressed_size
    if size > budget[0]:
        raise RecordError(
            f"{where}: a chunk of {size} bytes decompressed is past the limit for a record; not read"
        )
    budget[0] -= size
    if record.compression == "zstd":
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(record.data)) as reader:
            raw = reader.read(size + 1)
    elif record.compression == "lz4":
        raw = lz4.frame.LZ4FrameDecompressor().decompress(record.data, max_length=size + 1)
    elif record.compression == "":
        raw = record.data
    else:
        raise RecordError(f"{where}: a chunk compressed with {record.compression[:20]!r}, not zstd or lz4")
    if len(raw) != size:
        raise RecordError(f"{where}: a chunk decompresses to {len(raw)} bytes, its header says {size}")
    return list(breakup_chunk(replace(record, compression="", data=raw), validate_crc=True))


def decode_sample(data: bytes) -> tuple[float, tuple[str, ...], dict[str, FloatArray]]:
    """``time_s``, the channel names and the value arrays of one ``RecordSample`` message
    (``resistance_ohm`` always; ``force_n`` / ``temperature_c`` when not empty). ValueError
    naming what is wrong for a message that is not one."""
    if len(data) < 4 or bytes(data[:2]) != _CDR_LE[:2]:
        raise ValueError("not a little-endian CDR message")
    view = memoryview(data)
    pos = 4

    def align(size: int) -> None:
        nonlocal pos
        pos += -(pos - 4) % size

    def take(n: int) -> memoryview:
        nonlocal pos
        if n < 0 or pos + n > len(view):
            raise ValueError("the message ends early")
        out = view[pos : pos + n]
        pos += n
        return out

    def u32() -> int:
        align(4)
        return int(_U32.unpack(take(4))[0])

    def string() -> str:
        n = u32()
        raw = bytes(take(n))
        if not raw or raw[-1] != 0:
            raise ValueError("a string without its closing NUL")
        return raw[:-1].decode("utf-8")

    take(8)  # header.stamp
    string()  # header.frame_id
    align(8)
    time_s = float(_F64.unpack(take(8))[0])
    count = u32()
    if count > len(view):
        raise ValueError(f"{count} channels in a message of {len(view)} bytes")
    names = tuple(string() for _ in range(count))
    values: dict[str, FloatArray] = {}
    for field in ("resistance_ohm", "force_n", "temperature_c"):
        n = u32()
        if n:
            align(8)
            values[field] = np.frombuffer(take(8 * n), dtype="<f8").astype(np.float64)
            if n != count:
                raise ValueError(f"{n} values of {field} for {count} channels")
        elif field == "resistance_ohm" and count:
            raise ValueError(f"no resistance_ohm for {count} channels")
    return time_s, names, values


def _columns(samples: list[_Sample], metadata: dict[str, str], where: str, max_channels: int) -> McapColumns:
    """Check the samples as a CSV record's rows are checked and gather them per channel: runs
    of messages with the same channel list are stacked, so a channel's columns are sliced
    from a run's 2-D arrays, not appended value by value."""
    has_force = "force_n" in samples[0].values
    has_temp = "temperature_c" in samples[0].values
    fields = ["resistance_ohm", *(["force_n"] if has_force else []), *(["temperature_c"] if has_temp else [])]
    segments: dict[str, list[tuple[NDArray[np.int64], FloatArray, dict[str, FloatArray]]]] = {}
    last: dict[str, tuple[float, int]] = {}
    run: list[_Sample] = []
    for s in samples:
        _check_sample(s, where, has_force, has_temp)
        if run and s.names != run[0].names:
            _gather(run, fields, segments, last, where, max_channels)
            run = []
        run.append(s)
    _gather(run, fields, segments, last, where, max_channels)
    channels: dict[str, McapChannel] = {}
    for name, parts in segments.items():
        cols = {f: np.concatenate([v[f] for _, _, v in parts]) for f in fields}
        channels[name] = McapChannel(
            time_s=np.concatenate([t for _, t, _ in parts]),
            resistance_ohm=cols["resistance_ohm"],
            force_n=cols.get("force_n"),
            temperature_c=cols.get("temperature_c"),
            message=np.concatenate([n for n, _, _ in parts]),
        )
    return McapColumns(metadata, channels, has_force)


def _check_sample(s: _Sample, where: str, has_force: bool, has_temp: bool) -> None:
    at = f"{where}: message {s.number} ({s.topic})"
    if len(set(s.names)) != len(s.names):
        raise RecordError(f"{at}: a channel twice in one message")
    for field, present in (("force_n", has_force), ("temperature_c", has_temp)):
        if s.names and (field in s.values) != present:
            have = "has" if field in s.values else "has no"
            raise RecordError(f"{at}: {have} {field}, unlike the record's first message")
    if not math.isfinite(s.time_s):
        raise RecordError(f"{at}: time_s {s.time_s} is not a finite time")
    r = s.values.get("resistance_ohm", np.empty(0))
    bad = np.flatnonzero(np.isnan(r) | (r <= 0.0))
    if bad.size:
        k = int(bad[0])
        raise RecordError(
            f"{at}: channel {names_text([s.names[k]])!r}: resistance_ohm {float(r[k])!r} must be > 0 "
            "(inf for an open circuit)"
        )
    for field, what in (("force_n", "not finite"), ("temperature_c", "not a finite temperature")):
        v = s.values.get(field)
        if v is not None and not np.all(np.isfinite(v)):
            k = int(np.flatnonzero(~np.isfinite(v))[0])
            raise RecordError(
                f"{at}: channel {names_text([s.names[k]])!r}: {field} {float(v[k])!r} is {what}"
            )


def _gather(
    run: list[_Sample],
    fields: list[str],
    segments: dict[str, list[tuple[NDArray[np.int64], FloatArray, dict[str, FloatArray]]]],
    last: dict[str, tuple[float, int]],
    where: str,
    max_channels: int,
) -> None:
    """Add a run of messages with one channel list to ``segments``, checking that time goes
    forward in each channel (within the run and since the channel's last message)."""
    names = run[0].names
    if not names:
        return
    times = np.array([s.time_s for s in run], dtype=np.float64)
    numbers = np.array([s.number for s in run], dtype=np.int64)
    back = np.flatnonzero(np.diff(times) < 0.0)
    if back.size:
        k = int(back[0]) + 1
        _backwards(run[k], names[0], float(times[k - 1]), int(numbers[k - 1]), where)
    stacked = {f: np.vstack([s.values[f] for s in run]) for f in fields}
    for k, name in enumerate(names):
        if name in last and times[0] < last[name][0]:
            _backwards(run[0], name, *last[name], where)
        if name not in segments:
            if len(segments) >= max_channels:
                raise RecordError(
                    f"{where}: message {run[0].number} ({run[0].topic}): channel {names_text([name])!r} "
                    f"makes more than {max_channels} channels; a record holds at most {max_channels}"
                )
            segments[name] = []
        segments[name].append((numbers, times, {f: stacked[f][:, k] for f in fields}))
        last[name] = (float(times[-1]), int(numbers[-1]))


def _backwards(s: _Sample, name: str, before_s: float, before_message: int, where: str) -> None:
    raise RecordError(
        f"{where}: message {s.number} ({s.topic}): time goes backwards in channel {names_text([name])!r} "
        f"({s.time_s} after {before_s} in message {before_message})"
    )
