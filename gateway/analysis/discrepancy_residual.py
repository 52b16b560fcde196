"""The discrepancy workflow's last word: does the final model leave an unexplained residual?

An unexplained residual remains (``assess_residual``) when

1. the final model's held-out log-R RMS exceeds ``UNEXPLAINED_FLOOR_RATIO`` x the noise floor
   the measurement model predicts; or
2. it reads held-out force worse than the best static rival (the line, the lookup, any static
   curve of the ranking) by more than ``UNEXPLAINED_RIVAL_TIE``; or
3. an empirical calibration with drift terms (one of ``alternatives``: a static curve with
   creep, hysteresis or sensitivity, fitted on the same rows) reads held-out force better than
   the final model by more than ``UNEXPLAINED_ALTERNATIVE_FACTOR`` x: the record carries
   dynamics the final model does not take, whatever the log-R residual says (on a real FSR
   record the physical model reads 1.37 N where a line with two creep elements and hysteresis
   reads 0.54 N, its log-R RMS 1.8 x the noise floor); or
4. whatever its level, even below twice the noise floor, the residual has a *clear trend* in
   the time since the record's start or with the load history (``clear_trend``): the mean
   log-R residual of the record's five equal spans of time moves one way from first to last,
   or that of the holds right after a higher load differs from that of the others, by at
   least ``TREND_SPREAD_FLOOR`` x the noise floor, the bins explaining at least
   ``TREND_MIN_SHARE`` of the residual's variance. Noise does neither: five bin means of a few
   hundred rows each scatter by a tenth of the floor and are ordered one way one time in 60.

When the residual varies most with the time since the record's start, or has a trend in it,
an unknown load history before the record started is named as a possible cause, with how the
record starts (``load_history.start_load``: loaded, and at what load, or at rest).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from .diagnostics import WEAK_STRUCTURE, ResidualAxis, ResidualStructure, residual_structure
from .fitting import FitData, FitResult
from .load_history import StartLoad

#: An unexplained residual remains when the final held-out log-R RMS exceeds this multiple of
#: the noise floor the measurement model predicts ...
UNEXPLAINED_FLOOR_RATIO = 2.0
#: ... or the final model reads held-out force worse than the best static rival by more than
#: this share (the tie of ``rivals.verdict``) ...
UNEXPLAINED_RIVAL_TIE = 0.02
#: ... or an empirical calibration with drift terms reads held-out force better by more than
#: this factor (a clear margin: the fitted curves' held-out RMS moves by a few % between forms) ...
UNEXPLAINED_ALTERNATIVE_FACTOR = 1.5
#: ... or its residual has a trend (time since the start, load history) spanning at least this
#: multiple of the noise floor (log-R) ...
TREND_SPREAD_FLOOR = 0.5
#: ... whose bins explain at least this share of the residual's variance.
TREND_MIN_SHARE = WEAK_STRUCTURE
#: The fewest rows a bin needs to count in a trend.
TREND_MIN_ROWS = 10
LOAD_HISTORY_CAUSE = "an unknown load history before the record started"


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


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
    #: the clear trends found (time since the start, load history), in words
    trends: tuple[str, ...] = ()
    #: possible causes outside the catalogue, in words
    causes: tuple[str, ...] = ()

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
        if self.causes:
            words += "; possible cause: " + "; ".join(self.causes)
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
            "trends": list(self.trends),
            "possible_causes": list(self.causes),
            "structure": self.structure.as_json(),
            "sentence": self.sentence(),
        }


def clear_trend(axis: ResidualAxis, scale_log: float) -> str | None:
    """The trend of ``axis`` in words when it is clear (module docstring, 3), else None;
    ``scale_log`` is the noise floor (log-R) it is measured against."""
    bins = [b for b in axis.bins if b.n_rows >= TREND_MIN_ROWS and math.isfinite(b.log_r_mean)]
    share = axis.explained_log_r
    if not (math.isfinite(scale_log) and scale_log > 0 and math.isfinite(share) and share >= TREND_MIN_SHARE):
        return None
    means = [b.log_r_mean for b in bins]
    if axis.name == "elapsed":
        steps = [b - a for a, b in itertools.pairwise(means)]
        one_way = len(bins) >= 4 and (all(s > 0 for s in steps) or all(s < 0 for s in steps))
        spread = abs(means[-1] - means[0]) if means else 0.0
        if not (one_way and spread >= TREND_SPREAD_FLOOR * scale_log):
            return None
        return (
            f"the log-R residual moves one way with the time since the record's start, {means[0]:+.4f} "
            f"{bins[0].label} to {means[-1]:+.4f} {bins[-1].label} ({spread / scale_log:.2g} x the noise "
            f"floor, {100 * share:.0f} % of its variance)"
        )
    if axis.name == "load_history":
        if len(bins) < 2:
            return None
        low, high = min(bins, key=lambda b: b.log_r_mean), max(bins, key=lambda b: b.log_r_mean)
        spread = high.log_r_mean - low.log_r_mean
        if spread < TREND_SPREAD_FLOOR * scale_log:
            return None
        return (
            f"the log-R residual depends on the load history: {high.log_r_mean:+.4f} {high.label} against "
            f"{low.log_r_mean:+.4f} {low.label} ({spread / scale_log:.2g} x the noise floor, "
            f"{100 * share:.0f} % of its variance)"
        )
    return None


def assess_residual(
    data: FitData,
    fit: FitResult,
    floor_log: float,
    statics: Sequence[tuple[str, float]],
    alternatives: Sequence[tuple[str, float]] = (),
    real_time: bool = True,
    metadata: Mapping[str, str] | None = None,
    start: StartLoad | None = None,
) -> UnexplainedResidual:
    """Whether ``fit`` leaves an unexplained residual (module docstring): ``statics`` the
    static rivals and ``alternatives`` every further empirical model, each (name, held-out
    force RMS in N on the same rows); ``start`` how the record starts, for the causes."""
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
    dynamic = [a for a in alternatives if math.isfinite(a[1]) and not a[0].endswith(" + static")]
    best_dynamic = min(dynamic, key=lambda a: a[1]) if dynamic else None
    if best_dynamic is not None and gap.force_rms_n > UNEXPLAINED_ALTERNATIVE_FACTOR * best_dynamic[1]:
        remains = True
        reasons.append(
            f"held-out force RMS {gap.force_rms_n:.4g} N against {best_dynamic[0]}'s "
            f"{best_dynamic[1]:.4g} N: a curve with drift terms reads it more than "
            f"{UNEXPLAINED_ALTERNATIVE_FACTOR:g} x better, so the record carries dynamics this model "
            "does not take"
        )
    structure = residual_structure(data, fit, real_time, dict(metadata or {}))
    trends = tuple(t for a in structure.axes if (t := clear_trend(a, floor_log)) is not None)
    if trends:
        remains = True
        reasons.extend(f"a clear trend, whatever its level: {t}" for t in trends)
    elif structure.axes:
        reasons.append("no clear trend with the time since the record's start or with the load history")
    causes: list[str] = []
    best_axis = structure.most_varying()
    elapsed_varies = best_axis is not None and best_axis.name == "elapsed"
    elapsed_varies &= best_axis is not None and best_axis.explained_log_r >= WEAK_STRUCTURE
    at_start = any("record's start" in t or "the record starts in" in t for t in trends)
    if remains and (elapsed_varies or at_start):
        how = f"; {start.sentence()}" if start is not None else ""
        causes.append(LOAD_HISTORY_CAUSE + how)
    return UnexplainedResidual(
        remains=remains,
        log_r_rms=gap.log_resistance_rms,
        floor_log=floor_log,
        force_rms_n=gap.force_rms_n,
        best_static=best_static,
        alternatives=tuple((str(n), float(v)) for n, v in (*statics, *alternatives)),
        reasons=tuple(reasons),
        structure=structure,
        trends=trends,
        causes=tuple(causes),
    )
