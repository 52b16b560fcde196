"""The discrepancy workflow: where model and measurement disagree, which effect is missing.

Starting from a baseline model (by default ``tunneling``, the model the paper improves on):

1. fit the current model to the record (``fitting.fit_channel``);
2. describe where it disagrees: log-resistance residuals by force level, by time since the
   last load change, loading against unloading, by temperature and by load cycle;
3. refit with each candidate effect added and score it on held-out segments of the record,
   with a penalty for the parameters it adds;
4. add the best candidate only if it wins clearly (and say so when two candidates cannot be
   told apart, with the measurement that would separate them); repeat until none helps.

The JSON summary keeps the keys and meanings of ``docs/record-format.md``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model import EFFECT_NAMES, SensorParams, parse_effects
from .diagnostics import OPEN_CIRCUIT_OHM, Finding, describe_gaps
from .fitting import FitData, FitResult, Gap, fit_channel, parameters_for
from .measurement import noise_model, time_is_real
from .records import ChannelRecord
from .rivals import Rivals

FloatArray = NDArray[np.float64]

#: A candidate must lower the held-out log-resistance RMS by at least this fraction ...
MIN_RELATIVE_GAIN = 0.015
#: ... and its penalized held-out score by at least this much (like a BIC difference).
MIN_SCORE_GAIN = 30.0
#: Added to the unloaded rows' mean squared log residual: 1 % in resistance, squared.
UNLOADED_MSE_FLOOR = 1e-4
#: The runner-up is "indistinguishable" when it achieves this share of the best gain.
AMBIGUOUS_SHARE = 0.85
#: A candidate that raises the held-out force RMS by more than this share, plus a quarter of the
#: force noise floor (smaller changes cannot be told from noise), is not added.
FORCE_TOLERANCE = 0.02
FORCE_FLOOR_SHARE = 0.25
TIME_EFFECTS = ("creep", "creep2")
MAX_FIT_ROWS = 6000

_SEPARATING_MEASUREMENT: dict[frozenset[str], str] = {
    frozenset({"creep", "creep2"}): "a long hold (20 min or more) at constant load: a second, slower element "
    "keeps drifting after the first has settled",
    frozenset({"creep", "hysteresis"}): "an unload-and-hold and ramps at two rates: creep depends on time, "
    "hysteresis only on the load direction",
    frozenset({"creep2", "hysteresis"}): "an unload-and-hold and ramps at two rates: creep depends on time, "
    "hysteresis only on the load direction",
    frozenset({"contact", "series_resistance"}): "loads spanning 0.2-8 N: contact falls as 1/sqrt(F), a "
    "series resistance stays constant",
    frozenset(
        {"contact", "leakage"}
    ): "the unloaded resistance and loads below 0.5 N, where leakage caps the reading",
    frozenset({"series_resistance", "leakage"}): "loads at both ends of the range: a series resistance shows "
    "at high force, leakage at low force",
    frozenset({"temperature", "creep"}): "a temperature step at constant load",
    frozenset({"temperature", "creep2"}): "a temperature step at constant load",
    frozenset({"temperature", "hysteresis"}): "a temperature step at constant load",
}
_DEFAULT_MEASUREMENT = (
    "a record with log-spaced loads from 0.2 to 8 N, long holds, an unload-and-hold, ramps at two rates, "
    "several cycles and a temperature step at constant load"
)


def separating_measurement(a: str, b: str) -> str:
    """The measurement that would tell effects ``a`` and ``b`` apart, in words."""
    return _SEPARATING_MEASUREMENT.get(frozenset({a, b}), _DEFAULT_MEASUREMENT)


@dataclass(frozen=True)
class CandidateScore:
    """A candidate effect refitted and scored on held-out rows."""

    effect: str
    added_parameters: int
    gap_test: Gap
    score: float  # penalized: n ln(mse_held_out) + k ln(n); lower is better
    fit: FitResult


@dataclass(frozen=True)
class Step:
    """One round of the workflow."""

    effects_before: tuple[str, ...]
    fit_before: FitResult
    findings: tuple[Finding, ...]
    candidates: tuple[CandidateScore, ...]
    added: str | None
    evidence: str
    ambiguous_with: str | None = None


@dataclass(frozen=True)
class DiscrepancyReport:
    """The whole run."""

    record: str
    channel: str
    baseline: tuple[str, ...]
    candidates: tuple[str, ...]
    steps: tuple[Step, ...]
    final_fit: FitResult
    notes: tuple[str, ...] = field(default=())
    rivals: Rivals | None = None
    noise_floor_log: float = math.nan
    noise_description: str = ""

    def rival_summary(self) -> str:
        """The final model beside the line and the lookup on the same held-out rows, in words."""
        if self.rivals is None:
            return "no conductance line could be fitted"
        from .rivals import verdict

        model = self.final_fit.gap_test.force_rms_n
        line, lookup = self.rivals.line_force_rms_n, self.rivals.lookup_force_rms_n
        return (
            f"held-out force RMS: model {model:.4g} N, conductance line {line:.4g} N, "
            f"monotone lookup {lookup:.4g} N; {verdict(model, line)}"
        )

    @property
    def added(self) -> list[str]:
        return [s.added for s in self.steps if s.added]

    def as_json(self) -> dict[str, Any]:
        """The spec's JSON object (plus extra keys the spec allows)."""
        baseline_fit = self.steps[0].fit_before
        return {
            "record": self.record,
            "baseline": list(self.baseline),
            "added": self.added,
            "final": list(self.final_fit.effects),
            "gap_before": _gap_json(baseline_fit.gap_test),
            "gap_after": _gap_json(self.final_fit.gap_test),
            "steps": [
                {
                    "added": s.added,
                    "evidence": s.evidence,
                    "gap": _gap_json(_chosen(s).gap_test),
                    "candidates": [
                        {
                            "effect": c.effect,
                            "added_parameters": c.added_parameters,
                            "score": round(c.score, 3),
                            "gap": _gap_json(c.gap_test),
                        }
                        for c in s.candidates
                    ],
                }
                for s in self.steps
                if s.added
            ],
            "channel": self.channel,
            "candidates": list(self.candidates),
            "notes": list(self.notes),
            "rivals": None
            if self.rivals is None
            else {
                "line_force_rms_n": self.rivals.line_force_rms_n,
                "lookup_force_rms_n": self.rivals.lookup_force_rms_n,
                "model_force_rms_n": self.final_fit.gap_test.force_rms_n,
                "verdict": self.rival_summary(),
            },
            "noise": {"floor_log_resistance": self.noise_floor_log, "description": self.noise_description},
            "ambiguous": [
                {"added": s.added, "runner_up": s.ambiguous_with} for s in self.steps if s.ambiguous_with
            ],
        }


