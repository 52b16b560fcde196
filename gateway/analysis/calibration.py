"""Calibration: fit a channel's model to a record and put it beside its rivals.

The physical model (``fitting.fit_channel``, drift-corrected inversion) is fitted with
residuals weighted by the record's measurement model (``measurement``), over the force range
the record spans. That range is written to the calibration file as the channel's calibrated
range (``calibrated_min_n``/``calibrated_max_n``: the runtime flags a force outside it
``extrapolated``), and the model's own range (``force_min_n``/``force_max_n``, where it reads
no contact and saturated) reaches well beyond it (``model_force_range``): the calibrated range
is not a blindfold. When the
record has loading and unloading, ``hysteresis`` is tried and kept only if it reads the
held-out force better. Two objectives are fitted (``objectives``): log-resistance (the
measurement model's) and force, started from the log-R result; ``objective="auto"`` keeps the
one that reads held-out force better. A reference-force zero offset is fitted too
(``force_offset="auto"`` keeps it only if it reads held-out force better; held-out force
errors are then against F_ref + offset). The paper's conductance line C = m F + n and a
monotone lookup (``rivals``) are fitted and judged on the same rows; the report says which
reads force best, and ``model="line"|"lookup"|"auto"`` writes it (``docs/calibration.md``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write_text
from ..config.calibration_file import CalibrationFile, ChannelCalibration, ConversionTable
from ..model import EFFECT_PARAMETERS, SensorParams, parameter_names, parse_effects
from ..model.curves import CurveChannel
from .candidates import Candidate, hold_drift_pct, rank_candidates
from .diagnostics import residual_axes
from .discrepancy import decimate
from .fit_data import FloatArray
from .fitting import FitData, FitResult, fit_channel, invert_drift_corrected
from .measurement import NoiseModel, noise_model, time_is_real
from .objectives import OFFSET
from .records import ChannelRecord
from .rivals import LINE_ZERO_MARGIN, ConductanceLine, Rivals, verdict


class CalibrationModel(StrEnum):
    """What a calibration file gives a channel: the physical model, the conductance line, a
    monotone lookup, the best static curve with drift correction, or whichever of them reads
    held-out force best."""

    PHYSICS = "physics"
    LINE = "line"
    LOOKUP = "lookup"
    CURVE = "curve"
    AUTO = "auto"


class Objective(StrEnum):
    """What the physical model's fit minimises: log-resistance residuals, force residuals
    (started from the log-R fit), or both, keeping the one that reads held-out force better."""

    AUTO = "auto"
    LOG_R = "log_r"
    FORCE = "force"

    @property
    def option(self) -> str:
        """The command line's spelling (``log-r``)."""
        return self.value.replace("_", "-")


class OffsetMode(StrEnum):
    """The reference-force zero offset: fit it and keep it only if it helps, fit it, or none."""

    AUTO = "auto"
    FIT = "fit"
    NONE = "none"


MODELS = tuple(m.value for m in CalibrationModel)
#: The physical model's written range reaches light touch: force_min_n = min(calibrated
#: minimum / ``MODEL_RANGE_BELOW``, ``LIGHT_TOUCH_N``) ...
MODEL_RANGE_BELOW = 10.0
LIGHT_TOUCH_N = 0.01
#: ... and beyond the top: force_max_n = ``MODEL_RANGE_ABOVE`` x the calibrated maximum.
MODEL_RANGE_ABOVE = 3.0
OBJECTIVE_CHOICES = tuple(o.value for o in Objective)
OFFSET_CHOICES = tuple(o.value for o in OffsetMode)
#: an objective by its command-line spelling (``log-r``)
OBJECTIVE_OPTIONS = {o.option: o for o in Objective}
OBJECTIVE_WORDS: dict[str, str] = {Objective.LOG_R: "log-R", Objective.FORCE: "force"}
TIME_EFFECTS = ("creep", "creep2")


