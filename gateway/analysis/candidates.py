"""Empirical calibrations: every static curve with every drift form, fitted and ranked.

A candidate is a static curve (``gateway.model.curves``: power law G = k F^n, conductance
line, monotone lookup) with one of the drift forms (static, creep, creep2, hysteresis and
their combinations). Each is fitted on the training rows of the same ``FitData`` that the
physical model and the discrepancy workflow use, and judged on its held-out rows by the
*tracked* force: ``curves.track_series`` runs the runtime's per-sample tracker over the whole
record (state from every row, unusable ones included) and the error is taken on the held-out
rows only. Nothing a candidate reads on held-out rows was fitted on them.

Fitting one candidate (the reference force drives the state, as in the physical model's fit):

1. the apparent force the curve should read is x = F (1 + beta s) + a1 K1[F] + a2 K2[F]: K_i
   is a Kelvin element of unit fraction driven by the reference force (exact exponential
   steps, the tracker's convention), s the direction of the play on the curve's own reading;
2. the static curve is fitted to (x, R) on the training rows (force-space least squares for
   the power law and the line; pooled adjacent violators for the lookup);
3. with the curve's x_hat = curve(R), the fractions a1, a2, beta solve the linear least squares
   x_hat - F = a1 K1 + a2 K2 + beta F s; the time constants and the play width are chosen on
   a grid by the training residual, then steps 2-3 alternate a few times;
4. for the power law and the line, the curve's two parameters and the fractions are then
   solved together from there (one least-squares problem; the time constants, the width and
   the play's directions stay): the alternation alone moves slowly along the curve's gain,
   which a creep fraction shares on every hold, and leaves most of the fraction in the curve.

The power law and the line are fitted in conductance relative to the median conductance of
the rows they are fitted on (``conductance_scale``), so a record whose resistances are all
divided by one constant (a ``ratio`` front end's readings, in units of an unknown reference
resistor) gives the same fit, parameters rescaled, and reads the same forces: the solver's
steps, bounds and stopping rules see the same numbers either way.

``rank_candidates`` returns every candidate's held-out force RMS, its drift across held-out
holds (end minus start error, % of full scale) and its parameter count, best first.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..model.curves import (
    CURVE_KINDS,
    DRIFT_FORMS,
    PLAY_SHARES,
    CurveChannel,
    Drift,
    LineCurve,
    LookupCurve,
    PowerLawCurve,
    StaticCurve,
    preisach_direction,
    track_series,
)
from .fitting import FitData
from .holds import Hold, find_holds, hold_tolerance_n
from .rivals import LOOKUP_KNOTS, MonotoneLookup

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

TAU1_GRID_S = (1.0, 2.0, 5.0, 10.0, 20.0)
TAU2_GRID_S = (30.0, 60.0, 120.0, 300.0, 1000.0)
WIDTH_GRID_FS = (0.02, 0.05, 0.1, 0.2)  # play width as a share of the record's full scale
ALTERNATIONS = 3


@dataclass(frozen=True)
class Candidate:
    """One fitted candidate and how it reads the held-out rows."""

    name: str
    channel: CurveChannel
    held_out_force_rms_n: float
    hold_drift_pct_fs: float  # RMS over held-out holds of (end - start) error, % of full scale
    train_force_rms_n: float
    force_n: FloatArray = field(repr=False)  # the tracked force on every row of the data

    @property
    def kind(self) -> str:
        return self.channel.curve.kind

    @property
    def drift_form(self) -> str:
        return self.channel.drift.form

    @property
    def n_parameters(self) -> int:
        return self.channel.n_parameters


def rms(values: FloatArray) -> float:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else math.nan


def kelvin_response(held_n: FloatArray, dt_s: FloatArray, tau_s: float) -> FloatArray:
    """z_k = e_k z_{k-1} + (1 - e_k) held_k, e_k = exp(-dt_k / tau), z before the first = 0:
    a unit-fraction Kelvin element driven by the force held over each interval. Solved in
    closed form over chunks of at most 600 time constants (no overflow), exactly."""
    n = held_n.size
    out = np.empty(n)
    cum = np.cumsum(dt_s / tau_s)
    z, start = 0.0, 0
    while start < n:
        base = cum[start - 1] if start else 0.0
        end = max(int(np.searchsorted(cum, base + 600.0, side="left")), start + 1)
        e = np.exp(-dt_s[start:end] / tau_s)
        b = (1.0 - e) * held_n[start:end]
        if end == start + 1:
            out[start] = e[0] * z + b[0]
        else:
            lc = cum[start:end] - base
            out[start:end] = np.exp(-lc) * (z + np.cumsum(np.exp(lc) * b))
        z = float(out[end - 1])
        start = end
    return out


def _line_fit(x: FloatArray, y: FloatArray, rank_deficient: str) -> tuple[float, float]:
    """Slope and intercept of y on x by least squares; ``ValueError(rank_deficient)`` where
    x has no usable spread (numpy would only warn, RankWarning, and return a meaningless line)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", np.exceptions.RankWarning)
        try:
            slope, intercept = np.polyfit(x, y, 1)
        except np.exceptions.RankWarning:
            raise ValueError(rank_deficient) from None
    return float(slope), float(intercept)


