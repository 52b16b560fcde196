"""``tactile-gateway calibrate`` over many records: one calibration file per record (array or
session), and a summary table (``summary.csv``, ``summary.json``) in the ``--out`` folder.

A record that fails (unreadable, too short, a fit that does not converge) is one ``failed`` line
of the summary with its error; the other records go on."""

from __future__ import annotations

import csv
import glob
import io
import json
from collections.abc import Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from ..analysis.calibration import Calibration, write_calibration
from ..analysis.calibration_writer import written_name
from ..analysis.channel_work import FitSettings
from ..analysis.records import DEFAULT_CHANNEL, ChannelRecord, Record, read_record
from ..atomic import atomic_write_text
from ..errors import RecordError
from ..model import ParameterError
from .calibrate_pool import Pool, Tracker, submit_channels

EXIT_ALL_OK = 0
EXIT_SOME_FAILED = 1

SUMMARY_FIELDS = (
    "record",
    "status",
    "channel",
    "written",
    "model",
    "written_model",
    "best",
    "held_out_force_rms_n",
    "drift_after_higher_pct_fs",
    "drift_others_pct_fs",
    "verdict",
    "error",
)

_GLOB_CHARS = frozenset("*?[")
#: The files of a folder taken as records (a README beside them is not one).
RECORD_SUFFIXES = (".csv", ".mcap")


def batch_records(args: Sequence[Path]) -> list[Path] | None:
    """The records of a batch run, or None for the single-record command (no argument, or one
    that is neither a folder nor a glob pattern). A folder gives its ``.csv`` and ``.mcap`` files
    (sorted, hidden ones left out); a pattern no shell expanded (quoted) is expanded here."""
    if not args or (len(args) == 1 and not args[0].is_dir() and not _is_pattern(args[0])):
        return None
    records: list[Path] = []
    for arg in args:
        if arg.is_dir():
            records += sorted(
                p
                for p in arg.iterdir()
                if p.is_file() and p.suffix.lower() in RECORD_SUFFIXES and not p.name.startswith(".")
            )
        elif _is_pattern(arg):
            found = sorted(Path(p) for p in glob.glob(str(arg)) if Path(p).is_file())
            if not found:
                raise click.UsageError(f"no record matches {str(arg)!r}")
            records += found
        else:
            records.append(arg)
    if not records:
        raise click.UsageError(f"no record in {', '.join(str(a) for a in args)}")
    stems: dict[str, Path] = {}
    for rec in records:
        if rec.stem in stems and stems[rec.stem] != rec:
            raise click.UsageError(
                f"{stems[rec.stem]} and {rec} would both be written as {rec.stem}.toml: "
                "calibrate them in separate runs (or rename one)"
            )
        stems[rec.stem] = rec
    return records


def _is_pattern(path: Path) -> bool:
    return not path.exists() and bool(_GLOB_CHARS & set(str(path)))


def check_out_dir(out_dir: Path | None) -> Path:
    """The ``--out`` of a batch: an existing folder, or a new one in an existing folder."""
    if out_dir is None:
        raise click.UsageError(
            "several records need --out DIR: the folder for one calibration per record and the summary"
        )
    if out_dir.exists() and not out_dir.is_dir():
        raise click.UsageError(
            f"--out: {out_dir} is a file; several records need --out DIR, a folder for one calibration "
            "per record and the summary"
        )
    if not out_dir.parent.is_dir():
        raise click.UsageError(f"--out: directory {out_dir.parent} does not exist")
    out_dir.mkdir(exist_ok=True)
    return out_dir