@dataclass(frozen=True)
class Calibration:
    """Result of calibrating one channel."""

    channel: str
    record: str
    fit: FitResult
    rivals: Rivals
    unusable: dict[str, int]
    noise: NoiseModel
    noise_floor_log: float
    noise_floor_force_n: float
    force_range_n: tuple[float, float]  # the physical model's: the record's range + offset
    configured_range_n: tuple[float, float]
    rows_outside_configured: int
    fit_before: FitResult | None = None  # the fit without hysteresis, when hysteresis was tried
    #: the other objective's best fit (None when only one objective was fitted)
    other: FitResult | None = None
    objective_mode: str = "log_r"
    offset_mode: str = "none"
    record_range_n: tuple[float, float] = (math.nan, math.nan)  # the record's loaded range, as F_ref
    notes: tuple[str, ...] = field(default=())
    warnings: tuple[str, ...] = field(default=())
    #: every static curve with every drift form (``candidates``), best held-out force first
    candidates: tuple[Candidate, ...] = field(default=())
    #: per calibration name: the drift across held-out holds (% of full scale; NaN: no hold)
    hold_drift_pct_fs: Mapping[str, float] = field(default_factory=dict)
    #: how far beyond the record's lowest and highest force the model reads the record's own
    #: end loads (N, ``end_noise_margin_n``: bias + 3 sigma): the calibrated range reaches this
    #: far beyond the record's, so that a reading of an end load is not flagged extrapolated
    #: for its noise alone
    range_margin_n: tuple[float, float] = (0.0, 0.0)

    def calibrated_range_n(self, kind: str = "physics") -> tuple[float, float]:
        """The range written as ``calibrated_min_n``/``calibrated_max_n`` (N) for a channel
        read with ``kind``: the physical model's range (the record's + the zero offset) or,
        for a rival (which reads F_ref), the record's, widened at each end by
        ``range_margin_n`` (the low end never below half of itself)."""
        low, high = self.force_range_n if kind == "physics" else self.record_range_n
        below, above = self.range_margin_n
        return max(low - below, 0.5 * low), high + above

    @property
    def line_force_rms_n(self) -> float:
        return self.rivals.line_force_rms_n

    def force_rms(self) -> dict[str, float]:
        """Held-out force RMS (N) of every calibration: the physical model, the paper's line,
        the monotone lookup, and every curve-with-drift candidate by its name."""
        out = {
            "physics": self.fit.gap_test.force_rms_n,
            "line": self.rivals.line_force_rms_n,
            "lookup": self.rivals.lookup_force_rms_n,
        }
        out.update({c.name: c.held_out_force_rms_n for c in self.candidates})
        return out

    def n_parameters(self) -> dict[str, int]:
        out = {"physics": self.fit.n_parameters, "line": 2, "lookup": 2 * len(self.rivals.lookup.force_n)}
        out.update({c.name: c.n_parameters for c in self.candidates})
        return out

    def ranking(self) -> list[tuple[str, float, float, int]]:
        """(name, held-out force RMS N, drift across held-out holds % FS, parameters), best first."""
        rms, n = self.force_rms(), self.n_parameters()
        rows = [(k, v, self.hold_drift_pct_fs.get(k, math.nan), n[k]) for k, v in rms.items()]
        return sorted(rows, key=lambda r: (r[1] if math.isfinite(r[1]) else math.inf, r[3]))

    @property
    def best(self) -> str:
        """The calibration that reads held-out force best (the fewer parameters on an exact tie):
        never one that reads it worse than the best of the line and the lookup."""
        return self.ranking()[0][0]

    def candidate(self, name: str) -> Candidate | None:
        return next((c for c in self.candidates if c.name == name), None)

    @property
    def verdict(self) -> str:
        return verdict(self.fit.gap_test.force_rms_n, self.rivals.line_force_rms_n)

    def offset_dict(self) -> dict[str, Any]:
        """The reference zero offset: fitted or not, value and 95 % interval."""
        out: dict[str, Any] = {"mode": self.offset_mode, "fitted": False, "value_n": self.fit.force_offset_n}
        try:
            e = self.fit.estimate(OFFSET)
        except KeyError:
            return out
        out.update(fitted=e.fitted, value_n=e.value, ci95_low=e.low, ci95_high=e.high)
        out["held_out_against"] = "the offset-corrected reference F_ref + force_offset_n"
        return out

    def offset_words(self) -> str:
        """The fitted zero offset with its interval in words ('' when there is none)."""
        o = self.offset_dict()
        interval = f"[{o.get('ci95_low', 0.0):+.4g}, {o.get('ci95_high', 0.0):+.4g}]"
        return f"{o['value_n']:+.4g} N, 95 % {interval}" if o["fitted"] else ""

    def as_dict(self) -> dict[str, Any]:
        fit = self.fit
        out: dict[str, Any] = {
            "record": self.record,
            "channel": self.channel,
            "effects": list(fit.effects),
            "parameters": [
                {
                    "name": e.name,
                    "value": e.value,
                    "ci95_low": e.low,
                    "ci95_high": e.high,
                    "fitted": e.fitted,
                    "note": e.note,
                }
                for e in fit.estimates
            ],
            "correlation": {
                "names": list(fit.correlation_names),
                "matrix": [[round(float(v), 4) for v in row] for row in fit.correlation],
            },
            "fit_quality": {"train": fit.gap_train.as_dict(), "held_out": fit.gap_test.as_dict()},
            "rows": {"train": fit.n_train, "held_out": fit.n_test, "unusable": self.unusable},
            "conductance_line": {
                "slope_s_per_n": self.rivals.line.slope_s_per_n,
                "intercept_s": self.rivals.line.intercept_s,
                "held_out_force_rms_n": self.rivals.line_force_rms_n,
            },
            "lookup": {"held_out_force_rms_n": self.rivals.lookup_force_rms_n},
            "held_out_force_rms_n": self.force_rms(),
            "best": self.best,
            "ranking": [
                {
                    "name": name,
                    "held_out_force_rms_n": rms,
                    "hold_drift_pct_fs": None if math.isnan(drift) else drift,
                    "parameters": n,
                }
                for name, rms, drift, n in self.ranking()
            ],
            "verdict": self.verdict,
            "noise": {
                "estimated": self.noise.estimated,
                "description": self.noise.describe(),
                "rel_noise": self.noise.rel_noise,
                "floor_log_resistance": self.noise_floor_log,
                "floor_force_n": self.noise_floor_force_n,
            },
            "force_range_n": list(self.force_range_n),
            "calibrated_range_n": list(self.calibrated_range_n()),
            "range_margin_n": list(self.range_margin_n),
            "model_force_range_n": list(model_force_range(self.calibrated_range_n())),
            "configured_force_range_n": list(self.configured_range_n),
            "rows_outside_configured_range": self.rows_outside_configured,
            "notes": list(self.notes),
            "warnings": list(self.warnings),
        }
        other = self.other
        out["objective"] = {
            "used": fit.objective,
            "requested": self.objective_mode,
            "held_out_force_rms_n": {f.objective: f.gap_test.force_rms_n for f in (fit, other) if f},
            "other": other and {"objective": other.objective, "effects": list(other.effects)},
        }
        out["force_offset"] = self.offset_dict()
        out["record_force_range_n"] = list(self.record_range_n)
        if self.fit_before is not None:
            out["without_hysteresis"] = {
                "effects": list(self.fit_before.effects),
                "held_out": self.fit_before.gap_test.as_dict(),
            }
        return out


