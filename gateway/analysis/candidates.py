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
   steps with the loading or the recovery time constant, from the equilibrium at the first
   load: the tracker's convention, ``gateway.model.drift``), s the direction of the play on the
   curve's own reading;
2. the static curve is fitted to (x, R) on the training rows (force-space least squares for
   the power law and the line; pooled adjacent violators for the lookup);
3. with the curve's x_hat = curve(R), the fractions a1, a2, beta solve the bounded linear least
   squares x_hat - F = a1 K1 + a2 K2 + beta F s. Each creep fraction lies in
   ``CREEP_FRACTION_BOUNDS``: a reading may creep up (a > 0) or relax (a < 0: a real FSR's
   conductance can fall under a held high load and rise again at a low one), but the settled
   reading 1 + a1 + a2 stays at least 0.2 of the applied force, so that it rises with force;
   the time constants (loading, and recovery as a multiple of it) and the play width are chosen
   on a grid by the training residual, then steps 2-3 alternate a few times. Only time
   constants the record resolves are tried: at least ``TAU_MIN_STEPS`` sample steps and at
   most half the record's duration;
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
holds in two groups (``holds.hold_drifts``: right after a higher load, and the others; end
minus start error, % of full scale), read by the runtime's own tracker
(``gateway.model.tracker.track_series``), and its parameter count, best first.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares, lsq_linear

from ..model.calibrated import LINE_ZERO_MARGIN, CurveChannel
from ..model.drift import DRIFT_FORMS, PLAY_SHARES, Drift, kelvin_unit_series, play_direction_series
from ..model.static_curves import CURVE_KINDS, LineCurve, LookupCurve, PowerLawCurve, StaticCurve
from ..model.tracker import track_series
from .fitting import FitData
from .holds import DriftGroups, Hold, drift_groups_pct, find_holds, hold_drifts, hold_tolerance_n

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

TAU1_GRID_S = (0.3, 1.0, 2.0, 5.0, 10.0, 20.0)
TAU2_GRID_S = (30.0, 60.0, 120.0, 300.0, 1000.0)
#: The recovery time constant as a multiple of the loading one (1: symmetric).
RECOVERY_FACTORS = (1.0, 3.0, 10.0)
WIDTH_GRID_FS = (0.02, 0.05, 0.1, 0.2)  # play width as a share of the record's full scale
ALTERNATIONS = 3
#: A time constant must span this many median sample steps to be resolved by the record.
TAU_MIN_STEPS = 5.0
#: Each creep fraction's bounds: two at the lower bound still leave 1 + a1 + a2 = 0.2.
CREEP_FRACTION_BOUNDS = (-0.4, 5.0)
HYSTERESIS_BOUNDS = (-0.9, 0.9)
#: The sensitivity element's c (1/N) times the full scale: at the top of the range the settled
#: reading F exp(c F) still rises with F (c F > -1) and at most doubles per full scale.
SENSITIVITY_BOUNDS_FS = (-0.8, 0.7)


@dataclass(frozen=True)
class Candidate:
    """One fitted candidate and how it reads the held-out rows."""

    name: str
    channel: CurveChannel
    held_out_force_rms_n: float
    drift: DriftGroups  # held-out hold drift in two groups, % of full scale
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
        alpha, beta = _line_fit(g / g0, f, "the conductance does not change with force on these rows")
        if not alpha > 0.0:
            raise ValueError("the conductance does not rise with force on these rows")
        return LineCurve(float(g0 / alpha), float(-beta * g0 / alpha))
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
        return LookupCurve.fit(f, r)
    raise ValueError(f"unknown curve kind {kind!r}; allowed: {', '.join(CURVE_KINDS)}")