def fit_curve(kind: str, force_n: FloatArray, resistance_ohm: FloatArray) -> StaticCurve:
    """The static curve of ``kind`` through (apparent force, R) rows (finite, F > 0, R > 0)."""
    ok = np.isfinite(force_n) & np.isfinite(resistance_ohm) & (resistance_ohm > 0) & (force_n > 0)
    f, r = force_n[ok], resistance_ohm[ok]
    if f.size < 4 or np.ptp(f) <= 0.0:
        raise ValueError("a curve needs at least four rows at two or more distinct forces")
    g = 1.0 / r
    g0 = conductance_scale(g)
    if kind == "line":
        # force-space least squares: F = (G - c) / m = alpha G + beta
        alpha, beta = _line_fit(g, f, "the conductance does not change with force on these rows")
        if not alpha > 0.0:
            raise ValueError("the conductance does not rise with force on these rows")
        return LineCurve(float(1.0 / alpha), float(-beta / alpha))
    if kind == "power_law":
        # ln(G / g0) = ln(k / g0) + n ln F: p[0] = ln(k / g0), bounded relative to the data
        lg = np.log(g / g0)
        n0, lnk0 = _line_fit(np.log(f), lg, "the forces are too close for a power law")
        if not n0 > 0.0:
            raise ValueError("the conductance does not rise with force on these rows")

        def resid(p: FloatArray) -> FloatArray:
            return np.asarray(np.exp((lg - p[0]) / p[1]) - f)

        sol = least_squares(resid, np.array([lnk0, n0]), bounds=([-60.0, 0.05], [20.0, 10.0]), x_scale="jac")
        lnk, n = (float(v) for v in (sol.x if sol.success else (lnk0, n0)))
        return PowerLawCurve(g0 * math.exp(lnk), n)
    if kind == "lookup":
        lk = MonotoneLookup.fit(f, r, LOOKUP_KNOTS)
        lr = np.asarray(lk.log_r)
        keep = np.concatenate([[True], np.diff(lr) > 1e-9])
        lr, kf = lr[keep], np.asarray(lk.force_n)[keep]
        if lr.size < 2 or not kf[0] > kf[-1]:
            raise ValueError("the lookup found no force range on these rows")
        return LookupCurve(tuple(float(math.exp(v)) for v in lr), tuple(float(v) for v in kf))
    raise ValueError(f"unknown curve kind {kind!r}; allowed: {', '.join(CURVE_KINDS)}")


def conductance_scale(conductance_s: FloatArray) -> float:
    """The median of the finite, positive conductances (S, or 1/R_ref for relative
    readings): the unit the power law and the line are fitted in (1 when there are none)."""
    g = conductance_s[np.isfinite(conductance_s) & (conductance_s > 0)]
    return float(np.median(g)) if g.size else 1.0


