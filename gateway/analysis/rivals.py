"""The physical model's rivals on held-out force: the paper's line and a monotone lookup.

- the paper's conductance line C = m F + n (``gateway.model.ConductanceLine``, eq. 18);
- ``MonotoneLookup``: force as a non-increasing, piecewise-linear function of ln R through
  the medians of equal-count bins of the training rows (pool-adjacent-violators makes it
  monotone), flat beyond the first and last knot.

Both are fitted on the training rows and judged on the same held-out rows as the model, so
every report can say plainly which calibration reads force best.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model import ConductanceLine

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

LOOKUP_KNOTS = 24


@dataclass(frozen=True)
class MonotoneLookup:
    """F(ln R), non-increasing: ``log_r`` increasing knots, ``force_n`` at each knot."""

    log_r: tuple[float, ...]
    force_n: tuple[float, ...]

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            lr = np.log(r)
        out = np.interp(np.where(np.isfinite(lr), lr, self.log_r[-1]), self.log_r, self.force_n)
        return np.asarray(out)

    @classmethod
    def fit(cls, force_n: ArrayLike, resistance_ohm: ArrayLike, knots: int = LOOKUP_KNOTS) -> MonotoneLookup:
        f = np.asarray(force_n, dtype=np.float64).ravel()
        r = np.asarray(resistance_ohm, dtype=np.float64).ravel()
        ok = np.isfinite(f) & np.isfinite(r) & (r > 0)
        if np.count_nonzero(ok) < 4:
            raise ValueError("a lookup needs at least four rows with a finite resistance")
        lr, f = np.log(r[ok]), f[ok]
        order = np.argsort(lr, kind="stable")
        lr, f = lr[order], f[order]
        groups = np.array_split(np.arange(lr.size), min(knots, lr.size // 2))
        xs = [float(np.median(lr[g])) for g in groups]
        ys = [float(np.median(f[g])) for g in groups]
        ws = [float(g.size) for g in groups]
        xs_out, ys_out = _pav_non_increasing(xs, ys, ws)
        return cls(tuple(xs_out), tuple(ys_out))


def _pav_non_increasing(xs: list[float], ys: list[float], ws: list[float]) -> tuple[list[float], list[float]]:
    """Pool adjacent violators so that y does not increase with x (x pooled the same way)."""
    blocks: list[list[float]] = []  # [sum w x, sum w y, sum w]
    for x, y, w in zip(xs, ys, ws, strict=True):
        blocks.append([w * x, w * y, w])
        while len(blocks) > 1 and blocks[-1][1] / blocks[-1][2] > blocks[-2][1] / blocks[-2][2]:
            last = blocks.pop()
            for k in range(3):
                blocks[-1][k] += last[k]
    bx = [b[0] / b[2] for b in blocks]
    by = [b[1] / b[2] for b in blocks]
    if len(bx) == 1:
        bx, by = [bx[0] - 1e-6, bx[0] + 1e-6], [by[0], by[0]]
    return bx, by


def force_rms(predicted: FloatArray, reference: FloatArray) -> float:
    """RMS of predicted - reference over the rows where both are finite."""
    d = np.asarray(predicted, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d * d))) if d.size else math.nan


@dataclass(frozen=True)
class Rivals:
    """The line and the lookup, fitted on the training rows, scored on the held-out rows."""

    line: ConductanceLine
    line_force_rms_n: float
    lookup: MonotoneLookup
    lookup_force_rms_n: float

    @classmethod
    def fit(
        cls, force_n: FloatArray, resistance_ohm: FloatArray, train: BoolArray, test: BoolArray
    ) -> Rivals:
        line = ConductanceLine.fit(force_n[train], resistance_ohm[train])
        lookup = MonotoneLookup.fit(force_n[train], resistance_ohm[train])
        r_test, f_test = resistance_ohm[test], force_n[test]
        return cls(
            line=line,
            line_force_rms_n=force_rms(line.force(r_test), f_test),
            lookup=lookup,
            lookup_force_rms_n=force_rms(lookup.force(r_test), f_test),
        )

    def force_noise_floor_n(self, sigma_log: FloatArray, resistance_ohm: FloatArray) -> float:
        """The force RMS the log-R noise alone causes, through the line: |dF/d ln R| = C / m."""
        with np.errstate(divide="ignore", invalid="ignore"):
            dfd = 1.0 / (resistance_ohm * abs(self.line.slope_s_per_n))
        e = sigma_log * dfd
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e * e))) if e.size else math.nan


#: A line with n < 0 starts this factor above its zero-conductance force -n/m.
LINE_ZERO_MARGIN = 1.1


def line_range_lines(line: ConductanceLine, record_min_n: float) -> list[str]:
    """The ``[line]`` table's own ``force_min_n`` when the channel's (the record's lowest
    force) lies at or below 1.1 x the line's zero-conductance force -n/m (n < 0): below -n/m
    a sensor at rest would read a force (``gateway.model.conversion.LineConversion``)."""
    if line.intercept_s >= 0.0:
        return []
    floor_n = LINE_ZERO_MARGIN * float(line.force(math.inf))  # an open sensor reads -n/m
    if record_min_n > floor_n:
        return []
    return [
        f"# the line reaches zero conductance at {floor_n / LINE_ZERO_MARGIN:.4g} N: it reads from "
        f"{floor_n:.4g} N (no contact below), not from the record's {record_min_n:.4g} N",
        f"force_min_n = {floor_n!r}",
    ]


def verdict(
    model_rms: float,
    rivals: Mapping[str, float] | float,
    tie: float = 0.02,
    model_name: str = "the physical model",
) -> str:
    """Plain words: does the model beat, tie or lose to its best static rival on held-out force.

    ``rivals``: every static rival's held-out force RMS (N) by name (the line, the lookup, any
    static curve); the best of them (the lowest finite RMS) is the one compared with and named,
    never the line alone when another rival reads better. ``model_name``: what is judged
    (the physical model, or an empirical curve with drift correction). A bare number is the
    line's alone (the former signature, ``verdict(model_rms, line_rms)``), in the words it
    always gave."""
    if not isinstance(rivals, Mapping):
        return _line_verdict(model_rms, float(rivals), tie)
    finite = {name: float(v) for name, v in rivals.items() if math.isfinite(v)}
    if not (math.isfinite(model_rms) and finite):
        return f"{model_name} and its static rivals cannot be compared on these rows"
    name, best = min(finite.items(), key=lambda item: item[1])
    if model_rms <= best * (1.0 - tie):
        return f"{model_name} wins: {model_rms:.4g} N against the best static rival's ({name}) {best:.4g} N"
    if model_rms <= best * (1.0 + tie):
        return (
            f"{model_name} ties with the best static rival ({name}): {model_rms:.4g} N against {best:.4g} N"
        )
    return (
        f"THE {name.upper()} WINS: {model_name} reads force worse ({model_rms:.4g} N) than the {name} "
        f"({best:.4g} N), the best static rival on the same held-out rows"
    )


def _line_verdict(model_rms: float, line_rms: float, tie: float) -> str:
    """The physical model against the line alone (``verdict`` given a bare number)."""
    if not (math.isfinite(model_rms) and math.isfinite(line_rms)):
        return "the model and the line cannot be compared on these rows"
    if model_rms <= line_rms * (1.0 - tie):
        return f"the physical model wins: {model_rms:.4g} N against the line's {line_rms:.4g} N"
    if model_rms <= line_rms * (1.0 + tie):
        return f"the physical model ties with the line: {model_rms:.4g} N against {line_rms:.4g} N"
    return (
        f"THE LINE WINS: the physical model reads force worse ({model_rms:.4g} N) than the "
        f"conductance line ({line_rms:.4g} N) on the same held-out rows"
    )