def model_force_range(calibrated_n: tuple[float, float]) -> tuple[float, float]:
    """The physical model's ``force_min_n``/``force_max_n`` written for a channel calibrated
    over ``calibrated_n`` (N): from light touch (min(low / 10, 0.01 N)) to 3 x the top. Between
    them and the calibrated range the model reads forces flagged ``extrapolated``."""
    low, high = calibrated_n
    return min(low / MODEL_RANGE_BELOW, LIGHT_TOUCH_N), MODEL_RANGE_ABOVE * high


#: The calibrated range reaches this many standard deviations of the reading noise beyond
#: the record's ends (a reading of the end force lies beyond it with probability 0.13 %) ...
RANGE_MARGIN_SIGMA = 3.0
#: ... the noise measured on the rows whose reference lies within this share of the record's
#: span of each end.
RANGE_END_BAND = 0.1


def end_noise_margin_n(
    reference_n: FloatArray, force_read_n: FloatArray, range_n: tuple[float, float]
) -> tuple[float, float]:
    """How far beyond each end of the record's loaded range ``range_n`` (N) the calibrated
    model reads the record's own end loads: the reading's bias there (the median of read -
    reference, where it points outward) + ``RANGE_MARGIN_SIGMA`` x the reading's scatter.
    ``reference_n`` and ``range_n`` are as the model reads them (F_ref + the fitted zero
    offset); ``force_read_n``: the record read back with the calibrated model, row by row
    (drift-corrected, not capped at the range). Both over the consecutive rows whose reference
    lies within ``RANGE_END_BAND`` of the span of that end; the scatter is the robust
    second-difference estimate 1.4826 median|x[k-1] - 2 x[k] + x[k+1]| / sqrt(6) (a hold's
    creep and a ramp's slope cancel in a second difference, a step between two loads is an
    outlier the median ignores). 0 where fewer than 5 such triples exist."""
    lo, hi = range_n
    band = RANGE_END_BAND * max(hi - lo, 0.0)
    out: list[float] = []
    for end, outward in ((lo, -1.0), (hi, 1.0)):
        near = (reference_n > 0) & (np.abs(reference_n - end) <= band) & np.isfinite(force_read_n)
        triple = near[:-2] & near[1:-1] & near[2:]
        d2 = (force_read_n[:-2] - 2.0 * force_read_n[1:-1] + force_read_n[2:])[triple]
        if d2.size < 5:
            out.append(0.0)
            continue
        sigma = 1.4826 * float(np.median(np.abs(d2))) / math.sqrt(6.0)
        bias = outward * float(np.median((force_read_n - reference_n)[near]))
        out.append(max(bias, 0.0) + RANGE_MARGIN_SIGMA * sigma)
    return out[0], out[1]


