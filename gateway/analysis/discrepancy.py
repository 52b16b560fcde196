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
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model import EFFECT_NAMES, SensorParams, parse_effects
from .fitting import FitData, FitResult, Gap, fit_channel, parameters_for
from .records import ChannelRecord

FloatArray = NDArray[np.float64]

#: A candidate must lower the held-out log-resistance RMS by at least this fraction ...
MIN_RELATIVE_GAIN = 0.015
#: ... and its penalized held-out score by at least this much (like a BIC difference).
MIN_SCORE_GAIN = 30.0
#: Readings above this are open circuits for the zero-force consistency check (a 10 kohm
#: divider with a 16-bit converter cannot tell 100 Mohm from open).
OPEN_CIRCUIT_OHM = 1e8
#: Added to the unloaded rows' mean squared log residual: 1 % in resistance, squared.
UNLOADED_MSE_FLOOR = 1e-4
#: The runner-up is "indistinguishable" when it achieves this share of the best gain.
AMBIGUOUS_SHARE = 0.85
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
class Finding:
    """One systematic disagreement, in numbers and in words."""

    axis: str  # force, time_since_change, direction, temperature, cycle
    label: str
    mean_log_residual: float
    n_rows: int
    sentence: str


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


def default_candidates(channel: ChannelRecord, effects: Sequence[str]) -> tuple[tuple[str, ...], list[str]]:
    """Every spec effect not yet in the model; ``temperature`` only where the record has it.

    ``creep2`` is a *second* Kelvin element, so it is a candidate once ``creep`` is in.
    """
    notes: list[str] = []
    out = [e for e in EFFECT_NAMES if e != "tunneling" and e not in effects]
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
) -> DiscrepancyReport:
    """Run the workflow on one channel (see the module docstring)."""
    base = parse_effects(baseline)
    notes: list[str] = []
    if candidates is None:
        pool, why = default_candidates(channel, base)
        notes.extend(why)
    else:
        pool = tuple(e for e in parse_effects(candidates) if e != "tunneling" and e not in base)
    small = decimate(channel)
    if small.n_samples < channel.n_samples:
        notes.append(f"fitted on every {channel.n_samples // small.n_samples}th row ({small.n_samples} rows)")
    data = FitData.from_channel(small)
    current = base
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
        decision, evidence, ambiguous = _decide(fit, data, scored, findings)
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
    return DiscrepancyReport(
        record=record_name,
        channel=channel.name,
        baseline=base,
        candidates=pool,
        steps=tuple(steps),
        final_fit=fit,
        notes=tuple(notes),
    )


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
    for rows, floor in ((loaded, 0.0), (unloaded, UNLOADED_MSE_FLOOR)):
        with np.errstate(divide="ignore", invalid="ignore"):
            measured = np.log(np.minimum(data.resistance_ohm[rows], OPEN_CIRCUIT_OHM))
            model = np.log(np.minimum(fit.model_ohm[rows], OPEN_CIRCUIT_OHM))
        res = measured - model
        res = res[np.isfinite(res)]
        if res.size == 0:
            continue
        mse = float(np.mean(res * res)) + floor
        if mse <= 0:
            return -math.inf
        score += res.size * math.log(mse)
    return score


def _decide(
    fit: FitResult, data: FitData, scored: Sequence[CandidateScore], findings: Sequence[Finding]
) -> tuple[str | None, str, str | None]:
    if not scored:
        return None, "no candidates to try", None
    now = _penalized(fit, data)
    now_rms = fit.gap_test.log_resistance_rms
    best = scored[0]
    gain = now - best.score
    rel = 1.0 - best.gap_test.log_resistance_rms / now_rms if now_rms > 0 else 0.0
    table = "; ".join(f"{c.effect} {c.gap_test.log_resistance_rms:.4f}" for c in scored)
    if gain < MIN_SCORE_GAIN or rel < MIN_RELATIVE_GAIN:
        return (
            None,
            f"no candidate helps clearly: held-out log-resistance RMS {now_rms:.4f} now; "
            f"with each candidate: {table}",
            None,
        )
    if len(scored) > 1:
        second = scored[1]
        gain2 = now - second.score
        rel2 = 1.0 - second.gap_test.log_resistance_rms / now_rms
        if gain2 >= AMBIGUOUS_SHARE * gain and rel2 >= AMBIGUOUS_SHARE * rel:
            return (
                None,
                f"{best.effect} and {second.effect} cannot be told apart with this record (held-out RMS "
                f"{best.gap_test.log_resistance_rms:.4f} vs {second.gap_test.log_resistance_rms:.4f}); "
                f"to separate them, record {separating_measurement(best.effect, second.effect)}",
                second.effect,
            )
    where = f" ({findings[0].sentence})" if findings else ""
    evidence = (
        f"held-out log-resistance RMS {now_rms:.4f} -> {best.gap_test.log_resistance_rms:.4f} with "
        f"{best.effect} (+{best.added_parameters} parameters, score {best.score - now:+.1f}){where}; "
        f"all candidates: {table}"
    )
    return best.effect, evidence, None