def _chosen(step: Step) -> FitResult:
    for c in step.candidates:
        if c.effect == step.added:
            return c.fit
    return step.fit_before


def _gap_json(gap: Gap) -> dict[str, float | None]:
    def clean(x: float) -> float | None:
        return None if math.isnan(x) else round(x, 6)

    return {"log_resistance_rms": clean(gap.log_resistance_rms), "force_rms_n": clean(gap.force_rms_n)}


def decimate(channel: ChannelRecord, max_rows: int = MAX_FIT_ROWS) -> ChannelRecord:
    """Keep every k-th row so that at most ``max_rows`` remain (the fit's cost is linear in rows)."""
    n = channel.n_samples
    if n <= max_rows:
        return channel
    step = math.ceil(n / max_rows)
    sl = slice(None, None, step)
    return ChannelRecord(
        name=channel.name,
        time_s=channel.time_s[sl],
        resistance_ohm=channel.resistance_ohm[sl],
        force_n=None if channel.force_n is None else channel.force_n[sl],
        temperature_c=None if channel.temperature_c is None else channel.temperature_c[sl],
        line=channel.line[sl],
    )


def default_candidates(
    channel: ChannelRecord, effects: Sequence[str], real_time: bool = True
) -> tuple[tuple[str, ...], list[str]]:
    """Every spec effect not yet in the model; ``temperature`` only where the record has it,
    ``creep``/``creep2`` only where it has real time.

    ``creep2`` is a *second* Kelvin element, so it is a candidate once ``creep`` is in.
    """
    notes: list[str] = []
    out = [e for e in EFFECT_NAMES if e != "tunneling" and e not in effects]
    if not real_time:
        gone = [e for e in out if e in TIME_EFFECTS]
        out = [e for e in out if e not in TIME_EFFECTS]
        if gone:
            notes.append(
                f"{', '.join(gone)} not candidates: the record has no real time (its metadata says "
                "'time: none' or a sample index), so time-dependent effects cannot be identified"
            )
    if "creep" not in effects and "creep2" in out:
        out.remove("creep2")
    temps = channel.temperature_c
    if "temperature" in out and (temps is None or float(np.ptp(temps)) < 1.0):
        out.remove("temperature")
        notes.append(
            "temperature is not a candidate: the record has no temperature column"
            if temps is None
            else "temperature is not a candidate: the record's temperature varies by less than 1 K"
        )
    return tuple(out), notes


