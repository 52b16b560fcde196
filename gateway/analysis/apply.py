"""A calibration file applied to a recorded file by the runtime's own tracker.

``apply_calibration(calibration, record)`` reads a record (``docs/record-format.md``) as the
gateway would have read it live with the calibration in its device configuration:

* **The device.** ``config.calibration_file.calibrated_device``: a float32 (ohm) device whose
  channels are the record's, each named after its calibration table (the same name unless
  mapped), with parameters, effects (``[meta] effects``; a file without them: the paper's),
  baselines and line / lookup / curve tables from the calibration exactly as
  ``[[bus.device]] calibration = "..."`` gives them to the live gateway.
* **The tracker.** ``runtime.replay.replay``: ``runtime.processor.DeviceProcessor.process``,
  each channel at its own rows, its creep state stepped by its recorded time step (the
  record's ``time_s``). Rows of equal ``time_s`` across channels are one device sample (the
  count reported). A channel's state does not move between its rows but by relaxing with its
  held force, exact for a constant held force, so each channel reads what it would read
  sampled alone (``runtime.replay`` says why). ``inf`` (no current) reads no contact, 0 N, as
  the gateway reads a rail of a device with fault bitmaps; a record cannot tell a broken lead
  from a contact open at rest.

Hold statistics (``channel_errors``): the RMS error of the tracked and of the static force
against the reference, overall and, for each hold of the reference, the one per-hold measure
``calibrate`` ranks by (``holds.hold_drifts``): the mean error over the first and last 10 % of
its settled rows, whether it comes right after a higher load, and the drift (end minus start)
summed up in those two groups (``holds.drift_groups_pct``, % of the channel's full scale).
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..config.calibration_file import (
    calibrated_device,
    calibration_channels,
    calibration_effects,
    load_calibration,
)
from ..config.schema import ChannelConfig
from ..errors import GatewayError
from ..runtime.processor import DeviceProcessor
from ..runtime.replay import ChannelSeries, ReplayedChannel, replay
from ..runtime.snapshot import STATUS_LABELS, ChannelStatus
from .holds import EDGE_FRACTION, MIN_HOLD_S, DriftGroups, Hold, drift_groups_pct, find_holds, hold_drifts
from .records import ChannelRecord, Record, RecordWriter, names_text, write_record

__all__ = [
    "APPLIED_COLUMNS",
    "Applied",
    "AppliedChannel",
    "ApplyError",
    "ChannelErrors",
    "ErrorSummary",
    "HoldError",
    "applied_record_text",
    "apply_calibration",
    "apply_report",
    "calibration_processor",
    "channel_errors",
    "channel_mapping",
    "format_apply_report",
    "overall_errors",
    "replay_record",
    "write_applied",
]

FloatArray = NDArray[np.float64]

#: The columns ``applied_record_text`` adds to the record's (empty: no value, see ``status``).
APPLIED_COLUMNS = ("force_tracked_n", "force_static_n", "status")


class ApplyError(GatewayError):
    """A record's channels and a calibration's do not fit together (the message lists both)."""


@dataclass(frozen=True, eq=False)
class AppliedChannel:
    """One record channel read with its calibration table: the record's rows (in file order)
    and, per row, the runtime's drift-corrected force, the static estimate (N; NaN where the
    status carries no force) and the ``ChannelStatus`` code."""

    name: str
    calibration_channel: str
    model: str  # "physics", "line", "lookup" or "curve ..." (what reads the channel's force)
    record: ChannelRecord
    force_tracked_n: FloatArray
    force_static_n: FloatArray
    status: NDArray[np.int8]

    def status_counts(self) -> dict[str, int]:
        counts = np.bincount(self.status.astype(np.int64), minlength=len(ChannelStatus))
        return {s.label: int(counts[s]) for s in ChannelStatus if counts[s]}


@dataclass(frozen=True, eq=False)
class Applied:
    """A calibration applied to a record: every channel read, in the record's order."""

    record: Record
    calibration: Path
    channels: tuple[AppliedChannel, ...]
    effects: tuple[str, ...]  # the physical model's effects (the calibration's, as the gateway's)
    fitted_effects: tuple[str, ...] | None  # the calibration's [meta] effects, if it says
    device_samples: int
    #: the record is the one the calibration was fitted on (its [meta] record): its errors are
    #: fit errors, not a test on new data
    in_sample: bool = False

    @property
    def n_rows(self) -> int:
        return sum(c.record.n_samples for c in self.channels)

    def channel(self, name: str) -> AppliedChannel:
        for c in self.channels:
            if c.name == name:
                return c
        raise KeyError(name)


