"""The discrepancy workflow: where model and measurement disagree, which effect is missing.

Starting from a baseline model (by default ``tunneling``, the model the paper improves on):

1. fit the current model to the record (``fitting.fit_channel``);
2. describe where it disagrees: log-resistance residuals by force level, by time since the
   last load change, loading against unloading, by temperature and by load cycle;
3. refit with each candidate effect added and score it on held-out segments of the record,
   with a penalty for the parameters it adds;
4. add the best candidate only if it wins clearly on held-out log-R, or failing that, one that
   clearly lowers the held-out force and answers a disagreement of step 2 on its own axis
   (``discrepancy_choice``); say so when two candidates cannot be told apart, with the
   measurement that would separate them; repeat until none helps.

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
from .diagnostics import Finding, describe_gaps
from .discrepancy_choice import CandidateScore
from .discrepancy_choice import decide as _decide
from .discrepancy_choice import penalized as _penalized
from .fitting import FitData, FitResult, Gap, fit_channel, parameters_for
from .measurement import noise_model, time_is_real
from .records import ChannelRecord
from .rivals import Rivals

FloatArray = NDArray[np.float64]

TIME_EFFECTS = ("creep", "creep2")
MAX_FIT_ROWS = 6000


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