def _reading(curve: StaticCurve, resistance_ohm: FloatArray) -> FloatArray:
    """The curve's apparent force x (N) at each resistance (an open sensor reads 0 N)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x = curve.force(resistance_ohm)
    return np.asarray(np.where(np.isposinf(resistance_ohm), 0.0, x))


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
        first = max(float(f[0]), 0.0) if f.size else 0.0
        # the force held over each interval: the previous one, the first load before the first
        self.held = np.maximum(np.concatenate([[first], f[:-1]]), 0.0)
        self.first_n = first
        t = data.time_s
        self.dt = np.maximum(np.diff(t, prepend=t[:1]), 0.0)
        usable = data.usable & (f > 0)
        self.full_scale = float(np.max(f[usable])) if usable.any() else 1.0
        steps = self.dt[self.dt > 0]
        self.tau_low_s = TAU_MIN_STEPS * float(np.median(steps)) if steps.size else 0.0
        self.tau_high_s = 0.5 * float(t[-1] - t[0]) if t.size else 0.0
        self._k: dict[tuple[float, float], FloatArray] = {}
        self._s: dict[float, FloatArray] = {}
        self._u: dict[tuple[float, float], FloatArray] = {}
        self.reading = self.force  # the curve's reading x the play follows (set per curve)

    def resolved(self, tau_s: float) -> bool:
        return self.tau_low_s <= tau_s <= self.tau_high_s

    def read_with(self, x_hat: FloatArray) -> None:
        """Drive the hysteresis and sensitivity regressors by this curve's reading."""
        self.reading = x_hat
        self._s.clear()
        self._u.clear()

    def sensitivity(self, tau_s: float, recovery_tau_s: float) -> FloatArray:
        """A unit Kelvin element driven by the curve's reading held over each interval (the
        sensitivity element follows the reading, ``gateway.model.drift``), from the first."""
        key = (tau_s, recovery_tau_s)
        if key not in self._u:
            x = np.asarray(self.reading, dtype=np.float64)
            finite = np.isfinite(x)
            idx = np.where(finite, np.arange(x.size), 0)
            np.maximum.accumulate(idx, out=idx)
            first = float(np.maximum(x[finite][0], 0.0)) if finite.any() else 0.0
            carried = np.where(finite[idx], np.maximum(x[idx], 0.0), first)
            held = np.concatenate([[first], carried[:-1]])
            self._u[key] = kelvin_unit_series(held, self.dt, tau_s, recovery_tau_s, first)
        return self._u[key]

    def kelvin(self, tau_s: float, recovery_tau_s: float | None = None) -> FloatArray:
        key = (tau_s, tau_s if recovery_tau_s is None else recovery_tau_s)
        if key not in self._k:
            self._k[key] = kelvin_unit_series(self.held, self.dt, key[0], key[1], self.first_n)
        return self._k[key]

    def hysteresis(self, width_n: float) -> FloatArray:
        if width_n not in self._s:
            self._s[width_n] = self.force * play_direction_series(self.reading, width_n)
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
#: (tau1, tau2, width, recovery factor): one point of a drift form's grid.
GridPoint = tuple[float, float, float, float]


def _grid(reg: _Regressors, form: str, noise_n: float = 0.0) -> list[GridPoint]:
    """The grid points to try for a drift form (unused values at their defaults); only time
    constants the record resolves (``_Regressors.resolved``)."""
    elements, hyst, sens = DRIFT_FORMS[form]
    d = Drift()
    # the first time constant: the first creep element's, or the sensitivity element's
    first = elements >= 1 or sens
    tau1s = tuple(t for t in TAU1_GRID_S if reg.resolved(t)) if first else (d.creep_tau_s,)
    tau2s = tuple(t for t in TAU2_GRID_S if reg.resolved(t)) if elements >= 2 else (d.creep2_tau_s,)
    factors = RECOVERY_FACTORS if first else (1.0,)
    widths: tuple[float, ...] = (d.hysteresis_width_n,)
    if hyst:
        narrowest = min(PLAY_SHARES)
        fs = reg.full_scale
        wide = [w * fs for w in WIDTH_GRID_FS if narrowest * w * fs >= PLAY_NOISE_SIGMAS * noise_n]
        widths = tuple(wide) or (max(WIDTH_GRID_FS) * fs,)
    return [
        (t1, t2, w, r)
        for t1 in tau1s
        for t2 in tau2s
        for w in widths
        for r in factors
        if elements < 2 or t2 >= 3 * t1
    ]


def _drift_at(form: str, grid: GridPoint, values: Sequence[float]) -> Drift:
    """The drift of ``form`` at a grid point with fractions ``values`` (a1, a2, beta as used);
    a form's own terms stay on (a fitted zero would make it another form)."""
    elements, hyst, sens = DRIFT_FORMS[form]
    tau1, tau2, width, factor = grid
    vals = list(values)
    if sens:  # (c, beta): the sensitivity element on the first time constant
        c = _kept(vals.pop(0))
        beta = _kept(float(np.clip(vals.pop(0), *HYSTERESIS_BOUNDS))) if hyst else 0.0
        return Drift(
            hysteresis_fraction=beta, hysteresis_width_n=width, sensitivity_per_n=c, sensitivity_tau_s=tau1,
            sensitivity_recovery_tau_s=tau1 * factor if factor != 1.0 else None,
        )  # fmt: skip
    lo, hi = CREEP_FRACTION_BOUNDS
    a1 = _kept(float(np.clip(vals.pop(0), lo, hi))) if elements >= 1 else 0.0
    a2 = _kept(float(np.clip(vals.pop(0), lo, hi))) if elements >= 2 else 0.0
    beta = _kept(float(np.clip(vals.pop(0), *HYSTERESIS_BOUNDS))) if hyst else 0.0
    rec1 = tau1 * factor if elements >= 1 and factor != 1.0 else None
    rec2 = tau2 * factor if elements >= 2 and factor != 1.0 else None
    return Drift(a1, tau1, a2, tau2, beta, width, rec1, rec2)


