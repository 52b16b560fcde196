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
monotone lookup (``rivals``) and every static curve with every drift form (``candidates``) are
fitted and judged on the same rows, each read as the gateway reads it (``calibration_result``);
the report says which reads force best and holds, and ``model="line"|"lookup"|"curve"|"auto"``
writes it (``docs/calibration.md``).

The rooms: ``calibration_result`` (the result, its scores and what is written),
``calibration_range`` (the ranges written), ``calibration_writer`` (the file),
``calibration_report`` (the report); this module fits and puts them together.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..keys import choice_of
from ..model import EFFECT_PARAMETERS, SensorParams, parse_effects
from .calibration_range import (
    LIGHT_TOUCH_N,
    MODEL_RANGE_ABOVE,
    MODEL_RANGE_BELOW,
    end_noise_margin_n,
    model_force_range,
    widened_range_n,
)
from .calibration_report import format_report, outside_range_words, ranking_lines
from .calibration_result import (
    OBJECTIVE_OPTIONS,
    OBJECTIVE_WORDS,
    Calibration,
    CalibrationModel,
    Objective,
    OffsetMode,
    Score,
)
from .calibration_writer import HEADER, calibration_file, calibration_toml, write_calibration, written_name
from .candidates import held_out_drift, rank_candidates
from .diagnostics import residual_axes
from .discrepancy import decimate
from .fitting import FitData, FitResult, fit_channel, invert_drift_corrected
from .load_history import start_load
from .measurement import noise_model, time_is_real
from .objectives import OFFSET
from .parallel import Workers
from .records import ChannelRecord, Record
from .rivals import Rivals

__all__ = [
    "HEADER",
    "LIGHT_TOUCH_N",
    "MODEL_RANGE_ABOVE",
    "MODEL_RANGE_BELOW",
    "OBJECTIVE_OPTIONS",
    "OBJECTIVE_WORDS",
    "TIME_EFFECTS",
    "Calibration",
    "CalibrationModel",
    "Objective",
    "OffsetMode",
    "Score",
    "calibrate",
    "calibration_file",
    "calibration_toml",
    "format_report",
    "has_both_directions",
    "model_force_range",
    "outside_range_words",
    "ranking_lines",
    "write_calibration",
    "written_name",
]