class _Regressors:
    """The reference-driven drift regressors of one record, computed once per grid value."""

    def __init__(self, data: FitData) -> None:
        self.data = data
        f = np.nan_to_num(np.asarray(data.force_n, dtype=np.float64), nan=0.0)
        self.force = f
        self.held = np.maximum(np.concatenate([[0.0], f[:-1]]), 0.0)
        t = data.time_s
        self.dt = np.maximum(np.diff(t, prepend=t[:1]), 0.0)
        usable = data.usable & (f > 0)
        self.full_scale = float(np.max(f[usable])) if usable.any() else 1.0
        self._k: dict[float, FloatArray] = {}
        self._s: dict[float, FloatArray] = {}
        self.reading = self.force  # the curve's reading x the play follows (set per curve)

    def read_with(self, x_hat: FloatArray) -> None:
        """Drive the hysteresis regressors by this curve's reading."""
        self.reading = x_hat
        self._s.clear()

    def kelvin(self, tau_s: float) -> FloatArray:
        if tau_s not in self._k:
            self._k[tau_s] = kelvin_response(self.held, self.dt, tau_s)
        return self._k[tau_s]

    def hysteresis(self, width_n: float) -> FloatArray:
        if width_n not in self._s:
            self._s[width_n] = self.force * preisach_direction(self.reading, width_n)
        return self._s[width_n]


def reading_noise_n(x_hat: FloatArray, force_n: FloatArray, rows: BoolArray) -> float:
    """The noise of the curve's reading where it is loudest, in the top half of the force
    range (N): the 90th percentile of the change of x_hat - F between consecutive rows there,
    as a Gaussian sigma (/ (1.645 sqrt 2))."""
    top = rows & (force_n > 0.5 * float(np.max(np.where(rows, force_n, 0.0), initial=0.0)))
    d = np.diff(np.where(top, x_hat - force_n, np.nan))
    d = np.abs(d[np.isfinite(d)])
    return float(np.quantile(d, 0.9)) / (1.645 * math.sqrt(2.0)) if d.size >= 10 else 0.0


#: The narrowest play (``PLAY_SHARES``) must be this many reading-noise sigmas wide: a narrower
#: one turns between its branches on noise, and the force jumps by beta F / len(PLAY_SHARES).
PLAY_NOISE_SIGMAS = 2.0


def _grid(form: str, full_scale: float, noise_n: float = 0.0) -> list[tuple[float, float, float]]:
    """(tau1, tau2, width) triples to try for a drift form (unused values at their defaults)."""
    elements, hyst = DRIFT_FORMS[form]
    d = Drift()
    tau1s = TAU1_GRID_S if elements >= 1 else (d.creep_tau_s,)
    tau2s = TAU2_GRID_S if elements >= 2 else (d.creep2_tau_s,)
    widths: tuple[float, ...] = (d.hysteresis_width_n,)
    if hyst:
        narrowest = min(PLAY_SHARES)
        wide = [
            w * full_scale for w in WIDTH_GRID_FS if narrowest * w * full_scale >= PLAY_NOISE_SIGMAS * noise_n
        ]
        widths = tuple(wide) or (max(WIDTH_GRID_FS) * full_scale,)
    return [(t1, t2, w) for t1 in tau1s for t2 in tau2s for w in widths if elements < 2 or t2 >= 3 * t1]