def _kept(value: float) -> float:
    """A form's own term stays on: a fitted zero would make it another form."""
    return value if value != 0.0 else 1e-9


def _columns(reg: _Regressors, form: str, grid: GridPoint) -> list[FloatArray]:
    """The regressors of a form's linear fractions: in force for the additive forms (K1, K2,
    F s), in ln(x / F) for the sensitivity forms (K, s)."""
    elements, hyst, sens = DRIFT_FORMS[form]
    tau1, tau2, width, factor = grid
    cols: list[FloatArray] = []
    if sens:
        cols.append(reg.sensitivity(tau1, tau1 * factor))
        if hyst:
            with np.errstate(invalid="ignore", divide="ignore"):
                cols.append(reg.hysteresis(width) / reg.force)
        return cols
    if elements >= 1:
        cols.append(reg.kelvin(tau1, tau1 * factor))
    if elements >= 2:
        cols.append(reg.kelvin(tau2, tau2 * factor))
    if hyst:
        cols.append(reg.hysteresis(width))
    return cols


def _fractions(
    reg: _Regressors, form: str, grid: GridPoint, x_hat: FloatArray, rows: BoolArray
) -> tuple[Drift, float]:
    """The bounded linear least-squares fractions at one grid point (a1, a2, beta in force; c,
    beta in ln(x / F) for a sensitivity form), and the training residual RMS (N) of
    x_hat - x(F)."""
    elements, hyst, sens = DRIFT_FORMS[form]
    cols = _columns(reg, form, grid)
    if sens:
        with np.errstate(invalid="ignore", divide="ignore"):
            y = np.log(x_hat / reg.force)[rows]
        c_low, c_high = SENSITIVITY_BOUNDS_FS[0] / reg.full_scale, SENSITIVITY_BOUNDS_FS[1] / reg.full_scale
        low = [c_low] + [HYSTERESIS_BOUNDS[0]] * hyst
        high = [c_high] + [HYSTERESIS_BOUNDS[1]] * hyst
    else:
        y = (x_hat - reg.force)[rows]
        low = [CREEP_FRACTION_BOUNDS[0]] * elements + [HYSTERESIS_BOUNDS[0]] * hyst
        high = [CREEP_FRACTION_BOUNDS[1]] * elements + [HYSTERESIS_BOUNDS[1]] * hyst
    values = [0.0] * len(cols)
    if cols:
        a = np.column_stack([c[rows] for c in cols])
        ok = np.isfinite(y) & np.all(np.isfinite(a), axis=1)
        if ok.sum() > len(cols):
            values = [float(v) for v in lsq_linear(a[ok], y[ok], bounds=(low, high)).x]
    drift = _drift_at(form, grid, values)
    resid = (x_hat - reg.force - _design(reg, drift))[rows]
    return drift, rms(resid)


def _grid_point(d: Drift) -> GridPoint:
    if d.sensitivity_per_n:
        factor = d.recovery_sensitivity_tau_s / d.sensitivity_tau_s
        return (d.sensitivity_tau_s, d.creep2_tau_s, d.hysteresis_width_n, factor)
    factor = d.recovery_tau1_s / d.creep_tau_s if d.creep_fraction else d.recovery_tau2_s / d.creep2_tau_s
    return (d.creep_tau_s, d.creep2_tau_s, d.hysteresis_width_n, factor)