def run_discrepancy(
    channel: ChannelRecord,
    baseline: Iterable[str] = ("tunneling",),
    candidates: Iterable[str] | None = None,
    prior: SensorParams | None = None,
    record_name: str = "",
    max_steps: int = 6,
    metadata: Mapping[str, str] | None = None,
) -> DiscrepancyReport:
    """Run the workflow on one channel (see the module docstring)."""
    meta = dict(metadata or {})
    real_time = time_is_real(meta)
    base = parse_effects(baseline)
    notes: list[str] = []
    if candidates is None:
        pool, why = default_candidates(channel, base, real_time)
        notes.extend(why)
    else:
        pool = tuple(e for e in parse_effects(candidates) if e != "tunneling" and e not in base)
        if not real_time and any(e in TIME_EFFECTS for e in pool):
            notes.append("creep/creep2 not candidates: the record has no real time")
            pool = tuple(e for e in pool if e not in TIME_EFFECTS)
    small = decimate(channel)
    if small.n_samples < channel.n_samples:
        notes.append(f"fitted on every {channel.n_samples // small.n_samples}th row ({small.n_samples} rows)")
    data, prior, extra = prepare(small, meta, prior)
    notes.extend(extra)
    current = base
    try:
        rivals: Rivals | None = Rivals.fit(data.force_n, data.resistance_ohm, data.train, data.test)
    except ValueError:
        rivals = None
    force_floor = _force_floor(data, rivals)
    fit = fit_channel(data, current, prior)
    steps: list[Step] = []
    remaining = list(pool)
    for _ in range(max_steps):
        findings = describe_gaps(data, fit)
        scored = tuple(
            sorted(
                (_score(data, current, e, prior) for e in remaining),
                key=lambda c: c.score,
            )
        )
        decision, evidence, ambiguous = _decide(fit, data, scored, findings, force_floor)
        steps.append(Step(current, fit, findings, scored, decision, evidence, ambiguous))
        if decision is None:
            break
        current = parse_effects((*current, decision))
        fit = next(c.fit for c in scored if c.effect == decision)
        remaining.remove(decision)
        if (
            decision == "creep"
            and candidates is None
            and "creep2" not in remaining
            and "creep2" not in current
        ):
            remaining.append("creep2")
        if not remaining:
            steps.append(Step(current, fit, describe_gaps(data, fit), (), None, "no candidates left"))
            break
    floor = _floor(data)
    return DiscrepancyReport(
        record=record_name,
        channel=channel.name,
        baseline=base,
        candidates=pool,
        steps=tuple(steps),
        final_fit=fit,
        notes=tuple(notes),
        rivals=rivals,
        noise_floor_log=floor,
        noise_description=extra_description(small, meta),
    )