def _fractions(
    reg: _Regressors, form: str, grid: tuple[float, float, float], x_hat: FloatArray, rows: BoolArray
) -> tuple[Drift, float]:
    """The linear least-squares fractions (a1, a2, beta) at one grid point, and the training
    residual RMS (N) of x_hat - x(F)."""
    elements, hyst = DRIFT_FORMS[form]
    tau1, tau2, width = grid
    cols: list[FloatArray] = []
    if elements >= 1:
        cols.append(reg.kelvin(tau1))
    if elements >= 2:
        cols.append(reg.kelvin(tau2))
    if hyst:
        cols.append(reg.hysteresis(width))
    y = (x_hat - reg.force)[rows]
    ok = np.isfinite(y)
    values = [0.0] * len(cols)
    if cols and ok.sum() > len(cols):
        a = np.column_stack([c[rows][ok] for c in cols])
        values = [float(v) for v in np.nan_to_num(np.linalg.lstsq(a, y[ok], rcond=None)[0])]
    a1 = float(np.clip(values.pop(0), -0.9, 5.0)) if elements >= 1 else 0.0
    a2 = float(np.clip(values.pop(0), -0.9, 5.0)) if elements >= 2 else 0.0
    beta = float(np.clip(values.pop(0), -0.9, 0.9)) if hyst else 0.0
    # a form's own terms stay on (a fitted zero would make it another form)
    a1 = a1 if elements < 1 or a1 != 0.0 else 1e-9
    a2 = a2 if elements < 2 or a2 != 0.0 else 1e-9
    beta = beta if not hyst or beta != 0.0 else 1e-9
    drift = Drift(a1, tau1, a2, tau2, beta, width)
    resid = y - _design(reg, drift)[rows]
    return drift, rms(resid)


def _design(reg: _Regressors, d: Drift) -> FloatArray:
    """x(F) - F: the drift terms the reference force drives."""
    out = np.zeros_like(reg.force)
    if d.creep_fraction:
        out = out + d.creep_fraction * reg.kelvin(d.creep_tau_s)
    if d.creep2_fraction:
        out = out + d.creep2_fraction * reg.kelvin(d.creep2_tau_s)
    if d.hysteresis_fraction:
        out = out + d.hysteresis_fraction * reg.hysteresis(d.hysteresis_width_n)
    return out


def fit_candidate(reg: _Regressors, kind: str, form: str, nested: CurveChannel | None = None) -> CurveChannel:
    """Fit one curve kind with one drift form to the training rows (module docstring).

    ``nested``, a fit of the same curve with one creep element fewer, is a second start for
    a two-element form (its element, plus a slow one): the richer form then fits the
    training rows at least as well as the one it contains."""
    data = reg.data
    rows = data.train
    r = data.resistance_ohm
    curve = fit_curve(kind, np.where(rows, reg.force, np.nan), r)
    drift = Drift()
    if form != "static":
        x_hat = CurveChannel(curve).static_force(r)
        reg.read_with(x_hat)
        best = min(
            (
                _fractions(reg, form, g, x_hat, rows)
                for g in _grid(form, reg.full_scale, reading_noise_n(x_hat, reg.force, rows))
            ),
            key=lambda pair: pair[1] if math.isfinite(pair[1]) else math.inf,
        )
        drift = best[0]
        grid = (drift.creep_tau_s, drift.creep2_tau_s, drift.hysteresis_width_n)
        for _ in range(ALTERNATIONS):
            target = reg.force + _design(reg, drift)
            curve = fit_curve(kind, np.where(rows, target, np.nan), r)
            x_hat = CurveChannel(curve).static_force(r)
            reg.read_with(x_hat)
            drift = _fractions(reg, form, grid, x_hat, rows)[0]
        curve, drift = _refine(reg, form, curve, drift, rows)
        if nested is not None and DRIFT_FORMS[form][0] == 2:
            n = nested.drift
            start = Drift(
                n.creep_fraction, n.creep_tau_s, 0.01, max(4.0 * n.creep_tau_s, 60.0),
                n.hysteresis_fraction, n.hysteresis_width_n,
            )  # fmt: skip
            here = _training_rms(reg, curve, drift, rows)
            reg.read_with(CurveChannel(nested.curve).static_force(r))
            other = _refine(reg, form, nested.curve, start, rows)
            if _training_rms(reg, *other, rows) < here:
                curve, drift = other
    return CurveChannel(curve, drift, force_min_n=0.0, force_max_n=reg.full_scale)


def _training_rms(reg: _Regressors, curve: StaticCurve, drift: Drift, rows: BoolArray) -> float:
    """The reference-driven residual x_hat - x(F) on the training rows (N)."""
    x_hat = CurveChannel(curve).static_force(reg.data.resistance_ohm)
    reg.read_with(x_hat)
    return rms((x_hat - reg.force - _design(reg, drift))[rows])


