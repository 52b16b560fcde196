"""The discrepancy workflow: where model and measurement disagree, which effect is missing.

Starting from the sensor's best static form (``discrepancy_static.choose_static``, the default,
``baseline=None``): the paper's physics in its best static form (``tunneling`` and the
static-shape effects ``contact``, ``series_resistance``, ``leakage`` that steps 1-4 add) and
every static curve of ``calibrate``'s ranking (power law, line, lookup) compete on the tracked
held-out force, and the best one is the baseline. On the physics the workflow goes on with the
remaining effects as below; on a curve it adds the dynamic effects missing on top of it
(``discrepancy_static.curve_steps``: creep, creep2, hysteresis, on the tracked held-out force).
A baseline of effects (``baseline=("tunneling",)``, the model the paper improves on) starts
from the physics as given, and a curve kind (``baseline=("power_law",)``) from that curve.

On the physics:

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
5. say whether an unexplained residual remains (``discrepancy_residual.assess_residual``: the
   held-out gap well above the noise, a reading worse than the best static rival, or a clear
   trend with the time since the record's start or with the load history at any level), show
   its structure (``diagnostics.residual_structure``) and name the best empirical alternative.

Every verdict compares with the best static rival (the line, the lookup, any static curve of
the ranking: ``rivals.verdict``). The JSON summary keeps the keys and meanings of
``docs/record-format.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model import EFFECT_NAMES, SensorParams, parse_effects
from .candidates import Candidate, rank_candidates
from .diagnostics import describe_gaps
from .discrepancy_choice import CandidateScore, Step, refusal
from .discrepancy_choice import decide as _decide
from .discrepancy_choice import penalized as _penalized
from .discrepancy_residual import (
    UNEXPLAINED_FLOOR_RATIO,
    UNEXPLAINED_RIVAL_TIE,
    UnexplainedResidual,
    assess_residual,
)
from .discrepancy_static import (
    CURVE_EFFECTS,
    CURVE_KINDS,
    PHYSICS,
    STATIC_EFFECTS,
    StaticChoice,
    choose_static,
    curve_label,
    curve_steps,
    static_curves,
)
from .fitting import FitData, FitResult, Gap, fit_channel, parameters_for
from .load_history import StartLoad, channel_start_load
from .measurement import noise_model, time_is_real
from .parallel import Workers
from .records import ChannelRecord
from .rivals import Rivals, verdict

__all__ = [
    "UNEXPLAINED_FLOOR_RATIO",
    "UNEXPLAINED_RIVAL_TIE",
    "CandidateScore",
    "DiscrepancyReport",
    "Step",
    "UnexplainedResidual",
    "decimate",
    "default_candidates",
    "parse_baseline",
    "prepare",
    "run_discrepancy",
]

FloatArray = NDArray[np.float64]

TIME_EFFECTS = ("creep", "creep2")
MAX_FIT_ROWS = 6000
#: Further empirical models for the unexplained-residual verdict: given the fit data, each
#: (name, held-out force RMS in N on ``data.test``); the line and the lookup are always there.
Alternatives = Callable[[FitData], list[tuple[str, float]]]


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
    #: the static forms on held-out force and the one the workflow started from (None: the
    #: baseline was given)
    static_choice: StaticChoice | None = None
    #: how the record starts (loaded or at rest)
    start: StartLoad | None = None
    #: every static rival on held-out force (N): the line, the lookup, the ranking's static curves
    static_rivals: tuple[tuple[str, float], ...] = ()
    #: the final model in words: the physical model, or a curve with its effects
    model_name: str = "the physical model"

    def rival_summary(self) -> str:
        """The final model beside every static rival on the same held-out rows, and the verdict
        against the best of them (``rivals.verdict``), in words."""
        if not self.static_rivals:
            return "no static rival could be fitted"
        model = self.final_fit.gap_test.force_rms_n
        figures = ", ".join(f"{name} {v:.4g} N" for name, v in self.static_rivals)
        words = verdict(model, dict(self.static_rivals), model_name=self.model_name)
        return f"held-out force RMS: {self.model_name} {model:.4g} N, {figures}; {words}"

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
                    "model_label": s.label,
                    "evidence": s.evidence,
                    "gap": _gap_json(s.chosen.gap_test),
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
                    "model_label": s.label,
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
            if not self.static_rivals
            else {
                "line_force_rms_n": None if self.rivals is None else _num(self.rivals.line_force_rms_n),
                "lookup_force_rms_n": None if self.rivals is None else _num(self.rivals.lookup_force_rms_n),
                "model_force_rms_n": self.final_fit.gap_test.force_rms_n,
                "verdict": self.rival_summary(),
                "static": [{"name": n, "force_rms_n": _num(v)} for n, v in self.static_rivals],
            },
            "noise": {"floor_log_resistance": self.noise_floor_log, "description": self.noise_description},
            "static_form": None if self.static_choice is None else self.static_choice.as_json(),
            "final_model": self.model_name,
            "start_load": None if self.start is None else self.start.as_json(),
            "ambiguous": [
                {"added": s.added, "runner_up": s.ambiguous_with} for s in self.steps if s.ambiguous_with
            ],
        }


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


def parse_baseline(baseline: Iterable[str] | None) -> tuple[str, tuple[str, ...]]:
    """Where the workflow starts: ``("auto", ())`` for None or ``auto`` (the best static form),
    ``(kind, ())`` for one static curve kind, ``("physics", effects)`` for effect names."""
    if baseline is None:
        return "auto", ()
    tokens = [t.strip() for t in ([baseline] if isinstance(baseline, str) else baseline)]
    tokens = [t for part in tokens for t in part.split(",") if t.strip()]
    tokens = [t.strip() for t in tokens]
    if tokens == ["auto"]:
        return "auto", ()
    kinds = [t for t in tokens if t in CURVE_KINDS]
    if kinds:
        if len(tokens) != 1:
            raise ValueError(
                f"a static curve baseline is one curve kind alone ({', '.join(CURVE_KINDS)}), not "
                f"{', '.join(tokens)}: the dynamic effects on top of it are what the workflow looks for"
            )
        return kinds[0], ()
    if "auto" in tokens:
        raise ValueError("'auto' is a baseline alone: the best static form on held-out force")
    return PHYSICS, parse_effects(tokens)


def run_discrepancy(
    channel: ChannelRecord,
    baseline: Iterable[str] | None = None,
    candidates: Iterable[str] | None = None,
    prior: SensorParams | None = None,
    record_name: str = "",
    max_steps: int = 6,
    metadata: Mapping[str, str] | None = None,
    alternatives: Alternatives | None = None,
    jobs: int | None = 1,
) -> DiscrepancyReport:
    """Run the workflow on one channel (see the module docstring; ``baseline``: ``parse_baseline``).

    ``alternatives`` plugs further empirical models into the unexplained-residual verdict: it
    gets the fit data and returns (name, held-out force RMS on ``data.test``) pairs. By default
    they are every static curve with every drift form ``calibrate`` ranks (``candidates``),
    fitted on the same rows, so the two commands name the same best empirical calibration.
    ``jobs``: the processes a step's candidate fits may use (``parallel.Workers``; None: every
    core), the same report with any.
    """
    with Workers(jobs, spare_caller=False) as workers:
        return _run_discrepancy(
            channel,
            baseline,
            candidates,
            prior,
            record_name,
            max_steps,
            dict(metadata or {}),
            alternatives,
            workers,
        )


def _run_discrepancy(
    channel: ChannelRecord,
    baseline: Iterable[str] | None,
    candidates: Iterable[str] | None,
    prior: SensorParams | None,
    record_name: str,
    max_steps: int,
    meta: dict[str, str],
    alternatives: Alternatives | None,
    workers: Workers,
) -> DiscrepancyReport:
    real_time = time_is_real(meta)
    start_kind, base = parse_baseline(baseline)
    notes: list[str] = []
    zero_noise = channel.zero_noise_note()
    if zero_noise is not None:
        notes.append(zero_noise)
    pool, why = default_candidates(channel, base or ("tunneling",), real_time)
    if candidates is not None:
        pool = tuple(e for e in parse_effects(candidates) if e != "tunneling" and e not in base)
        why = []
        if not real_time and any(e in TIME_EFFECTS for e in pool):
            why.append("creep/creep2 not candidates: the record has no real time")
            pool = tuple(e for e in pool if e not in TIME_EFFECTS)
    notes.extend(why)
    small = decimate(channel)
    if small.n_samples < channel.n_samples:
        notes.append(f"fitted on every {channel.n_samples // small.n_samples}th row ({small.n_samples} rows)")
    data, prior, extra = prepare(small, meta, prior)
    notes.extend(extra)
    start = channel_start_load(channel) if channel.n_samples else None
    try:
        rivals: Rivals | None = Rivals.fit(data.force_n, data.resistance_ohm, data.train, data.test)
    except ValueError:
        rivals = None
    force_floor = _force_floor(data, rivals)
    ranking: list[Candidate] = []
    if start_kind != PHYSICS or alternatives is None:
        ranking = rank_candidates(data, real_time=real_time)
    statics: list[tuple[str, float]] = []
    if rivals is not None:
        statics += [
            ("conductance line", rivals.line_force_rms_n),
            ("monotone lookup", rivals.lookup_force_rms_n),
        ]
    further = list(alternatives(data)) if alternatives is not None else []
    further += [(c.name, c.held_out_force_rms_n) for c in ranking] if alternatives is None else []
    statics += [(c.name, c.held_out_force_rms_n) for c in static_curves(ranking).values()]
    statics += [a for a in further if a[0].endswith(" + static") and a[0] not in dict(statics)]
    further = [a for a in further if a[0] not in dict(statics)]

    choice: StaticChoice | None = None
    kind = start_kind
    if start_kind == "auto":
        static_pool = tuple(e for e in pool if e in STATIC_EFFECTS)
        first, physics_fit = _physics_steps(
            data, ("tunneling",), static_pool, prior, force_floor, max_steps, workers
        )
        choice = choose_static(physics_fit, ranking)
        kind = choice.chosen
        if kind == PHYSICS:
            if first and first[-1].added is None:
                first = first[:-1]
            rest = tuple(e for e in pool if e not in physics_fit.effects)
            more, fit = _physics_steps(
                data,
                physics_fit.effects,
                rest,
                prior,
                force_floor,
                max_steps,
                workers,
                candidates is None,
                physics_fit,
            )
            steps, base = first + more, ("tunneling",)
        else:
            notes.append(
                f"{', '.join(static_pool) or 'the static-shape effects'} not candidates: they bend the "
                f"physics' static curve, and the {kind} reads the sensor's static curve better "
                f"({choice.sentence()})"
            )
    elif start_kind == PHYSICS:
        steps, fit = _physics_steps(
            data, base, pool, prior, force_floor, max_steps, workers, candidates is None
        )
    if kind != PHYSICS:
        dynamic = tuple(e for e in pool if e in CURVE_EFFECTS) if candidates is not None else CURVE_EFFECTS
        dynamic = tuple(e for e in dynamic if real_time or e not in TIME_EFFECTS)
        if "temperature" in pool:
            notes.append(
                "temperature is not a candidate on a static curve (no curve form carries it): the "
                "residual's structure shows it"
            )
        steps, fit, kind = curve_steps(data, kind, ranking, dynamic, max_steps)
        base, pool = (), dynamic
    floor = _floor(data)
    unexplained = assess_residual(data, fit, floor, statics, further, real_time, meta, start)
    unexplained = replace(unexplained, added=tuple(s.added for s in steps if s.added))
    label = "the physical model" if kind == PHYSICS else curve_label(kind, fit.effects)
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
        static_choice=choice,
        start=start,
        static_rivals=tuple(statics),
        model_name=label,
    )


def _physics_steps(
    data: FitData,
    start: tuple[str, ...],
    pool: Sequence[str],
    prior: SensorParams | None,
    force_floor: float,
    max_steps: int,
    workers: Workers,
    creep2_follows: bool = False,
    fit: FitResult | None = None,
) -> tuple[list[Step], FitResult]:
    """Steps 1-4 of the module docstring from the physics ``start`` (fitted: ``fit``) with the
    candidates ``pool``; ``creep2_follows``: creep2 becomes a candidate once creep is added. A
    step's candidate fits are independent: ``workers`` runs them side by side."""
    current = start
    fit = fit if fit is not None else fit_channel(data, current, prior)
    steps: list[Step] = []
    remaining = list(pool)
    for _ in range(max_steps):
        findings = describe_gaps(data, fit)
        pending = [workers.submit(_score, data, current, e, prior) for e in remaining]
        scored = tuple(sorted((p.result() for p in pending), key=lambda c: c.score))
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
        if decision == "creep" and creep2_follows and "creep2" not in remaining and "creep2" not in current:
            remaining.append("creep2")
        if not remaining:
            steps.append(Step(current, fit, describe_gaps(data, fit), (), None, "no candidates left"))
            break
    return steps, fit


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
