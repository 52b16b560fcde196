"""Measurement records (``docs/record-format.md``): the strict reader and the writer.

A record is a CSV file, UTF-8, comma separated, with ``# key: value`` metadata lines before
one header row, in long format (one row per sample per channel). The reader is strict about
what it needs (``time_s``, ``resistance_ohm``; ``force_n`` for fitting) and tolerant of what
it does not (column order, unknown columns). Every problem is a ``RecordError`` naming the
file, the line and the column; no row is ever dropped silently. Rows that are valid but
unusable for a fit (open circuit, zero force) are kept, counted and reported.

A reference force slightly below 0 N is a load cell's zero noise at rest (a bench writes
-0.0002 N): a value at most ``zero_noise_tolerance_n`` below 0 N (the larger of
``ZERO_NOISE_FLOOR_N`` and ``ZERO_NOISE_SHARE`` of the record's largest reference force) is
read as 0 N, and the rows so read are counted per channel (``ChannelRecord.zero_noise_rows``,
``zero_noise_note``). Every model of the project takes F >= 0 (the contact term goes as
1/sqrt(F)), and a sensor at rest is unloaded: reading the noise as 0 N keeps the format's
meaning, a force >= 0, for everything downstream. Below the tolerance a force is refused.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
import os
import stat
from array import array
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TextIO

import numpy as np
from numpy.typing import NDArray

from ..atomic import AtomicFile, atomic_write_text
from ..errors import RecordError
from .mcap_records import MCAP_MAGIC, McapRecordWriter, read_mcap_columns
from .record_common import NAME_CHARS_SHOWN as NAME_CHARS_SHOWN
from .record_common import NAMES_SHOWN as NAMES_SHOWN
from .record_common import RECORD_FORMATS as RECORD_FORMATS
from .record_common import channel_name_problem as channel_name_problem
from .record_common import names_text as names_text
from .record_common import record_format_for as record_format_for

FloatArray = NDArray[np.float64]

REQUIRED_COLUMNS: tuple[str, ...] = ("time_s", "resistance_ohm")
#: A reference force below 0 N by at most max(ZERO_NOISE_FLOOR_N, ZERO_NOISE_SHARE x the
#: record's largest reference force) is the load cell's zero noise, read as 0 N (N, fraction).
ZERO_NOISE_FLOOR_N = 0.05
ZERO_NOISE_SHARE = 0.01
KNOWN_COLUMNS: tuple[str, ...] = ("time_s", "channel", "resistance_ohm", "force_n", "temperature_c")
DEFAULT_CHANNEL = "0"


@dataclass(frozen=True)
class ChannelRecord:
    """The samples of one channel, in file order (time non-decreasing)."""

    name: str
    time_s: FloatArray
    resistance_ohm: FloatArray
    force_n: FloatArray | None
    temperature_c: FloatArray | None
    line: NDArray[np.int64]  # the source line of every sample (MCAP: its message number), for messages
    #: rows whose reference force was below 0 N within the zero-noise tolerance, read as 0 N
    zero_noise_rows: int = 0
    #: the lowest such reference force as written (N, <= 0; 0 when there is none)
    zero_noise_min_n: float = 0.0
    #: the tolerance the record was read with (N; ``zero_noise_tolerance_n``)
    zero_noise_tolerance_n: float = ZERO_NOISE_FLOOR_N

    @property
    def n_samples(self) -> int:
        return int(self.time_s.size)

    def zero_noise_note(self) -> str | None:
        """The rows of reference force below 0 N read as 0 N, in words (None: there are none)."""
        if not self.zero_noise_rows:
            return None
        rows = "row" if self.zero_noise_rows == 1 else "rows"
        return (
            f"channel {self.name}: {self.zero_noise_rows} {rows} of reference below 0 N accepted as "
            f"load-cell zero noise (down to {self.zero_noise_min_n:.4g} N, within the tolerance of "
            f"{self.zero_noise_tolerance_n:.4g} N) and read as 0 N"
        )

    def usable_for_fit(self) -> NDArray[np.bool_]:
        """Rows a fit can use: finite resistance and a positive reference force."""
        ok = np.isfinite(self.resistance_ohm)
        if self.force_n is not None:
            ok &= self.force_n > 0.0
        return np.asarray(ok)

    def unusable_counts(self) -> dict[str, int]:
        """How many rows a fit cannot use, by reason."""
        counts = {"open_circuit": int(np.count_nonzero(np.isinf(self.resistance_ohm)))}
        if self.force_n is not None:
            counts["zero_force"] = int(np.count_nonzero(self.force_n <= 0.0))
        return counts


@dataclass(frozen=True)
class Record:
    """A whole measurement record: metadata and channels (in order of first appearance)."""

    path: Path | None
    metadata: dict[str, str]
    channels: dict[str, ChannelRecord]
    extra_columns: tuple[str, ...] = field(default=())

    def channel(self, name: str | None = None) -> ChannelRecord:
        """One channel by name; ``None`` means the only channel (an error if there are several)."""
        if name is None:
            if len(self.channels) == 1:
                return next(iter(self.channels.values()))
            names = names_text(self.channels)
            raise RecordError(
                f"{self._where()}: the record has {len(self.channels)} channels ({names}); "
                "choose one with --channel NAME"
            )
        if name not in self.channels:
            import difflib

            close = difflib.get_close_matches(name, list(self.channels), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise RecordError(
                f"{self._where()}: no channel {name!r}{hint} (channels: {names_text(self.channels)})"
            )
        return self.channels[name]

    def _where(self) -> str:
        return str(self.path) if self.path else "<record>"

    @property
    def zero_noise_rows(self) -> int:
        """Rows of every channel whose reference force below 0 N was read as 0 N."""
        return sum(ch.zero_noise_rows for ch in self.channels.values())

    def zero_noise_notes(self) -> list[str]:
        """``ChannelRecord.zero_noise_note`` of every channel that has such rows."""
        return [note for ch in self.channels.values() if (note := ch.zero_noise_note()) is not None]


def zero_noise_tolerance_n(full_scale_n: float) -> float:
    """How far below 0 N a reference force may lie and still be a load cell's zero noise (N):
    max(``ZERO_NOISE_FLOOR_N``, ``ZERO_NOISE_SHARE`` x ``full_scale_n``), ``full_scale_n``
    the record's largest reference force (N)."""
    scale = full_scale_n if math.isfinite(full_scale_n) and full_scale_n > 0.0 else 0.0
    return max(ZERO_NOISE_FLOOR_N, ZERO_NOISE_SHARE * scale)


