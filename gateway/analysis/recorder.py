"""Live measurement records: rows from the gateway's polls, flushed as they come.

Each good poll of a device adds one row per channel to a record in the format of
``docs/record-format.md``: the device clock (``time_s``, from the start of the
recording), the resistance the gateway read (``inf`` for an open contact), and the
reference force and temperature where the device provides them (a bench's load cell, or
the simulated array's bench registers). The header is written first and every poll's rows
are flushed, so an interrupted recording is a valid record of everything read so far.
"""

from __future__ import annotations

import io
import math
import os
import threading
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, TextIO, cast

from ..atomic import AtomicFile
from ..config import GatewayConfig
from ..runtime.snapshot import READING_STATUSES, ChannelStatus, DeviceSnapshot, GatewaySnapshot
from .mcap_records import McapRecordWriter, is_mcap_record
from .records import REQUIRED_COLUMNS, RecordWriter

#: the statuses whose row keeps its value: ok, no_contact, saturated, extrapolated, no_zero,
#: uncalibrated (a reading without a force: what ``calibrate`` needs)
_WITH_VALUE = {int(s) for s in READING_STATUSES}
_OPEN = int(ChannelStatus.OPEN)


@dataclass
class RecorderStats:
    polls: int = 0
    rows: int = 0
    skipped_rows: int = 0  # channels without a value in a good poll (short, error)
    read_errors: int = 0


class LiveRecorder:
    """Turns published snapshots into record rows (thread-safe; bus threads may publish).

    ``record_format`` ``csv`` writes text to ``out``; ``mcap`` (``mcap_records``) writes to
    ``out`` as an ``AtomicFile`` or a binary stream, one message per poll of a device, and
    needs ``close`` before the file is committed."""

    def __init__(
        self,
        out: TextIO | AtomicFile | BinaryIO,
        config: GatewayConfig,
        channels: Collection[str] | None = None,
        metadata: Mapping[str, str] | None = None,
        device: str | None = None,
        record_format: str = "csv",
    ) -> None:
        self.out = out
        self._device = device
        self.stats = RecorderStats()
        self._lock = threading.Lock()
        devices = [d for bus in config.buses for d in bus.devices if device is None or d.name == device]
        if not devices:
            raise ValueError(f"no device {device!r} in the configuration")
        self._multi = len(devices) > 1
        self._wanted = set(channels) if channels else None
        self._has_force = any(d.registers.force_reference_address is not None for d in devices)
        self._has_temp = any(d.registers.temperature_address is not None for d in devices)
        self._last: dict[str, float] = {}
        self._t0: dict[str, float] = {}
        self._errors: dict[str, int] = {}
        force, temp = self._has_force, self._has_temp
        self._writer: RecordWriter | McapRecordWriter
        if record_format == "mcap":
            binary = cast(AtomicFile | BinaryIO, out)
            self._writer = McapRecordWriter(
                binary, metadata, has_force=force, has_temperature=temp, device_levels=int(self._multi)
            )
        else:
            self._writer = RecordWriter(cast(TextIO, out), metadata, has_force=force, has_temperature=temp)
        self._writer.flush()

    def close(self) -> None:
        """The last rows to the file (an MCAP record's summary and index too)."""
        with self._lock:
            self._writer.close()

    def label(self, device: str, channel: str) -> str:
        return f"{device}/{channel}" if self._multi else channel

    def wanted(self, device: str, channel: str) -> bool:
        return self._wanted is None or channel in self._wanted or self.label(device, channel) in self._wanted

    def __call__(self, snapshot: GatewaySnapshot) -> None:
        with self._lock:
            self._take(snapshot)

    def _take(self, snapshot: GatewaySnapshot) -> None:
        rows = 0
        for name, counters in snapshot.counters.items():
            if self._device is not None and name != self._device:
                continue
            errors = sum(counters.read_errors_total.values())
            self.stats.read_errors += errors - self._errors.get(name, 0)
            self._errors[name] = errors
        for name, dev in snapshot.devices.items():
            if self._device is not None and name != self._device:
                continue
            if not dev.up or dev.last_success_timestamp_s is None:
                continue
            clock = dev.device_time_s if dev.device_time_s is not None else dev.last_success_timestamp_s
            if self._last.get(name) == dev.last_success_timestamp_s:
                continue  # this device was not polled again since the last rows
            self._last[name] = dev.last_success_timestamp_s
            t0 = self._t0.setdefault(name, clock)
            self.stats.polls += 1
            for k, channel in enumerate(dev.channel_names):
                if not self.wanted(name, channel):
                    continue
                status = int(dev.status[k])
                r = float(dev.resistance_ohm[k])
                if status == _OPEN or (status in _WITH_VALUE and not math.isfinite(r)):
                    r = math.inf  # an open circuit (the contact is open at rest)
                elif status not in _WITH_VALUE or not (math.isfinite(r) and r > 0.0):
                    self.stats.skipped_rows += 1
                    continue
                force = max(float(dev.reference_force_n[k]), 0.0) if self._has_force else None
                temps = dev.temperature_c
                temp = (float(temps[k]) if temps is not None else math.nan) if self._has_temp else None
                if (force is not None and not math.isfinite(force)) or (
                    temp is not None and not math.isfinite(temp)
                ):
                    self.stats.skipped_rows += 1
                    continue
                # microsecond resolution: the device clock counts milliseconds
                self._writer.row(round(clock - t0, 6), self.label(name, channel), r, force, temp)
                rows += 1
        if rows:
            self._writer.flush()
            self.stats.rows += rows