def _refine(
    reg: _Regressors, form: str, curve: StaticCurve, drift: Drift, rows: BoolArray
) -> tuple[StaticCurve, Drift]:
    """Step 4 (module docstring): a power law's or a line's two parameters and the fractions
    by one least-squares problem in force on the training rows, started from ``curve`` and
    ``drift``; both unchanged for a lookup or if it fails."""
    elements, hyst = DRIFT_FORMS[form]
    d = drift
    r = reg.data.resistance_ohm
    if not isinstance(curve, PowerLawCurve | LineCurve):
        return curve, drift
    hyst_col = reg.hysteresis(d.hysteresis_width_n) if hyst else None
    ok = rows & np.isfinite(r) & (r > 0)
    if hyst_col is not None:
        ok &= np.isfinite(hyst_col)
    if np.count_nonzero(ok) <= 2 + 2 * elements + hyst:
        return curve, drift
    f, g = reg.force[ok], 1.0 / r[ok]
    # solved in g = G / g0 (``conductance_scale``): the same problem whatever unit R is in
    g0 = conductance_scale(g)
    g = g / g0
    power = isinstance(curve, PowerLawCurve)
    if isinstance(curve, PowerLawCurve):  # x = exp((ln g - ln(k / g0)) / n)
        p0 = [math.log(curve.coefficient_s / g0), curve.exponent]
        low, high = [-60.0, 0.05], [20.0, 10.0]
    else:  # x = (G - c) / m = alpha G + b = (alpha g0) g + b
        p0 = [g0 / curve.slope_s_per_n, -curve.intercept_s / curve.slope_s_per_n]
        low, high = [0.0, -np.inf], [np.inf, np.inf]
    taus = [d.creep_tau_s, d.creep2_tau_s][:elements]
    fractions = [d.creep_fraction, d.creep2_fraction][:elements]
    # the time constants are refined too (ln tau, within the grid's span and a bit beyond)
    p0 += fractions + [math.log(t) for t in taus] + [d.hysteresis_fraction] * hyst
    low += [-0.9] * elements + [math.log(0.3), math.log(3.0)][:elements] + [-0.9] * hyst
    high += [5.0] * elements + [math.log(300.0), math.log(5000.0)][:elements] + [0.9] * hyst
    lg = np.log(g)

    def drift_terms(p: FloatArray) -> FloatArray:
        out = np.zeros(f.size)
        for i in range(elements):
            out = out + p[2 + i] * kelvin_response(reg.held, reg.dt, math.exp(p[2 + elements + i]))[ok]
        if hyst_col is not None:
            out = out + p[-1] * hyst_col[ok]
        return out

    def resid(p: FloatArray) -> FloatArray:
        x = np.exp((lg - p[0]) / p[1]) if power else p[0] * g + p[1]
        return np.asarray(x - f - drift_terms(p))

    bounds = (np.array(low), np.array(high))
    sol = least_squares(resid, np.clip(np.array(p0), *bounds), bounds=bounds, x_scale="jac")
    p = [float(v) for v in sol.x]
    if not sol.success or not all(math.isfinite(v) for v in p) or not (power or p[0] > 0.0):
        return curve, drift
    if rms(resid(sol.x)) > rms(resid(np.clip(np.array(p0), *bounds))):
        return curve, drift
    a = p[2 : 2 + elements] + [0.0] * (2 - elements)
    t = [math.exp(v) for v in p[2 + elements : 2 + 2 * elements]] + taus[
        len(p[2 + elements : 2 + 2 * elements]) :
    ]
    tau1 = t[0] if elements >= 1 else d.creep_tau_s
    tau2 = t[1] if elements >= 2 else d.creep2_tau_s
    if elements >= 2 and tau2 < tau1:  # keep the faster element first
        a[0], a[1], tau1, tau2 = a[1], a[0], tau2, tau1
    beta = p[-1] if hyst else 0.0
    # a form's own terms stay on (a fitted zero would make it another form)
    a1 = a[0] if elements < 1 or a[0] != 0.0 else 1e-9
    a2 = a[1] if elements < 2 or a[1] != 0.0 else 1e-9
    beta = beta if not hyst or beta != 0.0 else 1e-9
    out = Drift(a1, tau1, a2, tau2, beta, d.hysteresis_width_n)
    if power:
        return PowerLawCurve(g0 * math.exp(p[0]), p[1]), out
    return LineCurve(g0 / p[0], -p[1] / p[0] * g0), out