def prepare(
    channel: ChannelRecord, metadata: Mapping[str, str], prior: SensorParams | None
) -> tuple[FitData, SensorParams, list[str]]:
    """Fit data weighted by the measurement model, and a prior whose force range covers the record."""
    notes: list[str] = []
    prior = prior or SensorParams()
    if channel.force_n is None:
        return FitData.from_channel(channel), prior, notes
    noise = noise_model(metadata, channel.force_n, channel.resistance_ohm)
    if noise.estimated:
        notes.append("no front-end metadata: " + noise.describe())
    data = FitData.from_channel(channel, sigma_log=noise.sigma_log)
    loaded = data.force_n[data.usable]
    if loaded.size and float(loaded.max()) > prior.force_max_n:
        notes.append(
            f"the record's forces reach {float(loaded.max()):.4g} N, above force_max_n = "
            f"{prior.force_max_n:g} N: the range is widened to the record's for the fit"
        )
        prior = replace(prior, force_max_n=float(loaded.max()))
    return data, prior, notes


def extra_description(channel: ChannelRecord, metadata: Mapping[str, str]) -> str:
    f = channel.force_n
    return "" if f is None else noise_model(metadata, f, channel.resistance_ohm).describe()


def _force_floor(data: FitData, rivals: Rivals | None) -> float:
    """The held-out force RMS the log-R noise alone causes (0 when unknown)."""
    if rivals is None or data.sigma_log is None:
        return 0.0
    rows = data.test & (data.force_n > 0)
    value = rivals.force_noise_floor_n(data.sigma_log[rows], data.resistance_ohm[rows])
    return value if math.isfinite(value) else 0.0


def _floor(data: FitData) -> float:
    if data.sigma_log is None:
        return math.nan
    s = data.sigma_log[data.test & (data.force_n > 0)]
    s = s[np.isfinite(s)]
    return float(np.sqrt(np.mean(s * s))) if s.size else math.nan


def _score(
    data: FitData, current: tuple[str, ...], effect: str, prior: SensorParams | None
) -> CandidateScore:
    effects = parse_effects((*current, effect))
    fit = fit_channel(data, effects, prior)
    added = len(parameters_for(effects)) - len(parameters_for(current))
    return CandidateScore(effect, added, fit.gap_test, _penalized(fit, data), fit)


def _penalized(fit: FitResult, data: FitData) -> float:
    """Held-out score, lower is better: the Gaussian log-likelihood of two groups of rows,
    each with its own variance, plus a BIC penalty:
    ``n_l ln(mse_l) + n_u ln(mse_u + UNLOADED_MSE_FLOOR) + k ln(n_train)``.

    The loaded rows (``l``) carry the physics. The unloaded rows (``u``) are compared with
    both readings capped at the open-circuit level: a model that reads finite where the
    sensor is open (or the reverse) raises ``mse_u``, which is what tells an open contact at
    rest from a constant series resistance, and a leakage path from an open contact. The two
    groups have separate variances because one inconsistent unloaded row (a reading taken
    while the load changed, ln(1e8 / 3e4)^2 = 65) would otherwise swamp the loaded rows'
    squared residuals of about 1e-4 and hide every improvement of the physics.
    """
    score = fit.n_parameters * math.log(max(fit.n_train, 2))
    loaded = data.held_out & data.usable & (data.force_n > 0.0)
    unloaded = data.held_out & (data.force_n <= 0.0)
    weights = data.weights()
    for rows, floor in ((loaded, 0.0), (unloaded, UNLOADED_MSE_FLOOR)):
        with np.errstate(divide="ignore", invalid="ignore"):
            measured = np.log(np.minimum(data.resistance_ohm[rows], OPEN_CIRCUIT_OHM))
            model = np.log(np.minimum(fit.model_ohm[rows], OPEN_CIRCUIT_OHM))
        res = measured - model
        if floor == 0.0:
            res = res * weights[rows]
        res = res[np.isfinite(res)]
        if res.size == 0:
            continue
        mse = float(np.mean(res * res)) + floor
        if mse <= 0:
            return -math.inf
        score += res.size * math.log(mse)
    return score