def _design(reg: _Regressors, d: Drift) -> FloatArray:
    """x(F) - F: what the drift adds to the reading, driven by the reference force
    (x = F (1 + beta s) exp(c K) + a1 K1 + a2 K2, ``gateway.model.drift``)."""
    out = np.zeros_like(reg.force)
    if d.creep_fraction:
        out = out + d.creep_fraction * reg.kelvin(d.creep_tau_s, d.recovery_tau1_s)
    if d.creep2_fraction:
        out = out + d.creep2_fraction * reg.kelvin(d.creep2_tau_s, d.recovery_tau2_s)
    scaled = reg.force
    if d.hysteresis_fraction:
        scaled = scaled + d.hysteresis_fraction * reg.hysteresis(d.hysteresis_width_n)
    if d.sensitivity_per_n:
        k = reg.sensitivity(d.sensitivity_tau_s, d.recovery_sensitivity_tau_s)
        scaled = scaled * np.exp(d.sensitivity_per_n * k)
    return out + scaled - reg.force


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
        x_hat = _reading(curve, r)
        reg.read_with(x_hat)
        grid_points = _grid(reg, form, reading_noise_n(x_hat, reg.force, rows))
        if not grid_points:
            raise ValueError(f"the record resolves no time constant of {form}")
        best = min(
            (_fractions(reg, form, g, x_hat, rows) for g in grid_points),
            key=lambda pair: pair[1] if math.isfinite(pair[1]) else math.inf,
        )
        drift = best[0]
        grid = _grid_point(drift)
        for _ in range(ALTERNATIONS):
            target = reg.force + _design(reg, drift)
            curve = fit_curve(kind, np.where(rows, target, np.nan), r)
            x_hat = _reading(curve, r)
            reg.read_with(x_hat)
            drift = _fractions(reg, form, grid, x_hat, rows)[0]
        curve, drift = _refine(reg, form, curve, drift, rows)
        if nested is not None and DRIFT_FORMS[form][0] == 2:
            n = nested.drift
            slow = max(4.0 * n.creep_tau_s, 60.0)
            if reg.resolved(slow):
                start = replace(
                    n, creep2_fraction=0.01, creep2_tau_s=slow,
                    creep2_recovery_tau_s=None if n.creep_recovery_tau_s is None
                    else slow * n.recovery_tau1_s / n.creep_tau_s,
                )  # fmt: skip
                here = _training_rms(reg, curve, drift, rows)
                reg.read_with(_reading(nested.curve, r))
                other = _refine(reg, form, nested.curve, start, rows)
                if _training_rms(reg, *other, rows) < here:
                    curve, drift = other
    floor = curve.force_at_zero_conductance_n
    low_n = LINE_ZERO_MARGIN * floor if floor > 0.0 else 0.0
    return CurveChannel(curve, drift, force_min_n=low_n).with_range(0.0, reg.full_scale)


def _training_rms(reg: _Regressors, curve: StaticCurve, drift: Drift, rows: BoolArray) -> float:
    """The reference-driven residual x_hat - x(F) on the training rows (N)."""
    x_hat = _reading(curve, reg.data.resistance_ohm)
    reg.read_with(x_hat)
    return rms((x_hat - reg.force - _design(reg, drift))[rows])


