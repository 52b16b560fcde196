"""The discrepancy workflow's start: the sensor's best static form, and the dynamic effects
missing on top of a static curve.

**The start** (``choose_static``): the static forms compete on held-out force, read by the
runtime's tracker on the same held-out rows: the paper's physics in its best static form (from
``tunneling``, the static-shape effects ``contact``, ``series_resistance`` and ``leakage`` that
the workflow adds), and every static curve of the ranking (``candidates.rank_candidates``:
power law, line, lookup). The best one is where the workflow starts. A sensor whose static
curve the physics cannot take (an FSR's power law) is then examined from its own curve, and
the static-shape effects are not candidates: they are the physics' own way of bending its
curve, and a curve that already reads better does not lack them.

**On top of a static curve** (``curve_steps``): the dynamic effects are the drift forms the
ranking fits: ``creep`` (one Kelvin element, its recovery time constant free), ``creep2`` (a
second, slower one, once ``creep`` is in) and ``hysteresis``. Each step tries every effect not
yet in, on the curve kind that reads best with it, and adds the one that lowers the tracked
held-out force most, if it lowers it by at least ``MIN_FORCE_GAIN`` (the force route's share,
``discrepancy_choice``), the tracked-force rule allows it (never a worse reading), and the
product of its held-out force ratio (against the current model) and held-out log-R ratio
(against the same curve kind without it: a kind's shape is not the effect's doing) is below 1.
The two measures weigh the rows differently (log-R is the force error relative to the curve's
slope, heaviest at light loads): an effect that only trades the light loads' error for a
little of the heavy ones' is not added (on the clean power-law record, hysteresis on top of
creep: force 0.0915 -> 0.0885 N, -3.3 %, log-R 0.0102 -> 0.0117, +15 %); one whose force gain
outweighs its log-R cost is (a third off the force for a sixth more log-R).
``temperature`` has no curve form: where the record carries a temperature, its residual's
structure shows it.

A curve's log-R residual (``curve_fit``) is the measured resistance against the curve's own
at the apparent force the reference and the tracked state give, x_hat - (F_tracked - F_ref):
the force error mapped back through the curve (exact for creep, to first order in beta for
hysteresis). It puts the curve on the same noise floor as the physics.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..model import SensorParams
from .candidates import Candidate
from .diagnostics import describe_gaps
from .discrepancy_choice import (
    AMBIGUOUS_SHARE,
    MIN_FORCE_GAIN,
    CandidateScore,
    Step,
    penalized,
    refusal,
    separating_measurement,
)
from .fitting import FitData, FitResult, Gap, ParameterEstimate
from .objectives import log_ratio

#: The ranking's static curve kinds (``candidates.rank_candidates``).
CURVE_KINDS = ("power_law", "line", "lookup")
#: The physics' static-shape effects: candidates while its best static form is sought.
STATIC_EFFECTS = ("contact", "series_resistance", "leakage")
#: The dynamic effects a curve can carry, in the order they are written.
CURVE_EFFECTS = ("creep", "creep2", "hysteresis")
PHYSICS = "physics"


def form_effects(form: str) -> tuple[str, ...] | None:
    """The catalogued effects a drift form carries (``creep2+hysteresis`` -> creep, creep2,
    hysteresis; ``static`` -> none); None for a form with a term outside the catalogue."""
    parts = set(form.split("+")) - {"static"}
    if not parts <= set(CURVE_EFFECTS):
        return None
    out = []
    if parts & {"creep", "creep2"}:
        out.append("creep")
    if "creep2" in parts:
        out.append("creep2")
    if "hysteresis" in parts:
        out.append("hysteresis")
    return tuple(out)


def kind_and_form(candidate: Candidate) -> tuple[str, str]:
    """A ranked candidate's curve kind and drift form, from its name ``kind + form``."""
    kind, _, form = candidate.name.partition(" + ")
    return kind.strip(), form.strip() or "static"