def hold_drift_pct(
    time_s: FloatArray,
    reference_n: FloatArray,
    force_n: FloatArray,
    rows: BoolArray,
    full_scale: float,
    holds: Sequence[Hold] | None = None,
) -> float:
    """RMS over the holds inside ``rows`` of ``hold_change_n``, as % of ``full_scale``; NaN
    without a hold. ``holds``: the reference's holds when already found (``find_holds``)."""
    tolerance = hold_tolerance_n(reference_n)
    changes = []
    for h in find_holds(time_s, reference_n, tolerance) if holds is None else holds:
        if not rows[h.start : h.stop].all():
            continue
        change = hold_change_n(reference_n, force_n, h, tolerance)
        if math.isfinite(change):
            changes.append(change)
    if not changes or not full_scale > 0:
        return math.nan
    return 100.0 * rms(np.asarray(changes)) / full_scale


def hold_change_n(reference_n: FloatArray, force_n: FloatArray, hold: Hold, tolerance_n: float) -> float:
    """How much the error moves across a hold (N): the mean error over the last 10 % of its
    settled rows (``Hold.settled``) minus the mean over the first 10 %."""
    h = hold.settled(reference_n, tolerance_n)
    first, last = h.edges()
    err = np.asarray(force_n, dtype=np.float64) - np.asarray(reference_n, dtype=np.float64)
    a, b = float(np.nanmean(err[first])), float(np.nanmean(err[last]))
    return b - a


def score(
    data: FitData, name: str, channel: CurveChannel, full_scale: float, holds: Sequence[Hold] | None = None
) -> Candidate:
    """Track the whole record with ``channel`` and score it on the held-out rows."""
    force, _ = track_series(channel, data.resistance_ohm, data.time_s)
    err = force - data.force_n
    return Candidate(
        name=name,
        channel=channel,
        held_out_force_rms_n=rms(err[data.test]),
        hold_drift_pct_fs=hold_drift_pct(data.time_s, data.force_n, force, data.test, full_scale, holds),
        train_force_rms_n=rms(err[data.train]),
        force_n=force,
    )


def rank_candidates(
    data: FitData,
    kinds: Sequence[str] = CURVE_KINDS,
    forms: Sequence[str] | None = None,
    real_time: bool = True,
) -> list[Candidate]:
    """Every curve kind with every drift form (time-driven forms only with real time), fitted
    and scored; best held-out force RMS first. A candidate that cannot be fitted is left out."""
    reg = _Regressors(data)
    chosen = list(forms) if forms is not None else list(DRIFT_FORMS)
    if not real_time:
        chosen = [f for f in chosen if DRIFT_FORMS[f][0] == 0]
    out: list[Candidate] = []
    fitted: dict[tuple[str, str], CurveChannel] = {}
    holds = find_holds(data.time_s, data.force_n, hold_tolerance_n(data.force_n))  # once, for all
    for kind in kinds:
        for form in chosen:
            nested = fitted.get((kind, form.replace("creep2", "creep")))
            try:
                ch = fit_candidate(reg, kind, form, nested)
            except (ValueError, np.linalg.LinAlgError):
                continue
            fitted[(kind, form)] = ch
            out.append(score(data, f"{kind} + {form}", ch, reg.full_scale, holds))
    return sorted(
        out, key=lambda c: c.held_out_force_rms_n if math.isfinite(c.held_out_force_rms_n) else math.inf
    )