def has_both_directions(data: FitData, share: float = 0.1) -> bool:
    """Does the record load and unload (each direction on at least ``share`` of loaded rows)?"""
    d = residual_axes(data)["direction"]
    loaded = data.usable & (data.force_n > 0)
    n = max(int(np.count_nonzero(loaded)), 1)
    return bool(
        np.count_nonzero(loaded & (d > 0)) >= share * n and np.count_nonzero(loaded & (d < 0)) >= share * n
    )


def calibrate(
    channel: ChannelRecord,
    effects: Iterable[str] = ("tunneling", "contact", "creep"),
    prior: SensorParams | None = None,
    record_name: str = "",
    metadata: Mapping[str, str] | None = None,
    try_hysteresis: bool = True,
    objective: Objective | str = Objective.AUTO,
    force_offset: OffsetMode | str = OffsetMode.AUTO,
) -> Calibration:
    """Fit the model and its rivals to one channel of a record.

    ``objective``: ``"log_r"`` fits log-resistance residuals (the measurement model's);
    ``"force"`` also fits force-space residuals, started from the log-R result, and keeps those;
    ``"auto"`` fits both and keeps the one with the lower held-out force RMS. ``force_offset``:
    ``"fit"`` fits a reference zero offset, ``"auto"`` fits it and keeps it only if it lowers the
    held-out force RMS, ``"none"`` leaves it out. Held-out force errors of a fit with an offset
    are against F_ref + offset (the same as F_inv - offset against F_ref)."""
    if objective not in OBJECTIVE_CHOICES:
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVE_CHOICES)}, got {objective!r}")
    if force_offset not in OFFSET_CHOICES:
        raise ValueError(f"force_offset must be one of {', '.join(OFFSET_CHOICES)}, got {force_offset!r}")
    objective, force_offset = Objective(objective), OffsetMode(force_offset)
    meta = dict(metadata or {})
    prior = prior or SensorParams()
    notes: list[str] = []
    warnings: list[str] = []
    chosen = parse_effects(effects)
    if not time_is_real(meta) and any(e in chosen for e in TIME_EFFECTS):
        dropped = [e for e in chosen if e in TIME_EFFECTS]
        chosen = parse_effects(e for e in chosen if e not in TIME_EFFECTS)
        notes.append(
            f"{', '.join(dropped)} left out: the record has no real time (# time: {meta.get('time', '')})"
        )
    small = decimate(channel)
    if small.n_samples < channel.n_samples:
        notes.append(f"fitted on every {channel.n_samples // small.n_samples}th row ({small.n_samples} rows)")
    if small.force_n is None:
        raise ValueError(f"channel {channel.name!r} has no force_n column: a fit needs the reference force")
    noise = noise_model(meta, small.force_n, small.resistance_ohm)
    if noise.estimated:
        notes.append("no front-end metadata: " + noise.describe())
    data = FitData.from_channel(small, sigma_log=noise.sigma_log)
    if not data.train.any() or not data.test.any():
        raise ValueError(
            f"channel {channel.name!r}: not enough usable rows to fit and to hold out "
            f"({int(data.train.sum())} training, {int(data.test.sum())} held-out rows)"
        )
    loaded = data.force_n[data.usable]
    lo, hi = float(loaded.min()), float(loaded.max())
    configured = (prior.force_min_n, prior.force_max_n)
    assert channel.force_n is not None
    outside = int(
        np.count_nonzero(
            (channel.force_n > configured[1]) | ((channel.force_n > 0) & (channel.force_n < configured[0]))
        )
    )
    if hi > configured[1]:
        warnings.append(
            f"the record's forces reach {hi:.4g} N, above the configured force_max_n = {configured[1]:g} N: "
            f"{outside} rows would read as saturated (capped); the fit uses and writes the record's "
            f"range {lo:.3g}-{hi:.4g} N (+ the zero offset, when one is fitted)"
        )
    ranged = replace(prior, force_min_n=min(lo, hi * 0.999), force_max_n=hi)
    try_h = try_hysteresis and "hysteresis" not in chosen and has_both_directions(data)
    runs = [_fit_objective(data, chosen, ranged, "log_r", force_offset, try_h, None)]
    if objective != Objective.LOG_R:
        runs.append(_fit_objective(data, chosen, ranged, "force", force_offset, try_h, runs[0]))
    for run in runs:
        notes += run.notes
    pick = runs[-1] if objective == Objective.FORCE else min(runs, key=lambda r: _rms(r.fit))
    fit, other = pick.fit, next((r.fit for r in runs if r is not pick), None)
    if other is not None:
        notes.append(
            f"objective: {OBJECTIVE_WORDS[fit.objective]} ({objective} requested): "
            f"held-out force RMS {fit.gap_test.force_rms_n:.4g} N, the {OBJECTIVE_WORDS[other.objective]} "
            f"objective's {other.gap_test.force_rms_n:.4g} N"
        )
    rivals = Rivals.fit(data.force_n, data.resistance_ohm, data.train, data.test)
    # the record read as the gateway will read it: the model's written range, not capped at the
    # top; its ends and the reference as the model reads them (F_ref + the fitted zero offset)
    fitted_range = (fit.params.force_min_n, fit.params.force_max_n)
    reach = model_force_range(fitted_range)
    uncapped = replace(fit.params, force_min_n=reach[0], force_max_n=reach[1])
    read_n = invert_drift_corrected(data, fit.effects, uncapped)
    margin = end_noise_margin_n(data.force_n + fit.force_offset_n, read_n, fitted_range)
    test = data.test
    cands = tuple(rank_candidates(data, real_time=time_is_real(meta)))
    fs = float(hi)
    drifts = {c.name: c.hold_drift_pct_fs for c in cands}
    drifts["physics"] = hold_drift_pct(
        data.time_s, data.force_n + fit.force_offset_n, fit.force_inverted_n, test, fs
    )
    drifts["line"] = hold_drift_pct(
        data.time_s, data.force_n, rivals.line.force(data.resistance_ohm), test, fs
    )
    drifts["lookup"] = hold_drift_pct(
        data.time_s, data.force_n, rivals.lookup.force(data.resistance_ohm), test, fs
    )
    return Calibration(
        channel=channel.name,
        record=record_name,
        fit=fit,
        rivals=rivals,
        unusable=channel.unusable_counts(),
        noise=noise,
        noise_floor_log=noise.floor_log(test),
        noise_floor_force_n=rivals.force_noise_floor_n(noise.sigma_log[test], data.resistance_ohm[test]),
        range_margin_n=margin,
        force_range_n=fitted_range,
        record_range_n=(ranged.force_min_n, ranged.force_max_n),
        configured_range_n=configured,
        rows_outside_configured=outside,
        fit_before=pick.before,
        other=other,
        objective_mode=objective,
        offset_mode=force_offset,
        notes=tuple(notes),
        warnings=tuple(warnings),
        candidates=cands,
        hold_drift_pct_fs=drifts,
    )