# ------------------------------------------------------------------------- diagnostics
def residual_axes(data: FitData) -> dict[str, FloatArray]:
    """Per-row coordinates along which residuals are examined."""
    t, f = data.time_s, data.force_n
    change = np.flatnonzero(np.abs(np.diff(f)) > 1e-9) + 1
    last_change = np.zeros(t.size, dtype=np.int64)
    if change.size:
        idx = np.searchsorted(change, np.arange(t.size), side="right") - 1
        last_change = np.where(idx >= 0, change[np.maximum(idx, 0)], 0)
    since = t - t[last_change]
    step = np.diff(f, prepend=f[0])
    direction = np.zeros(t.size)
    moving = np.flatnonzero(np.abs(step) > 1e-9)
    if moving.size:
        idx = np.searchsorted(moving, np.arange(t.size), side="right") - 1
        direction = np.where(idx >= 0, np.sign(step[moving[np.maximum(idx, 0)]]), 0.0)
    level = float(np.median(f[f > 0])) if np.any(f > 0) else 0.0
    ups = np.flatnonzero((f[1:] >= level) & (f[:-1] < level)) + 1
    cycle = np.searchsorted(ups, np.arange(t.size), side="right").astype(np.float64)
    axes = {"force": f, "time_since_change": since, "direction": direction, "cycle": cycle}
    if data.temperature_c is not None:
        axes["temperature"] = data.temperature_c
    return axes


def describe_gaps(data: FitData, fit: FitResult, limit: int = 4) -> tuple[Finding, ...]:
    """The largest systematic disagreements, most significant first."""
    res = fit.log_residual
    rows = data.usable & np.isfinite(res)
    if not rows.any():
        return ()
    noise = float(np.std(np.diff(res[rows]))) / math.sqrt(2.0) or 1e-12
    axes = residual_axes(data)
    findings: list[tuple[float, Finding]] = []

    def add(axis: str, label: str, mask: NDArray[np.bool_], words: str) -> None:
        m = mask & rows
        n = int(np.count_nonzero(m))
        if n < 10:
            return
        mean = float(np.mean(res[m]))
        z = abs(mean) / (noise / math.sqrt(n))
        pct = 100.0 * math.expm1(mean)
        if abs(pct) < 1.0 or z < 5.0:
            return
        side = "above" if mean > 0 else "below"
        findings.append(
            (
                z,
                Finding(
                    axis,
                    label,
                    mean,
                    n,
                    f"{words} the measured resistance is {abs(pct):.0f} % {side} the model",
                ),
            )
        )

    f = axes["force"]
    pos = f[rows & (f > 0)]
    if pos.size:
        edges = np.geomspace(max(float(pos.min()), 1e-3), float(pos.max()) * 1.0001, 5)
        names = ["at low force", "at low-mid force", "at mid-high force", "at high force"]
        for i in range(4):
            add(
                "force",
                f"{edges[i]:.2g}-{edges[i + 1]:.2g} N",
                (f >= edges[i]) & (f < edges[i + 1]),
                f"{names[i]} ({edges[i]:.2g}-{edges[i + 1]:.2g} N)",
            )
    since = axes["time_since_change"]
    for lo, hi, words in (
        (0, 5, "within 5 s of a load change"),
        (5, 60, "5-60 s after a load change"),
        (60, 600, "1-10 min into a hold"),
        (600, math.inf, "after 10 min of holding"),
    ):
        add("time_since_change", f"{lo}-{hi} s", (since >= lo) & (since < hi) & (f > 0), words)
    d = axes["direction"]
    add("direction", "loading", d > 0, "while loading")
    add("direction", "unloading", (d < 0) & (f > 0), "while unloading")
    if "temperature" in axes:
        temp = axes["temperature"]
        ref = float(np.median(temp[rows]))
        add("temperature", f"above {ref + 2:.0f} °C", temp > ref + 2.0, f"above {ref + 2:.0f} °C")
        add("temperature", f"below {ref - 2:.0f} °C", temp < ref - 2.0, f"below {ref - 2:.0f} °C")
    cycle = axes["cycle"]
    if cycle.max() >= 3:
        add("cycle", "first cycle", cycle <= 1, "in the first load cycle")
        add("cycle", "later cycles", cycle >= 3, "in the later load cycles")
    unloaded = data.force_n <= 0.0
    if unloaded.any() and fit.model_ohm.size:
        measured_open = data.resistance_ohm[unloaded] >= OPEN_CIRCUIT_OHM
        model_open = fit.model_ohm[unloaded] >= OPEN_CIRCUIT_OHM
        n_bad = int(np.count_nonzero(measured_open != model_open))
        if n_bad >= 5:
            if np.count_nonzero(measured_open & ~model_open) >= np.count_nonzero(~measured_open & model_open):
                model_r = float(np.median(fit.model_ohm[unloaded][measured_open & ~model_open]))
                words = (
                    f"unloaded, the sensor reads open on {n_bad} rows where the model reads "
                    f"{model_r / 1e3:.0f} kohm"
                )
            else:
                meas_r = float(np.median(data.resistance_ohm[unloaded][~measured_open & model_open]))
                words = (
                    f"unloaded, the sensor reads {meas_r / 1e3:.0f} kohm on {n_bad} rows where the model "
                    "is open"
                )
            findings.append((math.inf, Finding("zero_force", "unloaded", math.nan, n_bad, words)))
    findings.sort(key=lambda item: -item[0])
    return tuple(fd for _, fd in findings[:limit])