#: A record with more channels than this is refused at the first channel past it: 16 devices of
#: the gateway's largest (256 channels). Each channel costs its arrays and bookkeeping (about
#: 2 kB when it has one row), so a record of a million one-row channels is not read into GBs.
MAX_RECORD_CHANNELS = 4096


def _check_channel_count(n_channels: int, channel: str, where: str, line_no: int) -> None:
    """Refuse a record's new channel ``channel`` (on ``line_no``) when it already has
    ``MAX_RECORD_CHANNELS``."""
    if n_channels >= MAX_RECORD_CHANNELS:
        raise RecordError(
            f"{where}:{line_no}: channel {names_text([channel])!r} makes more than {MAX_RECORD_CHANNELS} "
            f"channels; a record holds at most {MAX_RECORD_CHANNELS} (a channel column with another "
            "meaning, such as a sample number?)"
        )


#: A record file larger than this is refused (a 4-million-row record is about 200 MB): an
#: endless or mistaken input is never read into memory without bound.
MAX_RECORD_BYTES = 2 * 1024**3
#: Read in steps of this size, so that Ctrl-C ends a long read between steps.
_READ_CHUNK = 16 * 1024**2


def _size_text(n: int) -> str:
    for unit, size in (("GiB", 1024**3), ("MiB", 1024**2), ("KiB", 1024)):
        if n >= size and n % size == 0:
            return f"{n // size} {unit}"
    return f"{n} bytes"