@dataclass(frozen=True)
class _Run:
    """One objective's fits: the kept one, and the ones a next objective starts from."""

    fit: FitResult
    before: FitResult | None  # without hysteresis, when hysteresis was tried
    plain: FitResult
    with_h: FitResult | None
    notes: tuple[str, ...]


def _rms(fit: FitResult) -> float:
    v = fit.gap_test.force_rms_n
    return v if math.isfinite(v) else math.inf


def _fit_objective(
    data: FitData,
    effects: tuple[str, ...],
    ranged: SensorParams,
    objective: str,
    force_offset: str,
    try_h: bool,
    start: _Run | None,
) -> _Run:
    """Fit one objective, with hysteresis tried and the offset as ``force_offset`` says; a
    run of another objective (``start``) gives the starting parameters."""

    def at(base: FitResult | None, **reset: float) -> tuple[SensorParams, float]:
        """A start: the prior, or a fit's parameters with the record's range (its own is shifted)."""
        if base is None:
            return ranged, 0.0
        p = replace(base.params, force_min_n=ranged.force_min_n, force_max_n=ranged.force_max_n, **reset)
        return p, base.force_offset_n

    def run(eff: tuple[str, ...], starts: list[tuple[SensorParams, float]], offset: bool) -> FitResult:
        """The fit from each start; the lower objective wins (the force objective has local minima)."""
        fits = [
            fit_channel(data, eff, p, objective=objective, fit_force_offset=offset, force_offset_n=o * offset)
            for p, o in starts
        ]
        return min(fits, key=lambda f: f.cost if math.isfinite(f.cost) else math.inf)

    word, notes, fo = OBJECTIVE_WORDS[objective], [], force_offset == "fit"
    # the force objective starts from the log-R fit and from the prior; with hysteresis, from the
    # log-R fit with hysteresis and from its own fit without, hysteresis at the prior
    fit = plain = run(effects, [at(None)] if start is None else [at(start.plain), at(None)], fo)
    before = with_h = None
    if try_h:
        prior_h = {k: getattr(ranged, k) for k in EFFECT_PARAMETERS["hysteresis"]}
        starts = [at(None)] if start is None else [at(start.with_h or start.plain), at(plain, **prior_h)]
        with_h = run((*effects, "hysteresis"), starts, fo)
        before = plain
        a, b = plain.gap_test.force_rms_n, with_h.gap_test.force_rms_n
        if _rms(with_h) < _rms(plain):
            fit = with_h
            notes.append(
                f"{word} objective: hysteresis added (the record loads and unloads): held-out force RMS "
                f"{a:.4g} -> {b:.4g} N"
            )
        else:
            notes.append(
                f"{word} objective: hysteresis tried (the record loads and unloads) and left out: held-out "
                f"force RMS {a:.4g} N without, {b:.4g} N with it"
            )
    if force_offset == "auto":
        with_off = run(fit.effects, [at(fit)], True)
        e = with_off.estimate(OFFSET)
        what = f"{e.value:+.4g} N, 95 % [{e.low:+.4g}, {e.high:+.4g}]" if e.fitted else e.note
        a, b = fit.gap_test.force_rms_n, with_off.gap_test.force_rms_n
        lost = sorted(set(with_off.fixed_reasons) - set(fit.fixed_reasons) - {OFFSET})
        if lost:
            what += f"; it leaves {', '.join(lost)} undetermined"
        if e.fitted and not lost and _rms(with_off) < _rms(fit):
            notes.append(
                f"{word} objective: reference zero offset fitted and kept ({what}): held-out force RMS "
                f"{a:.4g} -> {b:.4g} N (against F_ref + offset)"
            )
            fit = with_off
        else:
            notes.append(
                f"{word} objective: reference zero offset fitted ({what}) and left out: held-out force "
                f"RMS {a:.4g} N without, {b:.4g} N with it"
            )
    return _Run(fit, before, plain, with_h, tuple(notes))