def _refine(
    reg: _Regressors, form: str, curve: StaticCurve, drift: Drift, rows: BoolArray
) -> tuple[StaticCurve, Drift]:
    """Step 4 (module docstring): a power law's or a line's two parameters and the fractions
    by one least-squares problem in force on the training rows, started from ``curve`` and
    ``drift`` (fractions within their bounds); a symmetric element's time constant is refined too (in ln tau,
    within what the record resolves). Both unchanged for a lookup or if it fails."""
    elements, hyst, sens = DRIFT_FORMS[form]
    d = drift
    r = reg.data.resistance_ohm
    if sens or not isinstance(curve, PowerLawCurve | LineCurve):
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
    recs = [d.recovery_tau1_s, d.recovery_tau2_s][:elements]
    # a symmetric element's time constant is refined (ln tau, within what the record resolves)
    free = [i for i in range(elements) if taus[i] == recs[i]] if not d.asymmetric else []
    fractions = [d.creep_fraction, d.creep2_fraction][:elements]
    lo_tau, hi_tau = math.log(max(reg.tau_low_s, 1e-3)), math.log(max(reg.tau_high_s, 2e-3))
    p0 += fractions + [math.log(taus[i]) for i in free] + [d.hysteresis_fraction] * hyst
    low += [CREEP_FRACTION_BOUNDS[0]] * elements + [lo_tau] * len(free) + [HYSTERESIS_BOUNDS[0]] * hyst
    high += [CREEP_FRACTION_BOUNDS[1]] * elements + [hi_tau] * len(free) + [HYSTERESIS_BOUNDS[1]] * hyst
    lg = np.log(g)
    fixed_cols = {i: reg.kelvin(taus[i], recs[i])[ok] for i in range(elements) if i not in free}

    def element_taus(p: FloatArray) -> list[float]:
        out = list(taus)
        for j, i in enumerate(free):
            out[i] = math.exp(p[2 + elements + j])
        return out

    def drift_terms(p: FloatArray) -> FloatArray:
        out = np.zeros(f.size)
        tau_now = element_taus(p)
        for i in range(elements):
            col = (
                fixed_cols[i]
                if i in fixed_cols
                else kelvin_unit_series(reg.held, reg.dt, tau_now[i], tau_now[i], reg.first_n)[ok]
            )
            out = out + p[2 + i] * col
        if hyst_col is not None:
            out = out + p[-1] * hyst_col[ok]
        return out

    def resid(p: FloatArray) -> FloatArray:
        x = np.exp((lg - p[0]) / p[1]) if power else p[0] * g + p[1]
        return np.asarray(x - f - drift_terms(p))

    bounds = (np.array(low), np.array(high))
    start = np.clip(np.array(p0), *bounds)
    sol = least_squares(resid, start, bounds=bounds, x_scale="jac")
    p = [float(v) for v in sol.x]
    if not sol.success or not all(math.isfinite(v) for v in p) or not (power or p[0] > 0.0):
        return curve, drift
    if rms(resid(sol.x)) > rms(resid(start)):
        return curve, drift
    a = p[2 : 2 + elements] + [0.0] * (2 - elements)
    t = element_taus(sol.x) + [d.creep2_tau_s] * (2 - elements)
    rec = [t[i] if i in free else recs[i] for i in range(elements)] + [d.recovery_tau2_s] * (2 - elements)
    tau1 = t[0] if elements >= 1 else d.creep_tau_s
    tau2 = t[1] if elements >= 2 else d.creep2_tau_s
    rec1, rec2 = rec[0], rec[1]
    if elements >= 2 and tau2 < tau1:  # keep the faster element first
        a[0], a[1], tau1, tau2, rec1, rec2 = a[1], a[0], tau2, tau1, rec2, rec1
    beta = p[-1] if hyst else 0.0
    # a form's own terms stay on (a fitted zero would make it another form)
    a1 = _kept(a[0]) if elements >= 1 else 0.0
    a2 = _kept(a[1]) if elements >= 2 else 0.0
    beta = _kept(beta) if hyst else 0.0
    out = Drift(
        a1, tau1, a2, tau2, beta, d.hysteresis_width_n,
        rec1 if elements >= 1 and rec1 != tau1 else None,
        rec2 if elements >= 2 and rec2 != tau2 else None,
    )  # fmt: skip
    if power:
        return PowerLawCurve(g0 * math.exp(p[0]), p[1]), out
    return LineCurve(g0 / p[0], -p[1] / p[0] * g0), out


def held_out_drift(
    data: FitData,
    force_n: FloatArray,
    full_scale: float,
    holds: Sequence[Hold] | None = None,
    offset_n: float = 0.0,
) -> DriftGroups:
    """The drift of ``force_n`` across the held-out holds (``holds.hold_drifts``, the measure
    ``apply`` prints), in its two groups, % of ``full_scale``; against F_ref + ``offset_n``."""
    reference = data.force_n + offset_n
    found = tuple(holds) if holds is not None else None
    drifts = hold_drifts(data.time_s, reference, force_n, data.test, found, hold_tolerance_n(data.force_n))
    return drift_groups_pct(drifts, full_scale)


def score(
    data: FitData, name: str, channel: CurveChannel, full_scale: float, holds: Sequence[Hold] | None = None
) -> Candidate:
    """Track the whole record with ``channel`` (the runtime's tracker) and score it on the
    held-out rows."""
    force, _ = track_series(channel, data.resistance_ohm, data.time_s)
    err = force - data.force_n
    return Candidate(
        name=name,
        channel=channel,
        held_out_force_rms_n=rms(err[data.test]),
        drift=held_out_drift(data, force, full_scale, holds),
        train_force_rms_n=rms(err[data.train]),
        force_n=force,
    )


def rank_candidates(
    data: FitData,
    kinds: Sequence[str] = CURVE_KINDS,
    forms: Sequence[str] | None = None,
    real_time: bool = True,
    range_n: tuple[float, float] | None = None,
) -> list[Candidate]:
    """Every curve kind with every drift form (time-driven forms only with real time), fitted
    and scored as written: calibrated over ``range_n`` (N; default: the fitted record's loaded
    range). Best held-out force RMS first. A candidate that cannot be fitted is left out."""
    reg = _Regressors(data)
    chosen = list(forms) if forms is not None else list(DRIFT_FORMS)
    if not real_time:
        chosen = [f for f in chosen if not DRIFT_FORMS[f].time_driven]
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
            if range_n is not None:
                ch = ch.with_range(*range_n)
            out.append(score(data, f"{kind} + {form}", ch, reg.full_scale, holds))
    return sorted(
        out, key=lambda c: c.held_out_force_rms_n if math.isfinite(c.held_out_force_rms_n) else math.inf
    )