def read_record(
    path: str | os.PathLike[str], require_force: bool = False, max_bytes: int | None = None
) -> Record:
    """Read and validate a record file (see the module docstring). The file must be a regular
    file of at most ``max_bytes`` (default ``MAX_RECORD_BYTES``): a device such as /dev/zero,
    a pipe or a directory is refused unread, and a larger file (or one that grows past the
    limit while read) is refused naming the limit."""
    p = Path(path)
    limit = MAX_RECORD_BYTES if max_bytes is None else max_bytes
    too_large = f"{p}: larger than the limit of {_size_text(limit)} for a record; not read"
    try:
        # O_NONBLOCK: a named pipe with no writer is refused below, not waited on (it has no
        # effect on a regular file)
        with os.fdopen(os.open(p, os.O_RDONLY | os.O_NONBLOCK), "rb") as f:
            info = os.fstat(f.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise RecordError(
                    f"{p}: not a regular file (a device, pipe or directory); a record is a file"
                )
            if info.st_size > limit:
                raise RecordError(too_large)
            data = bytearray()
            while chunk := f.read(min(_READ_CHUNK, limit + 1 - len(data))):
                data += chunk
                if len(data) > limit:
                    raise RecordError(too_large)
    except FileNotFoundError:
        raise RecordError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise RecordError(f"{p}: is a directory; a record is a file") from None
    except OSError as exc:
        raise RecordError(f"{p}: cannot read ({exc.strerror})") from None
    if data.startswith(MCAP_MAGIC):
        return _mcap_record(data, p, require_force, limit)
    if p.suffix.lower() == ".mcap":
        raise RecordError(f"{p}: not an MCAP file (it does not start with the MCAP magic bytes)")
    try:
        text = data.decode("utf-8-sig")  # a spreadsheet's byte order mark is not a column
    except UnicodeDecodeError as exc:
        raise RecordError(f"{p}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    del data
    return parse_record(text, p, require_force=require_force)


def _mcap_record(data: bytearray, path: Path, require_force: bool, limit: int) -> Record:
    """A record in MCAP (``mcap_records``): the same ``Record`` as its CSV form gives, with the
    message number where a CSV record has its line."""
    cols = read_mcap_columns(data, str(path), max_channels=MAX_RECORD_CHANNELS, max_bytes=limit)
    if require_force and not cols.has_force:
        raise RecordError(f"{path}: the record has no force_n (reference force); fitting needs one")
    channels = {
        name: ChannelRecord(name, c.time_s, c.resistance_ohm, c.force_n, c.temperature_c, c.message)
        for name, c in cols.channels.items()
    }
    return Record(path=path, metadata=cols.metadata, channels=_zero_noise(channels, str(path), None))


def parse_record(text: str, path: Path | None = None, require_force: bool = False) -> Record:
    """Parse record text; ``path`` is only used in messages."""
    where = str(path) if path else "<record>"
    text = text.removeprefix("\ufeff")
    try:
        return _parse_record(text, path, where, require_force)
    except csv.Error as exc:  # e.g. a field over the csv module's size limit
        raise RecordError(f"{where}: not a readable CSV record: {exc}") from None


def _lines(text: str) -> Iterator[str]:
    """The lines of ``text`` with their endings (as ``csv`` wants them, for quoted fields that
    span lines), one at a time: no list of every line as ``str.splitlines`` builds (~300 MB for
    a 4-million-row record). A line ends at \\n; a lone \\r (old Mac files) ends one too."""
    start, n = 0, len(text)
    while start < n:
        end = text.find("\n", start)
        stop = n if end < 0 else end + 1
        line = text[start:stop]
        if "\r" in line and (line.count("\r") > 1 or not line.endswith("\r\n")):
            yield from line.splitlines(keepends=True)
        else:
            yield line
        start = stop


def _parse_record(text: str, path: Path | None, where: str, require_force: bool) -> Record:
    lines = _lines(text)
    metadata: dict[str, str] = {}
    header_text = None
    header_line = 0
    for line in lines:
        header_line += 1
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, sep, value = stripped[1:].partition(":")
            if sep and key.strip():
                metadata[key.strip()] = value.strip()
            continue
        header_text = line
        break
    if header_text is None:
        raise RecordError(f"{where}: no header row (expected columns {', '.join(REQUIRED_COLUMNS)})")
    reader = csv.reader(itertools.chain([header_text], lines))
    header = [h.strip() for h in next(reader)]
    seen: set[str] = set()
    for col, name in enumerate(header, start=1):
        if name in seen:
            raise RecordError(f"{where}:{header_line}: column {col}: duplicate column {name!r}")
        seen.add(name)
    needed = [*REQUIRED_COLUMNS, *(("force_n",) if require_force else ())]
    for name in needed:
        if name not in header:
            raise RecordError(
                f"{where}:{header_line}: missing required column {name!r} (found: "
                f"{', '.join(h.encode('unicode_escape').decode('ascii') for h in header)})"
            )
    index = {name: header.index(name) for name in KNOWN_COLUMNS if name in header}
    extra = tuple(h for h in header if h not in KNOWN_COLUMNS)

    # packed doubles, not lists of float objects: 8 bytes a value instead of ~32
    columns: dict[str, dict[str, array[float]]] = {}
    line_numbers: dict[str, array[int]] = {}
    last_time: dict[str, tuple[float, int]] = {}
    for offset, row in enumerate(reader, start=1):
        line_no = header_line + offset
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise RecordError(f"{where}:{line_no}: {len(row)} fields, the header has {len(header)}")
        channel = row[index["channel"]].strip() if "channel" in index else DEFAULT_CHANNEL
        if not channel:
            raise RecordError(
                f"{where}:{line_no}: column {index['channel'] + 1} (channel): empty channel name"
            )
        values: dict[str, float] = {}
        for name, col in index.items():
            if name == "channel":
                continue
            values[name] = _number(row[col], where, line_no, col + 1, name)
        t = values["time_s"]
        if not math.isfinite(t):
            raise RecordError(
                f"{where}:{line_no}: column {index['time_s'] + 1} (time_s): {t} is not a finite time"
            )
        r = values["resistance_ohm"]
        col_r = index["resistance_ohm"] + 1
        if math.isnan(r) or r <= 0.0:
            raise RecordError(
                f"{where}:{line_no}: column {col_r} (resistance_ohm): {row[col_r - 1].strip()!r} must be > 0 "
                "(inf for an open circuit)"
            )
        if "force_n" in values and not math.isfinite(values["force_n"]):
            col = index["force_n"] + 1
            raise RecordError(
                f"{where}:{line_no}: column {col} (force_n): {row[col - 1].strip()!r} is not finite"
            )
        if "temperature_c" in values and not math.isfinite(values["temperature_c"]):
            col = index["temperature_c"] + 1
            raise RecordError(f"{where}:{line_no}: column {col} (temperature_c): not a finite temperature")
        if channel in last_time and t < last_time[channel][0]:
            prev_t, prev_line = last_time[channel]
            raise RecordError(
                f"{where}:{line_no}: column {index['time_s'] + 1} (time_s): time goes backwards in channel "
                f"{names_text([channel])!r} ({t} after {prev_t} on line {prev_line})"
            )
        last_time[channel] = (t, line_no)
        if channel not in columns:
            _check_channel_count(len(columns), channel, where, line_no)
        store = columns.setdefault(channel, {name: array("d") for name in values})
        for name, v in values.items():
            store[name].append(v)
        line_numbers.setdefault(channel, array("q")).append(line_no)
    if not columns:
        raise RecordError(f"{where}: no data rows after the header on line {header_line}")
    channels = {
        name: ChannelRecord(
            name=name,
            time_s=np.array(data["time_s"], dtype=np.float64),
            resistance_ohm=np.array(data["resistance_ohm"], dtype=np.float64),
            force_n=np.array(data["force_n"], dtype=np.float64) if "force_n" in data else None,
            temperature_c=np.array(data["temperature_c"], dtype=np.float64)
            if "temperature_c" in data
            else None,
            line=np.array(line_numbers[name], dtype=np.int64),
        )
        for name, data in columns.items()
    }
    channels = _zero_noise(channels, where, index.get("force_n", 0) + 1)
    return Record(path=path, metadata=metadata, channels=channels, extra_columns=extra)


def _zero_noise(channels: dict[str, ChannelRecord], where: str, col: int | None) -> dict[str, ChannelRecord]:
    """The channels with every reference force below 0 N within the record's zero-noise
    tolerance read as 0 N and counted; the first one below it (in file order) is refused.
    ``col``: the force_n column of a CSV record; None for an MCAP record (``line`` holds
    message numbers)."""
    forces = {name: ch.force_n for name, ch in channels.items() if ch.force_n is not None}
    if not forces:
        return channels
    full_scale = max((float(f.max()) for f in forces.values() if f.size), default=0.0)
    tol = zero_noise_tolerance_n(full_scale)
    worst: tuple[int, float] | None = None
    for name, f in forces.items():
        bad = np.flatnonzero(f < -tol)
        line = int(channels[name].line[bad[0]]) if bad.size else 0
        if bad.size and (worst is None or line < worst[0]):
            worst = (line, float(f[bad[0]]))
    if worst is not None:
        at = (
            f"{where}:{worst[0]}: column {col} (force_n)"
            if col is not None
            else f"{where}: message {worst[0]}: force_n"
        )
        raise RecordError(
            f"{at}: {worst[1]!r} is below 0 N by more than the "
            f"load-cell zero-noise tolerance of {tol:.4g} N (the larger of {ZERO_NOISE_FLOOR_N:g} N and "
            f"{100 * ZERO_NOISE_SHARE:g} % of the record's largest reference force, {full_scale:.4g} N); "
            "a reference force must be >= 0"
        )
    out = dict(channels)
    for name, f in forces.items():
        negative = f < 0.0
        n = int(np.count_nonzero(negative))
        out[name] = replace(
            channels[name],
            force_n=np.where(negative, 0.0, f),
            zero_noise_rows=n,
            zero_noise_min_n=float(f[negative].min()) if n else 0.0,
            zero_noise_tolerance_n=tol,
        )
    return out


def _number(text: str, where: str, line: int, col: int, name: str) -> float:
    raw = text.strip()
    try:
        value = float(raw)
    except ValueError:
        raise RecordError(f"{where}:{line}: column {col} ({name}): {raw!r} is not a number") from None
    if math.isnan(value):
        raise RecordError(f"{where}:{line}: column {col} ({name}): NaN is not a value")
    return value


class RecordWriter:
    """The one writer of the record format: ``# key: value`` metadata, the header, then one
    row per sample per channel (long format), each value as the shortest text that reads
    back as the same double (``inf`` for an open circuit).

    ``has_force`` / ``has_temperature`` add the ``force_n`` (N) / ``temperature_c`` (degC)
    columns, ``extra_columns`` columns after them that a reader keeps as extra (``apply``'s
    ``force_tracked_n``, ``force_static_n``, ``status``): a number as the others, NaN (no
    value) as an empty field, a label as written. A metadata value is written on one line,
    its runs of white space (line breaks too) as one space. ``row`` writes one row; ``flush``
    passes the rows to the file, so a recording that is interrupted is a valid record of what
    was written before. A channel name that would not read back as itself
    (``channel_name_problem``) is a ``ValueError``: no field is quoted.
    """

    def __init__(
        self,
        out: TextIO,
        metadata: Mapping[str, str] | None = None,
        *,
        has_force: bool = False,
        has_temperature: bool = False,
        extra_columns: Sequence[str] = (),
    ) -> None:
        self.out = out
        self.has_force = has_force
        self.has_temperature = has_temperature
        self.extra_columns = tuple(extra_columns)
        self._channels_ok: set[str] = set()
        for key, value in (metadata or {}).items():
            out.write(f"# {key}: {' '.join(str(value).split())}\n")
        cols = ["time_s", "channel", "resistance_ohm"]
        cols += ["force_n"] if has_force else []
        cols += ["temperature_c"] if has_temperature else []
        clash = [c for c in self.extra_columns if c in KNOWN_COLUMNS or not _plain_label(c)]
        if clash or len(set(self.extra_columns)) != len(self.extra_columns):
            raise ValueError(
                f"extra columns {', '.join(map(repr, self.extra_columns))}: each must be new, once, "
                "and free of commas, quotes and line breaks"
            )
        out.write(",".join([*cols, *self.extra_columns]) + "\n")

    def row(
        self,
        time_s: float,
        channel: str,
        resistance_ohm: float,
        force_n: float | None = None,
        temperature_c: float | None = None,
        extra: Sequence[float | str] = (),
    ) -> None:
        """One sample of one channel; ``force_n`` / ``temperature_c`` when the record has
        them, ``extra`` one value per extra column."""
        if channel not in self._channels_ok:
            problem = channel_name_problem(channel)
            if problem is not None:
                raise ValueError(f"channel name {channel[:80]!r}: {problem}")
            self._channels_ok.add(channel)
        fields = [_fmt(time_s), channel, _fmt(resistance_ohm)]
        if self.has_force:
            if force_n is None:
                raise ValueError("this record has a force_n column: give force_n")
            fields.append(_fmt(force_n))
        if self.has_temperature:
            if temperature_c is None:
                raise ValueError("this record has a temperature_c column: give temperature_c")
            fields.append(_fmt(temperature_c))
        if len(extra) != len(self.extra_columns):
            raise ValueError(
                f"this record has {len(self.extra_columns)} extra columns "
                f"({', '.join(self.extra_columns) or 'none'}): give {len(self.extra_columns)} values, "
                f"got {len(extra)}"
            )
        fields += [_cell(value) for value in extra]
        self.out.write(",".join(fields) + "\n")

    def flush(self) -> None:
        self.out.flush()

    def close(self) -> None:
        """The last rows to the file (the file itself stays open: its owner commits it)."""
        self.out.flush()


def open_record_writer(
    out: AtomicFile,
    record_format: str,
    metadata: Mapping[str, str] | None = None,
    *,
    has_force: bool = False,
    has_temperature: bool = False,
    device_levels: int = 0,
) -> RecordWriter | McapRecordWriter:
    """The record writer of ``record_format`` (``RECORD_FORMATS``) into ``out``: both have
    ``row``, ``flush`` and ``close``; call ``close`` before ``out.commit()``. ``device_levels``:
    how many leading ``/`` parts of a channel label name its device (MCAP: a topic each)."""
    if record_format == "mcap":
        return McapRecordWriter(
            out, metadata, has_force=has_force, has_temperature=has_temperature, device_levels=device_levels
        )
    if record_format != "csv":
        raise ValueError(f"record format {record_format!r}: one of {', '.join(RECORD_FORMATS)}")
    return RecordWriter(out.text, metadata, has_force=has_force, has_temperature=has_temperature)


def format_record(
    metadata: Mapping[str, str],
    channels: Sequence[str],
    time_s: Iterable[float],
    resistance_ohm: Iterable[Sequence[float]],
    force_n: Iterable[Sequence[float]] | None = None,
    temperature_c: Iterable[Sequence[float]] | None = None,
) -> str:
    """Record text in long format from per-sample rows of per-channel values."""
    out = io.StringIO()
    writer = RecordWriter(
        out, metadata, has_force=force_n is not None, has_temperature=temperature_c is not None
    )
    forces = iter(force_n) if force_n is not None else None
    temps = iter(temperature_c) if temperature_c is not None else None
    for t, rs in zip(time_s, resistance_ohm, strict=True):
        fs = next(forces) if forces is not None else None
        ts = next(temps) if temps is not None else None
        for i, name in enumerate(channels):
            writer.row(
                float(t),
                name,
                float(rs[i]),
                None if fs is None else float(fs[i]),
                None if ts is None else float(ts[i]),
            )
    return out.getvalue()


def _fmt(value: float) -> str:
    v = float(value)
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(v)


def _plain_label(text: str) -> bool:
    """True when ``text`` stands in a CSV field as it is (no comma, quote or line break)."""
    return bool(text) and not any(c in text for c in ',"\r\n')


def _cell(value: float | str) -> str:
    """An extra column's field: a label as written, a number as ``_fmt``, NaN (no value) empty."""
    if isinstance(value, str):
        if value and not _plain_label(value):
            raise ValueError(f"{value!r}: a label in a record has no comma, quote or line break")
        return value
    return "" if math.isnan(value) else _fmt(value)


def write_record(path: str | os.PathLike[str], text: str) -> None:
    """Write record text atomically (a reader never sees half a file)."""
    atomic_write_text(Path(path), text)