#: The first line of a file ``calibration_toml`` writes.
HEADER = (
    "Written by `tactile-gateway calibrate` (docs/calibration.md); the gateway reads every table but [meta]."
)


def calibration_file(
    calibrations: Iterable[Calibration],
    model: CalibrationModel | str = CalibrationModel.PHYSICS,
    names: Mapping[str, str] | None = None,
) -> CalibrationFile:
    """The calibration file of ``calibrations``: per channel (renamed by ``names``) a
    ``[channel.<name>]`` table (the physical model's parameters, its force range and the
    calibrated range) and, for a channel whose chosen ``model`` is a rival, its ``[line]``,
    ``[lookup]`` or ``[curve]`` table; ``[meta]`` names the record and the effects."""
    if model not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    model = CalibrationModel(model)
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
        kind = cal.best if model == CalibrationModel.AUTO else model
        if (
            model == CalibrationModel.CURVE
        ):  # the best static curve with drift correction, whatever else ranks first
            if not cal.candidates:
                raise ValueError(f"channel {cal.channel!r}: no curve could be fitted to the record")
            kind = cal.candidates[0].name
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
                    f"parameters fitted with the {OBJECTIVE_WORDS[cal.fit.objective]} objective",
                ),
                "calibrated_min_n": (
                    f"calibrated on {low:.4g}-{high:.4g} N: outside it forces read flagged extrapolated",
                ),
            },
        )
        if kind == "line":
            line = cal.rivals.line
            values: dict[str, Any] = {
                "slope_s_per_n": float(line.slope_s_per_n),
                "intercept_s": float(line.intercept_s),
                "held_out_force_rms_n": float(cal.rivals.line_force_rms_n),
            }
            comments: dict[str, tuple[str, ...]] = {}
            floor_n = _line_floor_n(line, low)
            if floor_n is not None:
                values["force_min_n"] = floor_n
                comments["force_min_n"] = (
                    f"the line reaches zero conductance at {floor_n / LINE_ZERO_MARGIN:.4g} N: it reads "
                    f"from {floor_n:.4g} N (no contact below), not from the record's {low:.4g} N",
                )
            conversions[name] = ConversionTable("line", values, comments)
        elif (cand := cal.candidate(kind)) is not None:
            values = curve_table(cand.channel, cal.calibrated_range_n(kind))
            values["held_out_force_rms_n"] = float(cand.held_out_force_rms_n)
            conversions[name] = ConversionTable("curve", values)
        elif kind == "lookup":
            lk = cal.rivals.lookup
            values = {
                "resistance_ohm": [math.exp(x) for x in lk.log_r],
                "force_n": [float(f) for f in lk.force_n],
                "held_out_force_rms_n": float(cal.rivals.lookup_force_rms_n),
            }
            conversions[name] = ConversionTable("lookup", values)
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
) -> str:
    """The text of ``calibration_file(calibrations, model, names)`` (``docs/calibration.md``):
    the gateway's configuration reads its ``[channel.<name>]``, ``[line.<name>]``,
    ``[lookup.<name>]`` and ``[curve.<name>]`` tables (``config.calibration_file``)."""
    return calibration_file(calibrations, model, names).to_toml()


