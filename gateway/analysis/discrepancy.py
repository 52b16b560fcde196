"""The discrepancy workflow: where model and measurement disagree, which effect is missing.

Starting from a baseline model (by default ``tunneling``, the model the paper improves on):

1. fit the current model to the record (``fitting.fit_channel``);
2. describe where it disagrees: log-resistance residuals by force level, by time since the
   last load change, loading against unloading, by temperature and by load cycle;
3. refit with each candidate effect added and score it on held-out segments of the record,
   with a penalty for the parameters it adds;
4. add the best candidate only if it wins clearly on held-out log-R, or failing that, one that
   clearly lowers the held-out force and answers a disagreement of step 2 on its own axis
   (``discrepancy_choice``); on either route, never one whose held-out force read with the
   tracked state (the drift-corrected inversion the runtime runs) is worse than the current
   model's; say so when two candidates cannot be told apart, with the measurement that would
   separate them; repeat until none helps;
5. when the final model's held-out gap is still well above the noise (log-R RMS above
   ``UNEXPLAINED_FLOOR_RATIO`` x the noise floor) or it reads force worse than the best static
   rival (the line or the lookup, by more than the verdict's 2 % tie), say that an unexplained
   residual remains, show its structure (``diagnostics.residual_structure``) and name the best
   empirical alternative (the line, the lookup, and whatever ``alternatives`` adds).

The JSON summary keeps the keys and meanings of ``docs/record-format.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model import EFFECT_NAMES, SensorParams, parse_effects
from .candidates import rank_candidates
from .diagnostics import Finding, ResidualStructure, describe_gaps, residual_structure
from .discrepancy_choice import CandidateScore, refusal
from .discrepancy_choice import decide as _decide
from .discrepancy_choice import penalized as _penalized
from .fitting import FitData, FitResult, Gap, fit_channel, parameters_for
from .measurement import noise_model, time_is_real
from .records import ChannelRecord
from .rivals import Rivals

FloatArray = NDArray[np.float64]

TIME_EFFECTS = ("creep", "creep2")
MAX_FIT_ROWS = 6000
#: An unexplained residual remains when the final held-out log-R RMS exceeds this multiple of
#: the noise floor the measurement model predicts ...
UNEXPLAINED_FLOOR_RATIO = 2.0
#: ... or the final model reads held-out force worse than the best static rival (line or lookup)
#: by more than this share (the tie of ``rivals.verdict``).
UNEXPLAINED_RIVAL_TIE = 0.02

#: Further empirical models for the unexplained-residual verdict: given the fit data, each
#: (name, held-out force RMS in N on ``data.test``); the line and the lookup are always there.
Alternatives = Callable[[FitData], list[tuple[str, float]]]


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

    @property
    def tracked_before(self) -> float:
        """The held-out force RMS of the model before this step, read with the tracked state."""
        return self.fit_before.gap_test.force_rms_n

    @property
    def tracked_after(self) -> float:
        """The same after this step (the added candidate's; the model's own when nothing was added)."""
        return _chosen(self).gap_test.force_rms_n

    def refused(self) -> list[tuple[CandidateScore, str]]:
        """The candidates the tracked-force rule refused at this step, with the reason."""
        now = self.tracked_before
        return [(c, why) for c in self.candidates if (why := refusal(c, now)) is not None]


@dataclass(frozen=True)
class UnexplainedResidual:
    """What the final model leaves: whether a residual remains that no catalogued effect
    explains, the numbers that say so, its structure and the best empirical alternative."""

    remains: bool
    log_r_rms: float
    floor_log: float
    force_rms_n: float
    best_static: tuple[str, float] | None
    alternatives: tuple[tuple[str, float], ...]
    reasons: tuple[str, ...]
    structure: ResidualStructure
    #: the effects the workflow added before this verdict
    added: tuple[str, ...] = ()

    @property
    def floor_ratio(self) -> float:
        ok = math.isfinite(self.log_r_rms) and math.isfinite(self.floor_log) and self.floor_log > 0
        return self.log_r_rms / self.floor_log if ok else math.nan

    @property
    def best_alternative(self) -> tuple[str, float] | None:
        finite = [a for a in self.alternatives if math.isfinite(a[1])]
        return min(finite, key=lambda a: a[1]) if finite else None

    def sentence(self) -> str:
        """The verdict in words (one paragraph)."""
        if not self.remains:
            return "no unexplained residual: " + "; ".join(self.reasons)
        reasons = "; ".join(self.reasons)
        words = f"AN UNEXPLAINED RESIDUAL REMAINS: no catalogued effect closes the gap ({reasons})"
        if self.added:
            names = " and ".join(self.added)
            words += (
                f"; what was added ({names}: each read the tracked held-out force better) does not close it"
            )
        words += f"; {self.structure.sentence()}"
        best = self.best_alternative
        if best is not None:
            words += f"; best empirical alternative on held-out force: {best[0]} ({best[1]:.4g} N"
            words += f", the model {self.force_rms_n:.4g} N)"
        return words

    def as_json(self) -> dict[str, Any]:
        best = self.best_alternative
        static = self.best_static
        return {
            "remains": self.remains,
            "reasons": list(self.reasons),
            "after_adding": list(self.added),
            "log_resistance_rms": _num(self.log_r_rms),
            "noise_floor_log_resistance": _num(self.floor_log),
            "floor_ratio": _num(self.floor_ratio),
            "floor_ratio_limit": UNEXPLAINED_FLOOR_RATIO,
            "force_rms_n": _num(self.force_rms_n),
            "best_static_rival": None
            if static is None
            else {"name": static[0], "force_rms_n": _num(static[1])},
            "best_alternative": None if best is None else {"name": best[0], "force_rms_n": _num(best[1])},
            "alternatives": [{"name": n, "force_rms_n": _num(v)} for n, v in self.alternatives],
            "structure": self.structure.as_json(),
            "sentence": self.sentence(),
        }


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


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
    unexplained: UnexplainedResidual | None = None

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
                    "tracked_force_rms_n": {"before": _num(s.tracked_before), "after": _num(s.tracked_after)},
                    "candidates": [
                        {
                            "effect": c.effect,
                            "added_parameters": c.added_parameters,
                            "score": round(c.score, 3),
                            "gap": _gap_json(c.gap_test),
                            "tracked_force_rms_n": _num(c.gap_test.force_rms_n),
                            "refused": refusal(c, s.tracked_before),
                        }
                        for c in s.candidates
                    ],
                }
                for s in self.steps
                if s.added
            ],
            "refused": [
                {
                    "step": i,
                    "model": list(s.effects_before),
                    "effect": c.effect,
                    "tracked_force_rms_n": {
                        "before": _num(s.tracked_before),
                        "after": _num(c.gap_test.force_rms_n),
                    },
                    "reason": why,
                }
                for i, s in enumerate(self.steps, start=1)
                for c, why in s.refused()
            ],
            "unexplained_residual": None if self.unexplained is None else self.unexplained.as_json(),
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
    return replace(
        channel,
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
    alternatives: Alternatives | None = None,
) -> DiscrepancyReport:
    """Run the workflow on one channel (see the module docstring).

    ``alternatives`` plugs further empirical models into the unexplained-residual verdict: it
    gets the fit data and returns (name, held-out force RMS on ``data.test``) pairs. By default
    they are every static curve with every drift form ``calibrate`` ranks (``candidates``),
    fitted on the same rows, so the two commands name the same best empirical calibration.
    """
    meta = dict(metadata or {})
    real_time = time_is_real(meta)
    if alternatives is None:

        def alternatives(data: FitData) -> list[tuple[str, float]]:
            return [(c.name, c.held_out_force_rms_n) for c in rank_candidates(data, real_time=real_time)]

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
    zero_noise = channel.zero_noise_note()
    if zero_noise is not None:
        notes.append(zero_noise)
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
        chosen = next((c for c in scored if c.effect == decision), None)
        # every route obeys the tracked-force rule; it is checked again where the model changes
        refused_now = None if chosen is None else refusal(chosen, fit.gap_test.force_rms_n)
        if refused_now is not None:
            evidence += f"; not added after all: {decision} {refused_now}"
            decision, ambiguous = None, None
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
    unexplained = assess_residual(data, fit, floor, rivals, alternatives, real_time, meta)
    unexplained = replace(unexplained, added=tuple(s.added for s in steps if s.added))
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
        unexplained=unexplained,
    )


def assess_residual(
    data: FitData,
    fit: FitResult,
    floor_log: float,
    rivals: Rivals | None,
    alternatives: Alternatives | None = None,
    real_time: bool = True,
    metadata: Mapping[str, str] | None = None,
) -> UnexplainedResidual:
    """Whether the final model leaves an unexplained residual (see the module docstring, 5)."""
    gap = fit.gap_test
    reasons: list[str] = []
    remains = False
    ratio = gap.log_resistance_rms / floor_log if math.isfinite(floor_log) and floor_log > 0 else math.nan
    if math.isfinite(ratio):
        above = ratio > UNEXPLAINED_FLOOR_RATIO
        remains |= above
        reasons.append(
            f"held-out log-R RMS {gap.log_resistance_rms:.4g} is {ratio:.2g} x the noise floor "
            f"{floor_log:.4g} ({'above' if above else 'within'} the {UNEXPLAINED_FLOOR_RATIO:g} x allowed)"
        )
    else:
        reasons.append("no noise floor to compare the held-out log-R RMS with")
    statics: list[tuple[str, float]] = []
    if rivals is not None:
        statics = [
            ("conductance line", rivals.line_force_rms_n),
            ("monotone lookup", rivals.lookup_force_rms_n),
        ]
    finite = [a for a in statics if math.isfinite(a[1])]
    best_static = min(finite, key=lambda a: a[1]) if finite else None
    if best_static is not None and math.isfinite(gap.force_rms_n):
        worse = gap.force_rms_n > best_static[1] * (1.0 + UNEXPLAINED_RIVAL_TIE)
        remains |= worse
        reasons.append(
            f"held-out force RMS {gap.force_rms_n:.4g} N against the best static rival's "
            f"({best_static[0]}) {best_static[1]:.4g} N ({'worse' if worse else 'not worse'} beyond the "
            f"{100 * UNEXPLAINED_RIVAL_TIE:g} % tie)"
        )
    extra = list(alternatives(data)) if alternatives is not None else []
    structure = residual_structure(data, fit, real_time, dict(metadata or {}))
    return UnexplainedResidual(
        remains=remains,
        log_r_rms=gap.log_resistance_rms,
        floor_log=floor_log,
        force_rms_n=gap.force_rms_n,
        best_static=best_static,
        alternatives=tuple((str(n), float(v)) for n, v in (*statics, *extra)),
        reasons=tuple(reasons),
        structure=structure,
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