def export_record(
    config: GatewayConfig,
    device: str,
    snapshots: Sequence[DeviceSnapshot],
    metadata: Mapping[str, str] | None = None,
) -> str:
    """The record (CSV text, ``docs/record-format.md``) of ``device``'s polls ``snapshots``
    (oldest first), row for row what ``record`` writes of them (``LiveRecorder``): the page's
    export (``/api/devices/{name}/export.csv``). ``time_s`` counts from the first poll."""
    out = io.StringIO()
    recorder = LiveRecorder(out, config, metadata=metadata, device=device)
    for seq, snap in enumerate(snapshots, start=1):
        recorder(GatewaySnapshot.build({device: snap}, {}, seq))
    recorder.close()
    return out.getvalue()


#: How much of an existing file ``is_record_file`` reads to find the header row.
_HEAD_BYTES = 64 * 1024


def is_record_file(path: Path) -> bool:
    """True if ``path`` is a regular file in the record format: ``#`` metadata lines (or
    none), then a header row naming ``time_s`` and ``resistance_ohm``; or an MCAP record this
    project wrote. Reads its first 64 kB."""
    try:
        if not path.is_file():
            return False
        with path.open("rb") as fh:
            raw = fh.read(_HEAD_BYTES)
    except OSError:
        return False
    if is_mcap_record(raw):
        return True
    head = raw.decode("utf-8-sig", errors="replace")
    lines = head.splitlines()
    if len(head) == _HEAD_BYTES and lines:
        lines.pop()  # maybe cut short
    for line in lines:
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        columns = {c.strip() for c in stripped.split(",")}
        return all(name in columns for name in REQUIRED_COLUMNS)
    return False


def record_path_ok(path: Path, force: bool = False, replace_record: bool = False) -> None:
    """Refuse to overwrite a directory, an existing file (unless ``force``; with
    ``replace_record`` an existing record is replaced, another kind of file still needs
    ``force``) or to write into a missing or read-only folder (clear messages)."""
    if path.is_dir():
        raise ValueError(f"{path} is a directory")
    if not path.parent.exists():
        raise ValueError(f"directory {path.parent} does not exist")
    if path.exists() and not force:
        if not replace_record:
            raise ValueError(f"{path} exists; refusing to overwrite it (use --force to replace it)")
        if not is_record_file(path):
            raise ValueError(
                f"{path} exists and is not a record (no time_s,resistance_ohm header, not an MCAP record; "
                "it could be your configuration or other data); refusing to replace it: choose another "
                "file, or --force"
            )
    if not os.access(path.parent, os.W_OK):
        raise ValueError(f"directory {path.parent} is not writable")