def _line_floor_n(line: ConductanceLine, record_min_n: float) -> float | None:
    """The ``[line]`` table's own ``force_min_n`` when the channel's (the record's lowest force)
    lies at or below 1.1 x the line's zero-conductance force -n/m (n < 0): below -n/m a sensor
    at rest would read a force (``rivals.line_range_lines``, ``model.conversion.LineConversion``)."""
    if line.intercept_s >= 0.0:
        return None
    floor_n = LINE_ZERO_MARGIN * float(line.force(math.inf))  # an open sensor reads -n/m
    return floor_n if record_min_n <= floor_n else None


def curve_table(channel: CurveChannel, calibrated_range_n: tuple[float, float]) -> dict[str, Any]:
    """The body of a ``[curve.<name>]`` table (``gateway.model.curves.curve_from_table``): kind,
    the static curve's parameters, the sensitivity, the drift and the calibrated force range."""
    out: dict[str, Any] = {"kind": channel.curve.kind}
    for key, value in channel.curve.table().items():
        out[key] = [float(v) for v in value] if isinstance(value, list) else float(value)
    out.update(gain=float(channel.gain), offset_n=float(channel.offset_n))
    out.update({key: float(value) for key, value in channel.drift.table().items()})
    low, high = calibrated_range_n
    out.update(force_min_n=max(float(low), 0.0), force_max_n=float(high))
    return out


def write_calibration(
    path: Path,
    calibrations: Iterable[Calibration],
    model: str = "physics",
    names: Mapping[str, str] | None = None,
) -> None:
    """Write the calibration file atomically."""
    atomic_write_text(path, calibration_toml(calibrations, model, names))


