"""The physical model's static rivals on held-out force: the paper's line and a monotone lookup.

- the paper's conductance line C = m F + n (``gateway.model.static_curves.LineCurve``, eq. 18,
  fitted in conductance), read as a ``[line]`` table reads it;
- a monotone lookup (``LookupCurve.fit``), read as a ``[lookup]`` table reads it: linear in
  ln R between its knots and along its end segments beyond them.

Both are fitted on the training rows and read on every row by the runtime's own tracker
(``gateway.model.tracker.track_series``, the function ``apply`` and the gateway read a written
table with), so the figure ranked is the figure a user gets; every report can say plainly
which calibration reads force best.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..model.calibrated import LINE_ZERO_MARGIN, CurveChannel, channel_from_table, line_channel
from ..model.static_curves import LineCurve, LookupCurve
from ..model.tracker import track_series

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

__all__ = ["LINE_ZERO_MARGIN", "Rivals", "force_rms", "verdict"]


def force_rms(predicted: FloatArray, reference: FloatArray) -> float:
    """RMS of predicted - reference over the rows where both are finite."""
    d = np.asarray(predicted, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d * d))) if d.size else math.nan


@dataclass(frozen=True)
class Rivals:
    """The line and the lookup as written (``CurveChannel``), fitted on the training rows, read
    on every row by the runtime's tracker and scored on the held-out rows."""

    line: CurveChannel
    line_force_rms_n: float
    lookup: CurveChannel
    lookup_force_rms_n: float
    line_force_n: FloatArray = field(repr=False)
    lookup_force_n: FloatArray = field(repr=False)

    @classmethod
    def fit(
        cls,
        force_n: FloatArray,
        resistance_ohm: FloatArray,
        train: BoolArray,
        test: BoolArray,
        range_n: tuple[float, float] | None = None,
    ) -> Rivals:
        """Fit both on ``train`` and score them on ``test``; ``range_n``: the line's calibrated
        range as written (default: the training rows' loaded range)."""
        line = LineCurve.fit_conductance(force_n[train], resistance_ohm[train])
        lookup = LookupCurve.fit(force_n[train], resistance_ohm[train])
        if range_n is None:
            loaded = force_n[train & np.isfinite(force_n) & (force_n > 0)]
            range_n = (float(loaded.min()), float(loaded.max())) if loaded.size else (0.01, 1.0)
        line_ch = line_channel(line, *range_n)
        lookup_ch = channel_from_table("lookup", lookup.table(), 0.0, 0.0)
        no_time = np.zeros(resistance_ohm.size)  # static: no state, time is not read
        line_f, _ = track_series(line_ch, resistance_ohm, no_time)
        lookup_f, _ = track_series(lookup_ch, resistance_ohm, no_time)
        return cls(
            line=line_ch,
            line_force_rms_n=force_rms(line_f[test], force_n[test]),
            lookup=lookup_ch,
            lookup_force_rms_n=force_rms(lookup_f[test], force_n[test]),
            line_force_n=line_f,
            lookup_force_n=lookup_f,
        )

    @property
    def line_curve(self) -> LineCurve:
        curve = self.line.curve
        assert isinstance(curve, LineCurve)
        return curve

    def force_noise_floor_n(self, sigma_log: FloatArray, resistance_ohm: FloatArray) -> float:
        """The force RMS the log-R noise alone causes, through the line: |dF/d ln R| = C / m."""
        with np.errstate(divide="ignore", invalid="ignore"):
            dfd = 1.0 / (resistance_ohm * abs(self.line_curve.slope_s_per_n))
        e = sigma_log * dfd
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e * e))) if e.size else math.nan


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
