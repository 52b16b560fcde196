"""The calibration file of a calibration: one ``[channel]`` table per channel and, for a channel
written with a line, a lookup or a curve, that channel's table, exactly as it was scored.

The tables' bodies are the form's own (``gateway.model.calibrated.CurveChannel.table``); the
file's format is ``gateway.config.calibration_format``'s.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from ..atomic import atomic_write_text
from ..config.calibration_file import CalibrationFile, ChannelCalibration, ConversionTable
from ..keys import choice_of
from ..model import parameter_names
from .calibration_range import model_force_range
from .calibration_result import OBJECTIVE_WORDS, Calibration, CalibrationModel

__all__ = [
    "HEADER",
    "calibration_file",
    "calibration_toml",
    "drift_words",
    "write_calibration",
    "written_name",
]


def written_name(cal: Calibration, model: CalibrationModel | str) -> str:
    """The calibration ``model`` writes for ``cal``: ``auto`` the best writable one
    (``Calibration.best``), ``curve`` the best writable curve (any curve if none is writable)."""
    model = CalibrationModel(model)
    if model == CalibrationModel.AUTO:
        return cal.best
    if model == CalibrationModel.CURVE:
        if not cal.candidates:
            raise ValueError(f"channel {cal.channel!r}: no curve could be fitted to the record")
        names = {c.name for c in cal.candidates}
        writable = [s.name for s in cal.writable() if s.name in names]
        return writable[0] if writable else cal.candidates[0].name
    return str(model.value)


def drift_words(cal: Calibration, kind: str) -> str:
    """The held-out hold drift of ``kind`` in its two groups, in words."""
    s = cal.score(kind)
    if s is None:
        return ""
    after, others = s.drift.all_pct_fs
    ref_after, ref_others = cal.static_drift_reference()

    def pct(v: float) -> str:
        return "-" if not math.isfinite(v) else f"{v:.2f} %"

    return (
        f"held-out hold drift (% FS): {pct(after)} after a higher load, {pct(others)} elsewhere "
        f"(best static: {pct(ref_after)}, {pct(ref_others)})"
    )


#: The first line of a file ``calibration_toml`` writes.
HEADER = (
    "Written by `tactile-gateway calibrate` (docs/calibration.md); the gateway reads every table, "
    "and of [meta] the effects."
)


def calibration_file(
    calibrations: Iterable[Calibration],
    model: CalibrationModel | str = CalibrationModel.PHYSICS,
    names: Mapping[str, str] | None = None,
    chosen: Mapping[str, str] | None = None,
) -> CalibrationFile:
    """The calibration file of ``calibrations``: per channel (renamed by ``names``) a
    ``[channel.<name>]`` table (the physical model's parameters, its force range and the
    calibrated range) and, for a channel whose chosen ``model`` is a rival, its ``[line]``,
    ``[lookup]`` or ``[curve]`` table; ``[meta]`` names the record and the effects."""
    model = choice_of(CalibrationModel, model, "model")
    items = list(calibrations)
    rename = dict(names or {})
    meta_comments = tuple(
        f"reference zero offset fitted: {c.offset_words()} ({rename.get(c.channel, c.channel)}: "
        "its calibrated_min_n/calibrated_max_n are the record's range + offset, widened by the "
        "reading's end margin)"
        for c in items
        if c.offset_words()
    )
    known = set(parameter_names())
    channels: dict[str, ChannelCalibration] = {}
    conversions: dict[str, ConversionTable] = {}
    for cal in items:
        name = rename.get(cal.channel, cal.channel)
        kind = (chosen or {}).get(cal.channel) or written_name(cal, model)
        if chosen and cal.channel in chosen and cal.score(kind) is None:
            raise ValueError(f"channel {cal.channel!r}: no calibration {kind!r} was scored")
        rms = cal.force_rms().get(kind, math.nan)
        params = {est.name: float(est.value) for est in cal.fit.estimates if est.name in known}
        # a rival reads F_ref, so its channel keeps the record's own range (widened by the noise)
        low, high = cal.calibrated_range_n(kind)
        # the physical model reads beyond the calibrated range (flagged extrapolated there);
        # a rival's own range is the calibrated one, and it reads beyond it along itself
        model_low, model_high = model_force_range((low, high)) if kind == "physics" else (low, high)
        params.update(force_min_n=float(model_low), force_max_n=float(model_high))
        channels[name] = ChannelCalibration(
            params,
            calibrated_range_n=(float(low), float(high)),
            comments={
                next(iter(params)): (
                    f"model: {kind}, held-out force RMS {rms:.4g} N ({cal.verdict})",
                    drift_words(cal, kind),
                    f"parameters fitted with the {OBJECTIVE_WORDS[cal.fit.objective]} objective",
                ),
                "calibrated_min_n": (
                    f"calibrated on {low:.4g}-{high:.4g} N: outside it forces read flagged extrapolated",
                ),
            },
        )
        # the channel exactly as it was scored (``Calibration.scores``)
        channel = cal.rivals.line if kind == "line" else cal.rivals.lookup if kind == "lookup" else None
        cand = cal.candidate(kind)
        if cand is not None:
            channel = cand.channel
        if channel is not None:
            values: dict[str, Any] = dict(channel.table())
            values["held_out_force_rms_n"] = float(rms)
            comments: dict[str, tuple[str, ...]] = {}
            floor = channel.zero_conductance_force_n
            if floor > 0.0 and channel.force_min_n > low:
                comments["force_min_n"] = (
                    f"the {channel.curve.kind} reaches zero conductance at {floor:.4g} N: it reads from "
                    f"{channel.force_min_n:.4g} N (no contact below), not from the record's {low:.4g} N",
                )
            conversions[name] = ConversionTable(channel.table_kind, values, comments)
    return CalibrationFile(
        channels,
        conversions,
        record=items[0].record if items else None,
        effects=tuple(items[0].fit.effects) if items else None,
        header=(HEADER,),
        meta_comments=meta_comments,
    )


def calibration_toml(
    calibrations: Iterable[Calibration],
    model: CalibrationModel | str = CalibrationModel.PHYSICS,
    names: Mapping[str, str] | None = None,
    chosen: Mapping[str, str] | None = None,
) -> str:
    """The text of ``calibration_file(calibrations, model, names)`` (``docs/calibration.md``):
    the gateway's configuration reads its ``[channel.<name>]``, ``[line.<name>]``,
    ``[lookup.<name>]`` and ``[curve.<name>]`` tables (``config.calibration_file``)."""
    return calibration_file(calibrations, model, names, chosen).to_toml()


def write_calibration(
    path: Path,
    calibrations: Iterable[Calibration],
    model: str = "physics",
    names: Mapping[str, str] | None = None,
    chosen: Mapping[str, str] | None = None,
) -> None:
    """Write the calibration file atomically; ``chosen``: per channel, the calibration to write
    by its name in the ranking (overrides ``model``)."""
    atomic_write_text(path, calibration_toml(calibrations, model, names, chosen))