def _decide(
    fit: FitResult,
    data: FitData,
    scored: Sequence[CandidateScore],
    findings: Sequence[Finding],
    force_floor: float = 0.0,
) -> tuple[str | None, str, str | None]:
    """The candidate to add (or None), the evidence in words, and the runner-up when they tie.

    A candidate must win on held-out log-R (score and relative gain) and must not make the
    held-out force worse. When the runner-up gains nearly as much, the better one is still
    added and the runner-up named; the separating measurement is named only when the record
    lacks it.
    """
    if not scored:
        return None, "no candidates to try", None
    now = _penalized(fit, data)
    now_rms = fit.gap_test.log_resistance_rms
    now_force = fit.gap_test.force_rms_n
    table = "; ".join(
        f"{c.effect} {c.gap_test.log_resistance_rms:.4f} / {c.gap_test.force_rms_n:.4g} N" for c in scored
    )
    worse_force = [c.effect for c in scored if _worse_force(c.gap_test.force_rms_n, now_force, force_floor)]
    eligible = [c for c in scored if c.effect not in worse_force]
    skipped = (
        f"; not added because they make the held-out force worse: {', '.join(worse_force)}"
        if worse_force
        else ""
    )
    if not eligible:
        return (
            None,
            f"no candidate helps the force: now {now_rms:.4f} / {now_force:.4g} N; {table}{skipped}",
            None,
        )
    best = eligible[0]
    gain = now - best.score
    rel = 1.0 - best.gap_test.log_resistance_rms / now_rms if now_rms > 0 else 0.0
    if gain < MIN_SCORE_GAIN or rel < MIN_RELATIVE_GAIN:
        return (
            None,
            f"no candidate helps clearly: held-out log-resistance RMS / force RMS {now_rms:.4f} / "
            f"{now_force:.4g} N now; with each candidate: {table}{skipped}",
            None,
        )
    runner_up = None
    tie = ""
    if len(eligible) > 1:
        second = eligible[1]
        gain2 = now - second.score
        rel2 = 1.0 - second.gap_test.log_resistance_rms / now_rms
        if gain2 >= AMBIGUOUS_SHARE * gain and rel2 >= AMBIGUOUS_SHARE * rel:
            runner_up = second.effect
            tie = (
                f"; {second.effect} fits nearly as well (held-out log-R RMS "
                f"{second.gap_test.log_resistance_rms:.4f} against {best.gap_test.log_resistance_rms:.4f}), "
                f"{best.effect} is added as the better one"
            )
            missing = _missing_measurement(data, best.effect, second.effect)
            if missing:
                tie += f"; to separate them, record {missing}"
    where = f" ({findings[0].sentence})" if findings else ""
    evidence = (
        f"held-out log-resistance RMS {now_rms:.4f} -> {best.gap_test.log_resistance_rms:.4f} and force RMS "
        f"{now_force:.4g} -> {best.gap_test.force_rms_n:.4g} N with {best.effect} (+{best.added_parameters} "
        f"parameters, score {now:.1f} -> {best.score:.1f}){where}{tie}; all candidates: {table}{skipped}"
    )
    return best.effect, evidence, runner_up


def _worse_force(candidate: float, now: float, force_floor: float = 0.0) -> bool:
    if not (math.isfinite(candidate) and math.isfinite(now)):
        return False
    return candidate > now * (1.0 + FORCE_TOLERANCE) + max(1e-3, FORCE_FLOOR_SHARE * force_floor)


def _missing_measurement(data: FitData, a: str, b: str) -> str:
    """The separating measurement, or "" when the record already has it (force span for the
    force-range pairs)."""
    pair = frozenset({a, b})
    loaded = data.force_n[data.usable & (data.force_n > 0)]
    spans = (
        loaded.size and float(np.percentile(loaded, 2)) <= 0.25 and float(np.percentile(loaded, 98)) >= 7.0
    )
    if spans and pair in _FORCE_RANGE_PAIRS:
        return ""
    return separating_measurement(a, b)


_FORCE_RANGE_PAIRS = {
    frozenset({"contact", "series_resistance"}),
    frozenset({"contact", "leakage"}),
    frozenset({"series_resistance", "leakage"}),
}
