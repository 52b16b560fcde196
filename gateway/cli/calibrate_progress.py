"""Progress of a long ``calibrate`` (many channels, many records): channels and records done, and
the time left.

``tracker_for(progress, as_json)`` picks the form: nothing with ``--no-progress``; on a terminal
a bar on stderr (tqdm: channels done of those known, records done, elapsed and time left);
otherwise, or with ``--json``, one plain line on stderr per channel done. stdout never carries
progress, so ``--json`` output stays one JSON object. The time left is the mean time per channel
so far times the channels still to do (a record not yet read counts as many channels as the
records read so far had on average). A pool calls ``channel_done`` from its own thread: every
method holds a lock."""

from __future__ import annotations

import sys
import threading
import time
from typing import Any, TextIO

import click

__all__ = ["Bar", "Lines", "Quiet", "tracker_for"]


class Quiet:
    """No progress shown."""

    def __init__(self, records: int = 1) -> None:
        self.records = records
        self.records_read = 0
        self.records_done = 0
        self.channels = 0
        self.channels_done = 0
        self.start_s = time.monotonic()
        self._lock = threading.Lock()

    def add_record(self, record: str, channels: int) -> None:
        """A record read, with this many channels to fit."""
        with self._lock:
            self.records_read += 1
            self.channels += channels
            self._added()

    def channel_done(self, record: str, channel: str) -> None:
        """One channel's calibration done (or failed)."""
        with self._lock:
            self.channels_done += 1
            self._channel(record, channel)

    def record_done(self, record: str, ok: bool) -> None:
        """A record written (``ok``) or failed."""
        with self._lock:
            self.records_done += 1
            self._record()

    def close(self) -> None:
        """The run is over."""

    def left_s(self) -> float | None:
        """Seconds left at the pace so far (None before the first channel is done)."""
        if not self.channels_done:
            return None
        per_record = self.channels / max(self.records_read, 1)
        still = self.channels - self.channels_done + per_record * max(self.records - self.records_read, 0)
        return (time.monotonic() - self.start_s) / self.channels_done * still

    def _added(self) -> None:
        pass

    def _channel(self, record: str, channel: str) -> None:
        pass

    def _record(self) -> None:
        pass


class Lines(Quiet):
    """One line on ``out`` (stderr) per channel done."""

    def __init__(self, records: int = 1, out: TextIO | None = None) -> None:
        super().__init__(records)
        self.out = out

    def _channel(self, record: str, channel: str) -> None:
        left = self.left_s()
        click.echo(
            f"[{time.monotonic() - self.start_s:7.1f} s] {record} channel {channel!r} done: "
            f"{self.channels_done}/{self.channels} channels, {self.records_done}/{self.records} records"
            + ("" if left is None else f", about {_duration(left)} left"),
            file=self.out,
            err=self.out is None,
        )


class Bar(Quiet):
    """A tqdm bar of channels on ``out`` (stderr), with the records done after it."""

    def __init__(self, records: int = 1, out: TextIO | None = None) -> None:
        super().__init__(records)
        from tqdm import tqdm  # type: ignore[import-untyped]

        tqdm.monitor_interval = 0  # no monitor thread: a pool may fork after the bar starts
        self._bar: Any = tqdm(
            total=0, unit="channel", file=out or sys.stderr, dynamic_ncols=True, desc="calibrate"
        )
        self._postfix()

    def _postfix(self) -> None:
        self._bar.set_postfix_str(f"{self.records_done}/{self.records} records", refresh=True)

    def _added(self) -> None:
        self._bar.total = self.channels
        self._bar.refresh()

    def _channel(self, record: str, channel: str) -> None:
        self._bar.update(1)

    def _record(self) -> None:
        self._postfix()

    def close(self) -> None:
        with self._lock:
            self._bar.close()


def tracker_for(progress: bool | None, as_json: bool, records: int = 1) -> Quiet:
    """The progress form of a run of ``records`` records (module docstring)."""
    if progress is False:
        return Quiet(records)
    if sys.stderr.isatty() and not as_json:
        return Bar(records)
    return Lines(records)


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