def curve_label(kind: str, effects: Sequence[str]) -> str:
    """``power_law + static``, ``power_law + creep, creep2``: a curve with its effects."""
    return f"{kind} + {', '.join(effects) if effects else 'static'}"


@dataclass(frozen=True)
class StaticChoice:
    """The static forms on held-out force (N), best first, and the one the workflow starts
    from: ``PHYSICS`` or a curve kind."""

    options: tuple[tuple[str, float], ...]
    chosen: str
    physics_effects: tuple[str, ...]

    @property
    def physics_name(self) -> str:
        return f"the paper's physics ({', '.join(self.physics_effects)})"

    def name(self, option: str) -> str:
        return self.physics_name if option == PHYSICS else f"{option} (static)"

    def sentence(self) -> str:
        figures = ", ".join(f"{self.name(n)} {v:.4g} N" for n, v in self.options)
        return f"started from the best static form on held-out force, {self.name(self.chosen)}: {figures}"

    def as_json(self) -> dict[str, Any]:
        return {
            "chosen": self.chosen,
            "physics_effects": list(self.physics_effects),
            "options": [{"name": n, "force_rms_n": v if math.isfinite(v) else None} for n, v in self.options],
            "sentence": self.sentence(),
        }


def static_curves(ranking: Sequence[Candidate]) -> dict[str, Candidate]:
    """The ranking's static curves by kind."""
    out: dict[str, Candidate] = {}
    for c in ranking:
        kind, form = kind_and_form(c)
        if form == "static":
            out.setdefault(kind, c)
    return out


def choose_static(physics: FitResult, ranking: Sequence[Candidate]) -> StaticChoice:
    """The best static form on held-out force (module docstring); the physics on a tie."""
    options = [(PHYSICS, physics.gap_test.force_rms_n)]
    options += [(kind, c.held_out_force_rms_n) for kind, c in static_curves(ranking).items()]
    order = sorted(options, key=lambda o: (o[1] if math.isfinite(o[1]) else math.inf, o[0] != PHYSICS))
    chosen = order[0][0] if math.isfinite(order[0][1]) else PHYSICS
    return StaticChoice(tuple(order), chosen, tuple(physics.effects))