def format_report(cal: Calibration) -> str:
    """Human-readable calibration report."""
    fit = cal.fit
    out = [f"channel {cal.channel} of {cal.record}: effects {', '.join(fit.effects)}"]
    out.append(f"rows: {fit.n_train} training, {fit.n_test} held out, unusable {cal.unusable}")
    lo, hi = cal.force_range_n
    low, high = cal.calibrated_range_n()
    below, above = cal.range_margin_n
    out.append(
        f"force range calibrated: {lo:.3g}-{hi:.4g} N, written as calibrated_min_n/calibrated_max_n "
        f"{low:.3g}-{high:.4g} N (widened to where the model reads the record's end loads, "
        f"bias + 3 sigma: -{below:.2g}/+{above:.2g} N) "
        f"(configured {cal.configured_range_n[0]:g}-{cal.configured_range_n[1]:g} N; "
        f"{cal.rows_outside_configured} rows outside it, none capped in the fit-quality numbers)"
        + (
            f"; the record's {cal.record_range_n[0]:.3g}-{cal.record_range_n[1]:.4g} N "
            f"+ the zero offset {cal.offset_words()}"
            if cal.offset_words()
            else ""
        )
    )
    out += outside_range_words(cal)
    out.append(
        f"fit objective: {OBJECTIVE_WORDS[fit.objective]} (requested: {cal.objective_mode}; zero offset: "
        f"{cal.offset_mode}); held-out force errors are against "
        + ("F_ref + offset" if cal.offset_words() else "F_ref")
    )
    out += [f"WARNING: {w}" for w in cal.warnings]
    out += [f"note: {n}" for n in cal.notes]
    out.append(f"measurement model: {cal.noise.describe()}")
    out.append("")
    out.append(f"{'parameter':<24} {'value':>12} {'95 % interval':>27}  note")
    for e in fit.estimates:
        interval = f"[{e.low:.4g}, {e.high:.4g}]" if e.fitted else "fixed at prior"
        out.append(f"{e.name:<24} {e.value:>12.5g} {interval:>27}  {e.note}")
    if fit.correlation.size:
        out.append("")
        out.append("strongest parameter correlations:")
        pairs = []
        n = len(fit.correlation_names)
        for i in range(n):
            for j in range(i + 1, n):
                pairs.append((abs(float(fit.correlation[i, j])), i, j))
        for value, i, j in sorted(pairs, reverse=True)[:5]:
            sign = "+" if fit.correlation[i, j] >= 0 else "-"
            out.append(f"  {fit.correlation_names[i]} ~ {fit.correlation_names[j]}: {sign}{value:.3f}")
    out.append("")
    out.append(f"held-out data ({fit.n_test} rows)             log-resistance RMS   force RMS (N)")
    if cal.fit_before is not None and cal.fit_before is not fit:
        g = cal.fit_before.gap_test
        out.append(
            f"  physical model without hysteresis {g.log_resistance_rms:>17.4f} {g.force_rms_n:>15.4f}"
        )
    out.append(
        f"  physical model (drift-corrected) {fit.gap_test.log_resistance_rms:>18.4f} "
        f"{fit.gap_test.force_rms_n:>15.4f}"
    )
    if cal.other is not None:
        g, word = cal.other.gap_test, f"  physical model, {OBJECTIVE_WORDS[cal.other.objective]} objective"
        out.append(f"{word:<35}{g.log_resistance_rms:>16.4f} {g.force_rms_n:>15.4f}")
    out.append(f"  conductance line C = m F + n     {'-':>18} {cal.rivals.line_force_rms_n:>15.4f}")
    out.append(f"  monotone lookup F(ln R)          {'-':>18} {cal.rivals.lookup_force_rms_n:>15.4f}")
    out.append(
        f"  noise floor (measurement model)  {cal.noise_floor_log:>18.4f} {cal.noise_floor_force_n:>15.4f}"
    )
    out.append(f"    m = {cal.rivals.line.slope_s_per_n:.6g} S/N, n = {cal.rivals.line.intercept_s:.6g} S")
    out.append("")
    out += ranking_lines(cal)
    out.append(f"verdict: {cal.verdict}; best on held-out force: {cal.best}")
    if cal.best != "physics":
        how = f"--model {cal.best} or --model auto" if cal.best in MODELS else "--model auto"
        out.append(f"  (write it as the channel's model with {how})")
    return "\n".join(out)


def outside_range_words(cal: Calibration) -> list[str]:
    """What the channel reads outside its calibrated range (lines of the report)."""
    lo, hi = cal.calibrated_range_n()
    model_lo, model_hi = model_force_range((lo, hi))
    rival = ""
    if cal.offset_words():
        r_lo, r_hi = cal.calibrated_range_n("line")
        rival = f" (written as a line, lookup or curve: outside {r_lo:.3g}-{r_hi:.4g} N)"
    return [
        f"outside the calibrated range: below {lo:.3g} N and above {hi:.4g} N the channel reads forces "
        f"extrapolated along its curve, flagged `extrapolated`{rival}; at or below 0 N it reads no_contact",
        f"  (the physical model is written over {model_lo:.3g}-{model_hi:.4g} N, force_min_n/force_max_n: "
        f"no_contact below {model_lo:.3g} N, saturated above {model_hi:.4g} N; a line with n < 0 reads "
        "no_contact below its force_min_n, where a sensor at rest would read a phantom force)",
    ]


def ranking_lines(cal: Calibration) -> list[str]:
    """Every calibration ranked on held-out force (the table of the report)."""
    rows = cal.ranking()
    out = [
        f"ranking on held-out force ({cal.fit.n_test} rows, tracked as the runtime reads them):",
        f"  {'calibration':<30} {'force RMS (N)':>13} {'hold drift (% FS)':>18} {'parameters':>10}",
    ]
    for i, (name, rms, drift, n) in enumerate(rows):
        d = "-" if math.isnan(drift) else f"{drift:.2f}"
        mark = "  <- best" if i == 0 else ""
        out.append(f"  {name:<30} {rms:>13.4f} {d:>18} {n:>10}{mark}")
    return out