TIME_EFFECTS = ("creep", "creep2")


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
    jobs: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Fit the model and its rivals to one channel of a record.

    ``objective``: ``"log_r"`` fits log-resistance residuals (the measurement model's);
    ``"force"`` also fits force-space residuals, started from the log-R result, and keeps those;
    ``"auto"`` fits both and keeps the one with the lower held-out force RMS. ``force_offset``:
    ``"fit"`` fits a reference zero offset, ``"auto"`` fits it and keeps it only if it lowers the
    held-out force RMS, ``"none"`` leaves it out. Held-out force errors of a fit with an offset
    are against F_ref + offset (the same as F_inv - offset against F_ref). ``jobs``: the
    processes it may use (``parallel.Workers``; default every core), the same result with any.
    ``progress`` is told each stage as it starts (a few words), for a long calibration."""
    with Workers(jobs) as workers:
        return _calibrate(
            channel,
            effects,
            prior,
            record_name,
            metadata,
            try_hysteresis,
            objective,
            force_offset,
            workers,
            progress or _quiet,
        )


def _quiet(stage: str) -> None:
    """No progress shown."""


def _calibrate(
    channel: ChannelRecord,
    effects: Iterable[str],
    prior: SensorParams | None,
    record_name: str,
    metadata: Mapping[str, str] | None,
    try_hysteresis: bool,
    objective: Objective | str,
    force_offset: OffsetMode | str,
    workers: Workers,
    say: Callable[[str], None],
) -> Calibration:
    objective = choice_of(Objective, objective, "objective")
    force_offset = choice_of(OffsetMode, force_offset, "force_offset")
    meta = dict(metadata or {})
    prior = prior or SensorParams()
    notes: list[str] = []
    zero_noise = channel.zero_noise_note()
    if zero_noise:
        notes.append(zero_noise)
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
    physics_data = _every_kth(data, PHYSICS_FIT_ROWS)
    if physics_data is not data:
        notes.append(
            f"the physical model fitted on every {math.ceil(data.time_s.size / PHYSICS_FIT_ROWS)}th of those "
            f"rows ({physics_data.time_s.size}); it is scored on all of them, as the gateway reads it"
        )
    say(f"physical model, log-R objective ({physics_data.time_s.size} rows)")
    pending = [_fit_objective(physics_data, chosen, ranged, "log_r", force_offset, try_h, None, workers)]
    if objective != Objective.LOG_R:
        lookup_n = Rivals.fit(data.force_n, data.resistance_ohm, data.train, data.test).lookup_force_rms_n
        # in contention by the log-R fit before its zero offset (the force objective starts there)
        log_r_n = pending[0].run.fit.gap_test.force_rms_n
        if objective == Objective.FORCE or not log_r_n > CONTENTION_FACTOR * lookup_n:
            say("physical model, force objective")
            pending.append(
                _fit_objective(
                    physics_data, chosen, ranged, "force", force_offset, try_h, pending[0].run, workers
                )
            )
        else:
            notes.append(
                f"force objective not tried: the log-R fit reads held-out force at {log_r_n:.4g} N, more "
                f"than {CONTENTION_FACTOR:g} x the monotone lookup's {lookup_n:.4g} N (out of contention)"
            )
    runs = [p.done() for p in pending]
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
    # the record read as the gateway will read it: the model's written range, not capped at the
    # top; its ends and the reference as the model reads them (F_ref + the fitted zero offset)
    fitted_range = (fit.params.force_min_n, fit.params.force_max_n)
    reach = model_force_range(fitted_range)
    uncapped = replace(fit.params, force_min_n=reach[0], force_max_n=reach[1])
    read_n = invert_drift_corrected(data, fit.effects, uncapped)
    margin = end_noise_margin_n(data.force_n + fit.force_offset_n, read_n, fitted_range)
    test = data.test
    record_range = (ranged.force_min_n, ranged.force_max_n)
    rival_range = widened_range_n(record_range, margin)
    rivals = Rivals.fit(data.force_n, data.resistance_ohm, data.train, test, rival_range)
    fs = float(hi)
    scores = [
        Score("line", rivals.line_force_rms_n, held_out_drift(data, rivals.line_force_n, fs), 2, False),
        Score(
            "lookup", rivals.lookup_force_rms_n, held_out_drift(data, rivals.lookup_force_n, fs),
            rivals.lookup.n_parameters, False,
        ),
    ]  # fmt: skip
    start = start_load(data.time_s, data.resistance_ohm, data.force_n)
    starting = start.force_n if start.loaded else 0.0
    if start.loaded:
        notes.append(
            f"the record starts loaded ({starting:.4g} N): every calibration is read from the "
            "equilibrium at its first load"
        )
    cal = Calibration(
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
        record_range_n=record_range,
        configured_range_n=configured,
        rows_outside_configured=outside,
        fit_before=pick.before,
        other=other,
        objective_mode=objective,
        offset_mode=force_offset,
        notes=tuple(notes),
        warnings=tuple(warnings),
        candidates=(),
        scores=tuple(scores),
        starting_load_n=starting,
        held_out_rows=int(np.count_nonzero(test)),
    )
    # the physical model read back (its written parameters and ranges only) while the curves fit
    read_back = workers.submit(physics_read_back, cal, small, meta)
    say("curves x drift forms, and the physical model read back as the gateway reads it")
    cands = tuple(rank_candidates(data, real_time=time_is_real(meta), range_n=rival_range))
    scores += [
        Score(c.name, c.held_out_force_rms_n, c.drift, c.n_parameters, c.channel.drift.active) for c in cands
    ]
    physics = read_back.result()
    drift = held_out_drift(data, physics, fs)
    physics_score = Score("physics", _held_out_rms(physics, data), drift, fit.n_parameters, _dynamic(fit))
    return replace(cal, candidates=cands, scores=(physics_score, *scores))


#: The physical model's fit (up to 8 fits of a stiff model) uses at most this many rows; every
#: calibration is scored on all the rows the candidates are fitted on.
PHYSICS_FIT_ROWS = 4000
#: ``objective="auto"`` tries the force objective (5 more fits) only while the log-R fit reads
#: held-out force within this factor of the monotone lookup's: beyond it the physical model is
#: out of contention on the record, and its second objective would cost minutes for nothing.
CONTENTION_FACTOR = 1.5


def _every_kth(data: FitData, max_rows: int) -> FitData:
    """``data`` itself, or every k-th row of it so that at most ``max_rows`` remain."""
    n = data.time_s.size
    if n <= max_rows:
        return data
    sl = slice(None, None, math.ceil(n / max_rows))
    return FitData(
        data.time_s[sl], data.resistance_ohm[sl], data.force_n[sl],
        None if data.temperature_c is None else data.temperature_c[sl], data.usable[sl], data.held_out[sl],
        None if data.sigma_log is None else data.sigma_log[sl],
    )  # fmt: skip


def _dynamic(fit: FitResult) -> bool:
    return any(e in fit.effects for e in ("creep", "creep2", "hysteresis"))


def _held_out_rms(force_n: np.ndarray, data: FitData) -> float:
    err = (force_n - data.force_n)[data.test]
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err * err))) if err.size else math.nan


def physics_read_back(cal: Calibration, channel: ChannelRecord, metadata: Mapping[str, str]) -> np.ndarray:
    """The physical model's force (N) on every row of ``channel``, read exactly as ``apply``
    and the gateway read the channel with its written calibration (the runtime's processor)."""
    from .apply import apply_calibration  # the runtime's own reading, imported where it is used

    name = "ch"
    with tempfile.TemporaryDirectory(prefix="tactile-cal-") as folder:
        path = Path(folder) / "physics.toml"
        write_calibration(path, [cal], CalibrationModel.PHYSICS, {cal.channel: name})
        record = Record(None, dict(metadata), {channel.name: channel})
        applied = apply_calibration(path, record, rename={channel.name: name})
    return np.asarray(applied.channels[0].force_tracked_n, dtype=np.float64)


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


def _best_of_starts(
    data: FitData,
    effects: tuple[str, ...],
    starts: list[tuple[SensorParams, float]],
    objective: str,
    offset: bool,
) -> FitResult:
    """The fit from each start; the lower objective wins (the force objective has local minima)."""
    fits = [
        fit_channel(data, effects, p, objective=objective, fit_force_offset=offset, force_offset_n=o * offset)
        for p, o in starts
    ]
    return min(fits, key=lambda f: f.cost if math.isfinite(f.cost) else math.inf)


@dataclass(frozen=True)
class _Pending:
    """One objective's fits with the zero offset's fit still running (``Workers``): ``done``
    decides on it as ``force_offset="auto"`` says."""

    run: _Run
    with_offset: Future[FitResult] | None
    word: str

    def done(self) -> _Run:
        if self.with_offset is None:
            return self.run
        fit, notes = self.run.fit, list(self.run.notes)
        with_off = self.with_offset.result()
        e = with_off.estimate(OFFSET)
        what = f"{e.value:+.4g} N, 95 % [{e.low:+.4g}, {e.high:+.4g}]" if e.fitted else e.note
        a, b = fit.gap_test.force_rms_n, with_off.gap_test.force_rms_n
        lost = sorted(set(with_off.fixed_reasons) - set(fit.fixed_reasons) - {OFFSET})
        if lost:
            what += f"; it leaves {', '.join(lost)} undetermined"
        if e.fitted and not lost and _rms(with_off) < _rms(fit):
            notes.append(
                f"{self.word} objective: reference zero offset fitted and kept ({what}): held-out force RMS "
                f"{a:.4g} -> {b:.4g} N (against F_ref + offset)"
            )
            fit = with_off
        else:
            notes.append(
                f"{self.word} objective: reference zero offset fitted ({what}) and left out: held-out force "
                f"RMS {a:.4g} N without, {b:.4g} N with it"
            )
        return replace(self.run, fit=fit, notes=tuple(notes))


def _fit_objective(
    data: FitData,
    effects: tuple[str, ...],
    ranged: SensorParams,
    objective: str,
    force_offset: str,
    try_h: bool,
    start: _Run | None,
    workers: Workers,
) -> _Pending:
    """Fit one objective, with hysteresis tried and the offset as ``force_offset`` says; a
    run of another objective (``start``) gives the starting parameters. With ``"auto"`` the
    offset's fit is handed to ``workers``: the next objective starts from the fits before it."""

    def at(base: FitResult | None, **reset: float) -> tuple[SensorParams, float]:
        """A start: the prior, or a fit's parameters with the record's range (its own is shifted)."""
        if base is None:
            return ranged, 0.0
        p = replace(base.params, force_min_n=ranged.force_min_n, force_max_n=ranged.force_max_n, **reset)
        return p, base.force_offset_n

    def run(eff: tuple[str, ...], starts: list[tuple[SensorParams, float]], offset: bool) -> FitResult:
        return _best_of_starts(data, eff, starts, objective, offset)

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
    with_offset = None
    if force_offset == "auto":
        with_offset = workers.submit(_best_of_starts, data, fit.effects, [at(fit)], objective, True)
    return _Pending(_Run(fit, before, plain, with_h, tuple(notes)), with_offset, word)