def run_batch(
    records: list[Path],
    out_dir: Path,
    pool: Pool,
    settings: FitSettings,
    channel_names: tuple[str, ...],
    as_name: str | None,
    model: str,
    as_json: bool,
    tracker: Tracker,
) -> int:
    """Calibrate each record into ``out_dir/<record stem>.toml``, write the summary; the exit
    status: 0 when every record was calibrated, 1 when any failed.

    Every channel of every record is a task of ``pool`` (``calibrate_pool``): records are read
    here one after another while the pool works, at most about two tasks a worker ahead (a
    thousand records are never all in memory), and each record is written as soon as its last
    channel is done."""
    rows: dict[int, list[dict[str, Any]]] = {}
    waiting: list[_Pending] = []

    def fail(k: int, rec: Path, exc: BaseException) -> None:
        message = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, OSError):
            message = f"cannot read or write: {exc.strerror or exc}"
        rows[k] = [{"record": str(rec), "status": "failed", "error": message}]
        tracker.record_done(str(rec), ok=False)
        if not as_json:
            click.echo(f"{rec}: failed: {message}", err=True)

    def finish(work: _Pending) -> None:
        try:
            results = [f.result() for f in work.futures]
            write_calibration(work.target, results, model, work.rename)
        except Exception as exc:  # a channel's fit or the file: this record fails, the others go on
            fail(work.index, work.path, exc)
            return
        rows[work.index] = [_row(work.path, work.target, cal, model, as_name) for cal in results]
        tracker.record_done(str(work.path), ok=True)
        if not as_json:
            click.echo(f"{work.path}: ok, wrote {work.target}", err=True)

    def harvest(block: bool) -> None:
        while waiting:
            busy = [f for w in waiting for f in w.futures if not f.done()]
            if block and len(busy) > 2 * pool.jobs:
                wait(busy, return_when=FIRST_COMPLETED)
                continue
            for work in [w for w in waiting if all(f.done() for f in w.futures)]:
                waiting.remove(work)
                finish(work)
            return

    for k, rec in enumerate(records):
        try:
            record, channels, rename = _prepare(rec, channel_names, as_name)
        except (RecordError, ParameterError, ValueError, OSError) as exc:
            fail(k, rec, exc)
            continue
        futures = submit_channels(pool, settings, channels, str(rec), record.metadata, tracker)
        waiting.append(_Pending(k, rec, out_dir / f"{rec.stem}.toml", rename, futures))
        harvest(block=True)
    for work in list(waiting):
        wait(work.futures)
        waiting.remove(work)
        finish(work)
    ordered = [row for k in sorted(rows) for row in rows[k]]
    failed = sum(1 for r in ordered if r["status"] == "failed")
    summary = {
        "records": len(records),
        "ok": len(records) - failed,
        "failed": failed,
        "out": str(out_dir),
        "rows": ordered,
    }
    atomic_write_text(out_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    atomic_write_text(out_dir / "summary.csv", _csv(ordered))
    if as_json:
        click.echo(json.dumps(summary))
    else:
        click.echo(
            f"{summary['ok']} of {len(records)} records calibrated, {failed} failed; "
            f"wrote {out_dir / 'summary.csv'} and {out_dir / 'summary.json'}"
        )
    return EXIT_SOME_FAILED if failed else EXIT_ALL_OK


@dataclass
class _Pending:
    """A record whose channels are with the pool."""

    index: int
    path: Path
    target: Path
    rename: dict[str, str]
    futures: list[Future[Calibration]]


def _prepare(
    rec: Path, channel_names: tuple[str, ...], as_name: str | None
) -> tuple[Record, list[ChannelRecord], dict[str, str]]:
    record = read_record(rec, require_force=True)
    names = list(channel_names) or list(record.channels)
    channels = [record.channel(n) for n in names]
    rename: dict[str, str] = {}
    if as_name is not None:
        if len(channels) != 1:
            raise ValueError(f"--as names one channel; this record has {len(channels)} (use --channel)")
        rename[channels[0].name] = as_name
    elif any(c.name == DEFAULT_CHANNEL for c in channels):
        raise ValueError(
            f"the record has no channel column, so its channel is named {DEFAULT_CHANNEL!r}; give --as NAME, "
            "the device channel name to write"
        )
    return record, channels, rename


def _row(rec: Path, target: Path, cal: Calibration, model: str, as_name: str | None) -> dict[str, Any]:
    d = cal.as_dict()
    drift = d["drift_reference_pct_fs"]
    kept = written_name(cal, model)
    return {
        "record": str(rec),
        "status": "ok",
        "channel": as_name or cal.channel,
        "written": str(target),
        "model": model,
        "written_model": kept,
        "best": d["best"],
        "held_out_force_rms_n": cal.force_rms().get(kept),
        "drift_after_higher_pct_fs": drift["after_higher"],
        "drift_others_pct_fs": drift["others"],
        "verdict": d["verdict"],
        "error": "",
    }


def _csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=SUMMARY_FIELDS, restval="", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row.get(k) is None else row.get(k, "") for k in SUMMARY_FIELDS})
    return buf.getvalue()