def _listing(names: Sequence[str]) -> str:
    return names_text(names)


def channel_mapping(
    record_channels: Sequence[str],
    calibration_channels: Sequence[str],
    selected: Sequence[str] = (),
    rename: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """Record channel -> calibration channel, for ``selected`` record channels (default: all),
    each by its own name unless ``rename`` maps it. ``ApplyError`` names both lists."""
    rename = dict(rename or {})
    both = (
        f"(record channels: {_listing(record_channels)}; calibration channels: "
        f"{_listing(calibration_channels)})"
    )
    for name in [*selected, *rename]:
        if name not in record_channels:
            raise ApplyError(f"no channel {name!r} in the record {both}")
    chosen = list(dict.fromkeys(selected)) or list(record_channels)
    for name, target in rename.items():
        if name not in chosen:
            raise ApplyError(f"{name!r} is mapped but not among the channels chosen ({names_text(chosen)})")
        if target not in calibration_channels:
            raise ApplyError(f"{name!r} is mapped to {target!r}, which has no calibration table {both}")
    mapping = {name: rename.get(name, name) for name in chosen}
    missing = [name for name, target in mapping.items() if target not in calibration_channels]
    if missing:
        shown = names_text(repr(m) for m in missing)
        several = len(missing) > 1
        raise ApplyError(
            f"record channel{'s' if several else ''} {shown} {'have' if several else 'has'} no calibration "
            f"table {both}; map a record channel to a table (RECORD_CH=CAL_CH)"
        )
    targets: dict[str, str] = {}
    for name, target in mapping.items():
        if target in targets:
            raise ApplyError(
                f"record channels {targets[target]!r} and {name!r} both map to calibration channel "
                f"{target!r}; one table reads one channel"
            )
        targets[target] = name
    return mapping


def _model_label(channel: ChannelConfig) -> str:
    conversion = channel.conversion
    if conversion is None:
        return "physics"
    if conversion.table_kind != "curve":
        return conversion.table_kind
    return f"curve ({conversion.describe()})"


def calibration_processor(calibration: Path, mapping: Mapping[str, str]) -> DeviceProcessor:
    """The runtime's processor of a device whose enabled channels are ``mapping``'s calibration
    channels, in its order (``ConfigError`` for a calibration the gateway would refuse)."""
    known = calibration_channels(calibration)
    targets = list(mapping.values())
    device = calibrated_device(calibration, targets, others=known)
    return DeviceProcessor(device, bus="record", poll_interval_s=1.0)


def replay_record(
    processor: DeviceProcessor, channels: Sequence[ChannelRecord]
) -> tuple[tuple[ReplayedChannel, ...], int]:
    """``runtime.replay.replay`` of record channels (the processor's enabled channels, in its
    order): what the runtime read at each row, and the number of device samples."""
    series = [ChannelSeries(c.time_s, c.resistance_ohm, c.force_n, c.temperature_c) for c in channels]
    return replay(processor, series)


def apply_calibration(
    calibration: Path,
    record: Record,
    channels: Sequence[str] = (),
    rename: Mapping[str, str] | None = None,
) -> Applied:
    """Read ``record`` (its ``channels``, default all) with ``calibration`` through the
    runtime's tracker; ``rename`` maps record channels to calibration channels.

    ``ConfigError`` for a calibration the gateway would refuse, ``ApplyError`` when a record
    channel has no calibration table."""
    known = calibration_channels(calibration)
    mapping = channel_mapping(list(record.channels), known, channels, rename)
    processor = calibration_processor(calibration, mapping)
    chans = [record.channels[name] for name in mapping]
    results, n_samples = replay_record(processor, chans)
    applied = tuple(
        AppliedChannel(name, target, _model_label(cfg), ch, out.force_n, out.force_static_n, out.status)
        for (name, target), cfg, ch, out in zip(
            mapping.items(), processor.channels, chans, results, strict=True
        )
    )
    effects = tuple(processor.channels[0].effects) if processor.channels else ()
    return Applied(
        record,
        calibration,
        applied,
        effects,
        calibration_effects(calibration),
        n_samples,
        _same_file(load_calibration(calibration).record, calibration, record.path),
    )


def _same_file(fitted_on: str | None, calibration: Path, record_path: Path | None) -> bool:
    """Whether ``fitted_on`` (a calibration's [meta] record, as typed to ``calibrate``: absolute,
    or relative to where it ran, often the calibration's folder) is the file at ``record_path``."""
    if fitted_on is None or record_path is None or not record_path.is_file():
        return False
    named = Path(fitted_on)
    candidates = [named] if named.is_absolute() else [named, calibration.parent / named]
    for candidate in candidates:
        try:
            if candidate.is_file() and candidate.samefile(record_path):
                return True
        except OSError:
            continue
    return False


# ------------------------------------------------------------------------------ the record
def applied_record_text(applied: Applied, metadata: Mapping[str, str] | None = None) -> str:
    """The record with ``APPLIED_COLUMNS`` added, rows in the record's order (by source line):
    ``time_s, channel, resistance_ohm[, force_n][, temperature_c], force_tracked_n,
    force_static_n, status``; a force with no value (status ``error``, ``open``, ...) is empty.
    Written by the records' one writer (``records.RecordWriter``)."""
    chans = applied.channels
    has_force = bool(chans) and all(c.record.force_n is not None for c in chans)
    has_temp = bool(chans) and all(c.record.temperature_c is not None for c in chans)
    out = io.StringIO()
    meta = {**applied.record.metadata, **(metadata or {})}
    writer = RecordWriter(
        out, meta, has_force=has_force, has_temperature=has_temp, extra_columns=APPLIED_COLUMNS
    )
    lines = np.concatenate([c.record.line for c in chans]) if chans else np.zeros(0, dtype=np.int64)
    owner = np.concatenate([np.full(c.record.n_samples, j) for j, c in enumerate(chans)]) if chans else lines
    index = np.concatenate([np.arange(c.record.n_samples) for c in chans]) if chans else lines
    for pos in np.argsort(lines, kind="stable").tolist():
        ch = chans[int(owner[pos])]
        i = int(index[pos])
        rec = ch.record
        writer.row(
            rec.time_s[i],
            ch.name,
            rec.resistance_ohm[i],
            rec.force_n[i] if has_force and rec.force_n is not None else None,
            rec.temperature_c[i] if has_temp and rec.temperature_c is not None else None,
            (ch.force_tracked_n[i], ch.force_static_n[i], STATUS_LABELS[int(ch.status[i])]),
        )
    return out.getvalue()


def write_applied(path: Path, applied: Applied, metadata: Mapping[str, str] | None = None) -> None:
    """Write ``applied_record_text`` atomically (``records.write_record``)."""
    write_record(path, applied_record_text(applied, metadata))


# ------------------------------------------------------------------------------ the errors
@dataclass(frozen=True)
class ErrorSummary:
    """RMS force errors against the reference (N) over ``rows`` rows with a value, and the
    full scale they are a percentage of (the largest reference force, N)."""

    rows: int
    full_scale_n: float
    tracked_rms_n: float
    static_rms_n: float

    def pct(self, value_n: float) -> float:
        return 100.0 * value_n / self.full_scale_n if self.full_scale_n > 0 else math.nan

    def as_dict(self) -> dict[str, Any]:
        return {
            "rows": self.rows,
            "full_scale_n": self.full_scale_n,
            "tracked": {"rms_n": _num(self.tracked_rms_n), "rms_pct_fs": _num(self.pct(self.tracked_rms_n))},
            "static": {"rms_n": _num(self.static_rms_n), "rms_pct_fs": _num(self.pct(self.static_rms_n))},
        }


@dataclass(frozen=True)
class HoldError:
    """One hold of the reference force (its settled rows) and the mean force error (force -
    reference, N) over its first and last ``EDGE_FRACTION`` of rows (``edge_rows`` each),
    tracked and static; ``after_higher``: it comes right after a higher load."""

    hold: Hold
    edge_rows: int
    tracked_start_n: float
    tracked_end_n: float
    static_start_n: float
    static_end_n: float
    after_higher: bool = False

    def as_dict(self) -> dict[str, Any]:
        h = self.hold
        return {
            "after_higher_load": self.after_higher,
            "start_s": h.start_s,
            "end_s": h.end_s,
            "level_n": h.level_n,
            "rows": h.n_rows,
            "edge_rows": self.edge_rows,
            "tracked": {"start_error_n": _num(self.tracked_start_n), "end_error_n": _num(self.tracked_end_n)},
            "static": {"start_error_n": _num(self.static_start_n), "end_error_n": _num(self.static_end_n)},
        }


@dataclass(frozen=True)
class ChannelErrors:
    """A channel's errors: overall, per hold, and the hold drift in its two groups (% FS)."""

    channel: str
    overall: ErrorSummary
    holds: tuple[HoldError, ...]
    drift_tracked: DriftGroups | None = None
    drift_static: DriftGroups | None = None


def _num(value: float) -> float | None:
    """JSON has no NaN: None."""
    return float(value) if math.isfinite(value) else None


def _rms(err: FloatArray) -> float:
    return float(np.sqrt(np.mean(err * err))) if err.size else math.nan


def _mean(values: FloatArray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else math.nan


def _summary(tracked: FloatArray, static: FloatArray, reference: FloatArray) -> ErrorSummary:
    ok = np.isfinite(tracked) & np.isfinite(static) & np.isfinite(reference)
    full_scale = float(reference.max()) if reference.size else math.nan
    return ErrorSummary(
        int(np.count_nonzero(ok)),
        full_scale,
        _rms(tracked[ok] - reference[ok]),
        _rms(static[ok] - reference[ok]),
    )


def channel_errors(
    channel: AppliedChannel,
    tolerance_n: float | None = None,
    min_hold_s: float = MIN_HOLD_S,
) -> ChannelErrors | None:
    """The channel's RMS errors (rows where both forces have a value) and its holds' start and
    end errors and drift groups (``holds.hold_drifts``); None without a reference force."""
    rec = channel.record
    if rec.force_n is None:
        return None
    ref = rec.force_n
    found = find_holds(rec.time_s, ref, tolerance_n, min_hold_s)
    tracked = hold_drifts(rec.time_s, ref, channel.force_tracked_n, None, found, tolerance_n)
    static = hold_drifts(rec.time_s, ref, channel.force_static_n, None, found, tolerance_n)
    holds = tuple(
        HoldError(
            t.hold, t.hold.edge_rows(EDGE_FRACTION), t.start_error_n, t.end_error_n, s.start_error_n,
            s.end_error_n, t.after_higher,
        )
        for t, s in zip(tracked, static, strict=True)
    )  # fmt: skip
    summary = _summary(channel.force_tracked_n, channel.force_static_n, ref)
    full = summary.full_scale_n
    return ChannelErrors(
        channel.name, summary, holds, drift_groups_pct(tracked, full), drift_groups_pct(static, full)
    )


def overall_errors(applied: Applied) -> ErrorSummary | None:
    """The RMS errors over every channel's rows (full scale: the largest reference force of
    all); None when the record has no reference force."""
    chans = applied.channels
    if not chans or any(c.record.force_n is None for c in chans):
        return None
    return _summary(
        np.concatenate([c.force_tracked_n for c in chans]),
        np.concatenate([c.force_static_n for c in chans]),
        np.concatenate([c.record.force_n for c in chans if c.record.force_n is not None]),
    )


def apply_report(applied: Applied, errors: Sequence[ChannelErrors | None]) -> dict[str, Any]:
    """The numbers of ``format_apply_report`` as one JSON-ready object."""
    overall = overall_errors(applied)
    return {
        "record": str(applied.record.path) if applied.record.path else None,
        "calibration": str(applied.calibration),
        "effects": list(applied.effects),
        "fitted_effects": None if applied.fitted_effects is None else list(applied.fitted_effects),
        "rows": applied.n_rows,
        "device_samples": applied.device_samples,
        "reference": overall is not None,
        "in_sample": applied.in_sample,
        "channels": [
            {
                "channel": ch.name,
                "calibration_channel": ch.calibration_channel,
                "model": ch.model,
                "rows": ch.record.n_samples,
                "status": ch.status_counts(),
                "errors": None if err is None else err.overall.as_dict(),
                "holds": [] if err is None else [h.as_dict() for h in err.holds],
                "hold_drift_pct_fs": None if err is None else _drift_dict(err),
            }
            for ch, err in zip(applied.channels, errors, strict=True)
        ],
        "overall": None if overall is None else overall.as_dict(),
    }


def _drift_dict(err: ChannelErrors) -> dict[str, Any]:
    """The hold drift groups (% FS) of the tracked and the static force."""
    out: dict[str, Any] = {}
    for name, groups in (("tracked", err.drift_tracked), ("static", err.drift_static)):
        if groups is not None:
            out[name] = {
                "after_higher_load": _num(groups.after_higher_pct_fs),
                "others": _num(groups.others_pct_fs),
                "holds": {"after_higher_load": groups.after_higher_holds, "others": groups.other_holds},
            }
    return out


def _n(value: float, spec: str = ".4f") -> str:
    """``value`` as ``spec`` says ("-" for none), never "-0.0000" for a tiny negative."""
    if not math.isfinite(value):
        return "-"
    if spec.endswith("f"):
        value = round(value, int(spec.rstrip("f").split(".")[-1])) + 0.0
    return format(value, spec)


def _rms_cell(summary: ErrorSummary, value: float) -> str:
    return f"{_n(value)} ({_n(summary.pct(value), '.2f')} %)"


def format_apply_report(applied: Applied, errors: Sequence[ChannelErrors | None]) -> str:
    """What ``apply`` prints: the channels read, the RMS errors and the holds' errors."""
    src = applied.record.path or "<record>"
    lines = [
        f"applied {applied.calibration} to {src}: {len(applied.channels)} channel(s), {applied.n_rows} rows, "
        f"{applied.device_samples} device samples; physical model: {', '.join(applied.effects)}"
    ]
    if applied.in_sample:
        lines.append(
            "note: in-sample: this is the record the calibration was fitted on ([meta] record), so "
            "the errors below are fit errors, not a test; apply it to another record for held-out ones"
        )
    fitted = applied.fitted_effects
    by_model = any(c.model == "physics" for c in applied.channels)
    if by_model and fitted is not None and set(fitted) != set(applied.effects):
        lines.append(
            f"note: the calibration was fitted with {', '.join(fitted)}; its first channel has no "
            f"[channel] table, so it is read with the paper's effects ({', '.join(applied.effects)})"
        )
    for ch in applied.channels:
        zero_noise = ch.record.zero_noise_note()
        if zero_noise:
            lines.append(f"note: {zero_noise}")
    for ch in applied.channels:
        counts = ", ".join(f"{k} {v}" for k, v in ch.status_counts().items())
        lines.append(f"  {ch.name} <- [{ch.calibration_channel}] read by {ch.model}: {counts}")
    overall = overall_errors(applied)
    if overall is None:
        lines.append("the record has no reference force (force_n): no errors to report")
        return "\n".join(lines) + "\n"
    rows = [("channel", "rows", "full scale N", "tracked RMS N (% FS)", "static RMS N (% FS)")]
    for err in errors:
        if err is not None:
            s = err.overall
            rows.append(
                (err.channel, str(s.rows), _n(s.full_scale_n, ".4g"),
                 _rms_cell(s, s.tracked_rms_n), _rms_cell(s, s.static_rms_n))
            )  # fmt: skip
    if len(applied.channels) > 1:
        s = overall
        rows.append(
            ("all", str(s.rows), _n(s.full_scale_n, ".4g"), _rms_cell(s, s.tracked_rms_n),
             _rms_cell(s, s.static_rms_n))
        )  # fmt: skip
    lines += ["", "force error against the reference (full scale: the largest reference force):"]
    lines += _table(rows)
    holds = [(err.channel, h) for err in errors if err is not None for h in err.holds]
    lines.append("")
    if not holds:
        lines.append(f"no hold (a reference level > 0 held for at least {MIN_HOLD_S:g} s)")
        return "\n".join(lines) + "\n"
    lines.append(
        f"holds: mean error (force - reference, N) over the first and the last {100 * EDGE_FRACTION:g} % "
        "of each hold's settled rows (at least one); after: right after a higher load"
    )
    table = [
        ("channel", "start s", "end s", "level N", "rows", "after", "tracked start", "tracked end",
         "static start", "static end")
    ]  # fmt: skip
    for name, h in holds:
        table.append(
            (name, _n(h.hold.start_s, ".2f"), _n(h.hold.end_s, ".2f"), _n(h.hold.level_n, ".4g"),
             str(h.hold.n_rows), "yes" if h.after_higher else "", _n(h.tracked_start_n, "+.4f"),
             _n(h.tracked_end_n, "+.4f"), _n(h.static_start_n, "+.4f"), _n(h.static_end_n, "+.4f"))
        )  # fmt: skip
    lines += _table(table)
    lines += ["", "hold drift (end minus start error, RMS over holds, % of full scale), as calibrate ranks:"]
    for err in errors:
        if err is None or err.drift_tracked is None or err.drift_static is None:
            continue
        tr, st = err.drift_tracked, err.drift_static
        lines.append(
            f"  {err.channel}: after a higher load ({tr.after_higher_holds} holds) tracked "
            f"{_n(tr.after_higher_pct_fs, '.2f')}, static {_n(st.after_higher_pct_fs, '.2f')}; "
            f"others ({tr.other_holds} holds) tracked {_n(tr.others_pct_fs, '.2f')}, static "
            f"{_n(st.others_pct_fs, '.2f')}"
        )
    return "\n".join(lines) + "\n"


def _table(rows: Sequence[Sequence[str]]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip() for r in rows]