def curve_fit(data: FitData, candidate: Candidate, effects: tuple[str, ...]) -> FitResult:
    """A ranked curve as a fit of the workflow (module docstring): its tracked force on every
    row, its resistance at the apparent force of the reference with the tracked state, the
    log-R residual and the gaps on the training and held-out rows."""
    ch = candidate.channel
    force = np.asarray(candidate.force_n, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        x_hat = ch.static_force(data.resistance_ohm)
        apparent = x_hat - (force - data.force_n)
        model = ch.gain * np.asarray(ch.curve.resistance(np.maximum(apparent - ch.offset_n, 0.0)))
    model = np.where(np.isfinite(model) | np.isposinf(model), model, np.nan)
    residual = log_ratio(data.resistance_ohm, model)

    def gap(rows: np.ndarray[Any, np.dtype[np.bool_]]) -> Gap:
        r = residual[rows]
        r = r[np.isfinite(r)]
        e = (force - data.force_n)[rows]
        e = e[np.isfinite(e)]
        return Gap(
            float(np.sqrt(np.mean(r * r))) if r.size else math.nan,
            float(np.sqrt(np.mean(e * e))) if e.size else math.nan,
        )

    note = "curve and drift, as calibrate ranks them"
    estimates = tuple(
        ParameterEstimate(k, v, math.nan, math.nan, True, note) for k, v in _active(ch.table()).items()
    )
    return FitResult(
        effects=effects,
        params=SensorParams(),
        estimates=estimates,
        correlation_names=(),
        correlation=np.zeros((0, 0)),
        gap_train=gap(data.train),
        gap_test=gap(data.test),
        n_train=int(np.count_nonzero(data.train)),
        n_test=int(np.count_nonzero(data.test)),
        n_parameters=int(ch.n_parameters),
        log_residual=residual,
        model_ohm=model,
        force_inverted_n=force,
        objective="curve",
    )


def _active(table: Mapping[str, object]) -> dict[str, float]:
    """The numbers of a curve channel's table that say something: no switched-off drift term,
    no unit gain or zero offset (a lookup's knot lists are not single numbers)."""
    out = {k: float(v) for k, v in table.items() if isinstance(v, int | float) and not isinstance(v, bool)}
    switches = {"creep": "creep_fraction", "creep2": "creep2_fraction"}
    switches |= {"hysteresis": "hysteresis_fraction", "sensitivity": "sensitivity_per_n"}
    for term, switch in switches.items():
        if out.get(switch, 0.0) == 0.0:
            out = {k: v for k, v in out.items() if not k.startswith(f"{term}_")}
    if out.get("gain") == 1.0:
        del out["gain"]
    if out.get("offset_n") == 0.0:
        del out["offset_n"]
    return out


def curve_steps(
    data: FitData,
    kind: str,
    ranking: Sequence[Candidate],
    candidates: Sequence[str] = CURVE_EFFECTS,
    max_steps: int = 6,
) -> tuple[list[Step], FitResult, str]:
    """The steps on top of the static curve ``kind`` (module docstring), the final fit and
    its curve kind.

    The dynamic effects are what is sought; the curve they sit on is the one that reads best
    with them: with the effects of a step in, the curve kind is chosen again among those the
    ranking fitted with them (a creep the static fit took for part of its shape leaves a
    lookup bent where a power law is not), so a kind chosen statically does not hold the
    effects to its own shape."""
    fitted: dict[tuple[str, frozenset[str]], tuple[Candidate, tuple[str, ...]]] = {}
    for c in ranking:
        k, form = kind_and_form(c)
        effects = form_effects(form)
        if effects is not None:
            fitted.setdefault((k, frozenset(effects)), (c, effects))
    if (kind, frozenset()) not in fitted:
        raise ValueError(f"the ranking has no static {kind} curve to start from")
    cache: dict[tuple[str, frozenset[str]], FitResult] = {}

    def fit_of(key: tuple[str, frozenset[str]]) -> FitResult:
        if key not in cache:
            c, names = fitted[key]
            cache[key] = curve_fit(data, c, names)
        return cache[key]

    def drift_parameters(key: tuple[str, frozenset[str]]) -> int:
        """The parameters of the drift alone: a lookup's knots are not the effect's."""
        return int(fitted[key][0].channel.drift.n_parameters)

    def best_kind(effects: frozenset[str]) -> str:
        kinds = [k for k, e in fitted if e == effects]
        return min(kinds, key=lambda k: _finite_or_inf(fitted[(k, effects)][0].held_out_force_rms_n))

    current: frozenset[str] = frozenset()
    fit = fit_of((kind, current))
    steps: list[Step] = []
    for _ in range(max_steps):
        options = [
            e
            for e in CURVE_EFFECTS
            if e in candidates
            and e not in current
            and (e != "creep2" or "creep" in current)
            and any(eff == current | {e} for _, eff in fitted)
        ]
        on: dict[str, str] = {e: best_kind(current | {e}) for e in options}
        scored = sorted(
            (
                CandidateScore(
                    e,
                    drift_parameters((on[e], current | {e})) - drift_parameters((kind, current)),
                    fit_of((on[e], current | {e})).gap_test,
                    penalized(fit_of((on[e], current | {e})), data),
                    fit_of((on[e], current | {e})),
                )
                for e in options
            ),
            key=lambda c: _finite_or_inf(c.gap_test.force_rms_n),
        )
        findings = describe_gaps(data, fit)
        # each effect's log-R is judged against its own curve without it: a curve kind's shape
        # is not the effect's doing
        without = {e: fit_of((on[e], current)) if (on[e], current) in fitted else fit for e in options}
        added, evidence, ambiguous = decide_on_curve(fit, scored, kind, on, without)
        label = curve_label(kind, [e for e in CURVE_EFFECTS if e in current])
        steps.append(Step(fit.effects, fit, findings, tuple(scored), added, evidence, ambiguous, label))
        if added is None:
            break
        current = current | {added}
        kind = on[added]
        fit = fit_of((kind, current))
    return steps, fit, kind


def _finite_or_inf(x: float) -> float:
    return x if math.isfinite(x) else math.inf


def decide_on_curve(
    fit: FitResult,
    scored: Sequence[CandidateScore],
    kind: str = "",
    on: Mapping[str, str] | None = None,
    without: Mapping[str, FitResult] | None = None,
) -> tuple[str | None, str, str | None]:
    """The effect to add on a curve (or None), the evidence in words and the runner-up when
    they tie (module docstring): the lowest tracked held-out force among the candidates the
    tracked-force rule allows whose held-out force and log-R ratios multiply to less than 1,
    if it is at least ``MIN_FORCE_GAIN`` below the current one. ``kind``: the current curve; ``on``: the curve
    each candidate reads best on; ``without``: that curve fitted without the candidate, whose
    held-out log-R the candidate's is compared with (default: ``fit``'s)."""
    on = on or {}

    def where(effect: str) -> str:
        other = on.get(effect, kind)
        return f" (on the {other} curve, which reads best with it)" if other != kind else ""

    if not scored:
        return None, "no candidates to try", None
    now = fit.gap_test.force_rms_n
    now_log = fit.gap_test.log_resistance_rms
    table = "; ".join(
        f"{c.effect}{where(c.effect)} {c.gap_test.force_rms_n:.4g} N, log-R "
        f"{c.gap_test.log_resistance_rms:.4f}"
        for c in scored
    )
    refused = {c.effect: why for c in scored if (why := refusal(c, now)) is not None}
    for c in scored:
        after_log = c.gap_test.log_resistance_rms
        base = (without or {}).get(c.effect, fit)
        before_log = base.gap_test.log_resistance_rms
        ok = before_log > 0 and now > 0
        both = (after_log / before_log) * (c.gap_test.force_rms_n / now) if ok else math.nan
        if c.effect not in refused and not (math.isfinite(both) and both < 1.0):
            curve = f" on the {on.get(c.effect, kind)} curve" if base is not fit else ""
            refused[c.effect] = (
                f"reads the held-out log-R worse{curve} ({before_log:.4f} -> {after_log:.4f}) by more than "
                f"it reads the force better ({now:.4g} -> {c.gap_test.force_rms_n:.4g} N)"
            )
    skipped = "; ".join(f"{e} {why}" for e, why in refused.items())
    skipped = f"; not added: {skipped}" if skipped else ""
    eligible = [c for c in scored if c.effect not in refused]

    def gain(c: CandidateScore) -> float:
        after = c.gap_test.force_rms_n
        return 1.0 - after / now if math.isfinite(after) and math.isfinite(now) and now > 0 else 0.0

    if not eligible or gain(eligible[0]) < MIN_FORCE_GAIN:
        return (
            None,
            f"no effect lowers the tracked held-out force by {100 * MIN_FORCE_GAIN:g} % or more and reads "
            f"the held-out log-R better: now {now:.4g} N / log-R {now_log:.4f}; with each: {table}{skipped}",
            None,
        )
    best = eligible[0]
    evidence = (
        f"tracked held-out force RMS {now:.4g} -> {best.gap_test.force_rms_n:.4g} N with {best.effect}"
        f"{where(best.effect)} (-{100 * gain(best):.1f} %, {best.added_parameters:+d} drift parameters), "
        f"held-out log-R RMS {now_log:.4f} -> {best.gap_test.log_resistance_rms:.4f}; "
        f"all candidates: {table}{skipped}"
    )
    runner_up = None
    if len(eligible) > 1 and gain(eligible[1]) >= AMBIGUOUS_SHARE * gain(best):
        runner_up = eligible[1].effect
        evidence += (
            f"; {runner_up} reads nearly as well ({eligible[1].gap_test.force_rms_n:.4g} N), "
            f"{best.effect} is added as the better one; to separate them, record "
            f"{separating_measurement(best.effect, runner_up)}"
        )
    return best.effect, evidence, runner_up
