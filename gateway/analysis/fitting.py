"""Fitting a channel's model to a measurement record (shared by calibration and discrepancy).

The fit minimises log-resistance residuals, ln R_measured - ln R_model, where the model is
driven by the record's reference force history (the creep state needs the whole history,
unusable rows included). Positive parameters are fitted as ln(p / prior) and force slopes
as (slope / scale), which makes the problem well scaled; ``scipy.optimize.least_squares``
runs with bounds and a soft-L1 robust loss. Confidence intervals come from the Jacobian at
the solution. Gaps are measured on held-out segments of the timeline that the fit never saw.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..model import EFFECT_PARAMETERS, ForceStatus, SensorModel, SensorParams, parse_effects
from ..model.params import PARAMETER_RANGES
from .records import ChannelRecord

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Parameters fitted on a linear scale (they may be zero); the rest are fitted in log space.
LINEAR_PARAMETERS: dict[str, float] = {
    "e0_slope_pa_per_n": 1e6,
    "e1_slope_pa_per_n": 1e7,
    "mu1_slope_pa_s_per_n": 1e9,
    "temperature_coeff_per_k": 0.01,
    "series_resistance_ohm": 1e3,
}
#: log-space half-width of the bounds: a factor of 1000 either way of the prior.
LOG_BOUND = math.log(1e3)
Z95 = 1.959963984540054
HELD_OUT_BLOCKS = 20  # the timeline is cut in this many blocks; every fourth is held out


@dataclass(frozen=True)
class Gap:
    """How far model and data are apart, on a set of rows."""

    log_resistance_rms: float
    force_rms_n: float

    def as_dict(self) -> dict[str, float]:
        return {"log_resistance_rms": self.log_resistance_rms, "force_rms_n": self.force_rms_n}


@dataclass(frozen=True)
class ParameterEstimate:
    """A fitted (or fixed) parameter with its 95 % confidence interval."""

    name: str
    value: float
    low: float
    high: float
    fitted: bool
    note: str = ""


@dataclass(frozen=True)
class FitResult:
    """Everything a fit produced for one channel."""

    effects: tuple[str, ...]
    params: SensorParams
    estimates: tuple[ParameterEstimate, ...]
    correlation_names: tuple[str, ...]
    correlation: FloatArray
    gap_train: Gap
    gap_test: Gap
    n_train: int
    n_test: int
    n_parameters: int
    fixed_reasons: dict[str, str] = field(default_factory=dict)
    log_residual: FloatArray = field(default_factory=lambda: np.zeros(0))
    model_ohm: FloatArray = field(default_factory=lambda: np.zeros(0))
    force_inverted_n: FloatArray = field(default_factory=lambda: np.zeros(0))

    def estimate(self, name: str) -> ParameterEstimate:
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)


@dataclass(frozen=True)
class FitData:
    """One channel's samples prepared for fitting."""

    time_s: FloatArray
    resistance_ohm: FloatArray
    force_n: FloatArray
    temperature_c: FloatArray | None
    usable: BoolArray
    held_out: BoolArray
    #: per-row standard deviation of ln R (``measurement.NoiseModel``); None: uniform noise
    sigma_log: FloatArray | None = None

    @classmethod
    def from_channel(
        cls,
        channel: ChannelRecord,
        held_out_blocks: int = HELD_OUT_BLOCKS,
        sigma_log: FloatArray | None = None,
    ) -> FitData:
        if channel.force_n is None:
            raise ValueError(
                f"channel {channel.name!r} has no force_n column: a fit needs the reference force"
            )
        t = channel.time_s
        span = float(t[-1] - t[0]) if t.size else 0.0
        block = np.zeros(t.size, dtype=np.int64)
        if span > 0:
            block = np.minimum(((t - t[0]) / span * held_out_blocks).astype(np.int64), held_out_blocks - 1)
        return cls(
            time_s=t,
            resistance_ohm=channel.resistance_ohm,
            force_n=channel.force_n,
            temperature_c=channel.temperature_c,
            usable=channel.usable_for_fit(),
            held_out=np.asarray(block % 4 == 2),
            sigma_log=sigma_log,
        )

    def weights(self) -> FloatArray:
        """Residual weights 1/sigma, scaled to a median of 1 over the usable rows (uniform: 1)."""
        if self.sigma_log is None:
            return np.ones(self.time_s.size)
        s = self.sigma_log
        ok = self.usable & np.isfinite(s) & (s > 0)
        ref = float(np.median(s[ok])) if ok.any() else 1.0
        with np.errstate(divide="ignore"):
            return np.asarray(np.where(np.isfinite(s) & (s > 0), ref / s, 0.0))

    @property
    def train(self) -> BoolArray:
        return np.asarray(self.usable & ~self.held_out)

    @property
    def test(self) -> BoolArray:
        return np.asarray(self.usable & self.held_out)


def parameters_for(effects: Iterable[str]) -> tuple[str, ...]:
    """The parameters a model with these effects fits, in effect order."""
    out: list[str] = []
    for e in parse_effects(effects):
        out.extend(EFFECT_PARAMETERS[e])
    return tuple(out)


def record_limitations(data: FitData, effects: Sequence[str], prior: SensorParams) -> dict[str, str]:
    """Parameters this record cannot determine, with the reason in words."""
    reasons: dict[str, str] = {}
    f = data.force_n[data.usable]
    if f.size == 0:
        return dict.fromkeys(parameters_for(effects), "the record has no usable rows")
    lo, hi = float(np.percentile(f, 2)), float(np.percentile(f, 98))
    holds = _hold_durations(data.time_s, data.force_n)
    tau_s = prior.mu1_pa_s / prior.e1_pa
    long_holds = [(level, d) for level, d in holds if d >= 0.2 * tau_s and level > 0]
    if "contact" in effects and hi < 3.0 * lo:
        reasons["rho2_ohm_m"] = (
            f"the force range {lo:.2g}-{hi:.2g} N is too narrow to separate contact from tunneling "
            "(needs a max/min force ratio of at least 3)"
        )
    if hi < 3.0 * lo:
        reasons["e0_slope_pa_per_n"] = f"the force range {lo:.2g}-{hi:.2g} N is too narrow for a force slope"
    if "creep" in effects:
        if not long_holds:
            why = (
                f"no hold of at least {0.2 * tau_s:.0f} s (0.2 tau): creep cannot be fitted from this "
                "record; record constant loads held for minutes"
            )
            for name in EFFECT_PARAMETERS["creep"]:
                reasons[name] = why
        else:
            levels = sorted({round(level, 1) for level, _ in long_holds})
            if len(levels) < 2 or levels[-1] < 2.0 * levels[0]:
                why = (
                    "holds at only one force level: the force slopes of E1 and mu1 need holds at two or more"
                )
                reasons["e1_slope_pa_per_n"] = why
                reasons["mu1_slope_pa_s_per_n"] = why
    if "temperature" in effects:
        temps = data.temperature_c
        if temps is None or float(np.ptp(temps[data.usable])) < 2.0:
            reasons["temperature_coeff_per_k"] = "the record's temperature varies by less than 2 K"
    return reasons


def _hold_durations(time_s: FloatArray, force_n: FloatArray) -> list[tuple[float, float]]:
    """(level, duration) of every run of constant force (within 1 % or 0.01 N)."""
    runs: list[tuple[float, float]] = []
    if time_s.size == 0:
        return runs
    start = 0
    for k in range(1, time_s.size + 1):
        if k == time_s.size or abs(force_n[k] - force_n[start]) > max(0.01, 0.01 * abs(force_n[start])):
            runs.append((float(force_n[start]), float(time_s[k - 1] - time_s[start])))
            start = k
    return runs


class _Problem:
    """The least-squares problem of one fit."""

    def __init__(self, data: FitData, effects: tuple[str, ...], prior: SensorParams, names: tuple[str, ...]):
        self.data = data
        self.effects = effects
        self.prior = prior
        self.names = names
        self.force = data.force_n[:, None]
        self.temp = None if data.temperature_c is None else data.temperature_c[:, None]
        self.train = data.train
        self.weight = data.weights()[self.train]

    def params(self, x: FloatArray) -> SensorParams:
        values = {}
        for name, xi in zip(self.names, x, strict=True):
            if name in LINEAR_PARAMETERS:
                values[name] = float(xi) * LINEAR_PARAMETERS[name]
            else:
                values[name] = getattr(self.prior, name) * math.exp(float(xi))
        return replace(self.prior, **values)

    def x0(self) -> FloatArray:
        x = []
        for name in self.names:
            value = getattr(self.prior, name)
            x.append(value / LINEAR_PARAMETERS[name] if name in LINEAR_PARAMETERS else 0.0)
        return np.array(x, dtype=np.float64)

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        lo, hi = [], []
        for name in self.names:
            if name == "temperature_coeff_per_k":
                lo.append(-20.0)
                hi.append(20.0)
            elif name in LINEAR_PARAMETERS:
                lo.append(0.0)
                hi.append(max(100.0, 100.0 * getattr(self.prior, name) / LINEAR_PARAMETERS[name]))
            else:
                lo.append(-LOG_BOUND)
                hi.append(LOG_BOUND)
        return np.array(lo), np.array(hi)

    def model_ohm(self, params: SensorParams) -> FloatArray:
        """The model's resistance on every row, driven by the record's force history."""
        model = SensorModel(self.effects, params)
        out, _ = model.simulate(self.force, self.data.time_s, temperature_c=self.temp)
        return np.asarray(out.total_ohm[:, 0])

    def log_residual(self, params: SensorParams) -> FloatArray:
        """ln R_measured - ln R_model on every row (NaN where either side is not finite)."""
        r_model = self.model_ohm(params)
        with np.errstate(divide="ignore", invalid="ignore"):
            res = np.log(self.data.resistance_ohm) - np.log(r_model)
        return np.asarray(np.where(np.isfinite(res), res, np.nan))

    def residual(self, x: FloatArray) -> FloatArray:
        try:
            res = self.log_residual(self.params(x))[self.train]
        except ValueError:
            return np.full(int(np.count_nonzero(self.train)), 1e3)
        return np.asarray(np.nan_to_num(res, nan=10.0) * self.weight)


def fit_channel(
    data: FitData,
    effects: Iterable[str],
    prior: SensorParams | None = None,
    fit: Sequence[str] | None = None,
    fix: Sequence[str] = (),
    loss: str = "soft_l1",
) -> FitResult:
    """Fit the parameters of ``effects`` (or ``fit``) to one channel's record.

    Parameters the record cannot determine (``record_limitations``) or that come out with a
    95 % interval wider than a factor of 10 are fixed at their prior, with the reason kept.
    """
    chosen = parse_effects(effects)
    prior = prior or SensorParams()
    names = tuple(fit) if fit is not None else parameters_for(chosen)
    reasons = {k: v for k, v in record_limitations(data, chosen, prior).items() if k in names}
    reasons.update({name: "fixed by request" for name in fix if name in names})
    free = tuple(n for n in names if n not in reasons)
    params, x, jac, free = _solve(data, chosen, prior, free, loss)
    # a parameter the data leave undetermined is fixed at its prior, and the rest refitted
    for _ in range(3):
        sigma = _sigma(jac, _Problem(data, chosen, params, free).residual(x), len(free))
        loose = [n for n, s in zip(free, sigma, strict=True) if not (s < _LOOSE_SIGMA.get(n, 1.15))]
        if not loose:
            break
        worst = loose[int(np.argmax([sigma[free.index(n)] for n in loose]))]
        reasons[worst] = "not determined by this record (95 % interval wider than a factor of 10)"
        free = tuple(n for n in free if n != worst)
        params = replace(params, **{worst: getattr(prior, worst)})
        params, x, jac, free = _solve(data, chosen, params, free, loss)
    problem = _Problem(data, chosen, params, free)
    model_all = problem.model_ohm(params)
    with np.errstate(divide="ignore", invalid="ignore"):
        residual_all = np.log(data.resistance_ohm) - np.log(model_all)
    residual_all = np.where(np.isfinite(residual_all), residual_all, np.nan)
    sigma = _sigma(jac, problem.residual(problem.x0()), len(free))
    corr = _correlation(jac, len(free))
    estimates = []
    for name in names:
        value = getattr(params, name)
        if name in free:
            s = float(sigma[free.index(name)])
            if name in LINEAR_PARAMETERS:
                low, high = _bounded_interval(name, value, s * LINEAR_PARAMETERS[name])
            else:
                low, high = value * math.exp(-Z95 * s), value * math.exp(Z95 * s)
            estimates.append(ParameterEstimate(name, value, low, high, True))
        else:
            estimates.append(ParameterEstimate(name, value, value, value, False, reasons.get(name, "")))
    force_inv = invert_drift_corrected(data, chosen, params)
    return FitResult(
        effects=chosen,
        params=params,
        estimates=tuple(estimates),
        correlation_names=free,
        correlation=corr,
        gap_train=_gap(residual_all, force_inv, data, data.train),
        gap_test=_gap(residual_all, force_inv, data, data.test),
        n_train=int(np.count_nonzero(data.train)),
        n_test=int(np.count_nonzero(data.test)),
        n_parameters=len(free),
        fixed_reasons={k: v for k, v in reasons.items() if k not in free},
        log_residual=residual_all,
        model_ohm=model_all,
        force_inverted_n=force_inv,
    )


def _bounded_interval(name: str, value: float, sigma: float) -> tuple[float, float]:
    """A 95 % interval inside the parameter's allowed range: a non-negative parameter's
    interval is taken in log space (delta method on ln p, so it never crosses 0); a signed one
    is the Wald interval clipped to its range."""
    allowed = PARAMETER_RANGES.get(name)
    if allowed is not None and allowed.low == 0.0 and value > 0.0:
        rel = sigma / value
        if not math.isfinite(rel) or Z95 * rel > 700.0:
            return 0.0, math.inf
        return value * math.exp(-Z95 * rel), value * math.exp(Z95 * rel)
    low, high = value - Z95 * sigma, value + Z95 * sigma
    if allowed is not None:
        low, high = max(low, allowed.low), min(high, allowed.high)
    return low, high


# a log-parameter with sigma s has a 95 % interval of a factor exp(2 * 1.96 s); 1.15 is x10 wide
_LOOSE_SIGMA: dict[str, float] = {
    "e0_slope_pa_per_n": 5.0,
    "e1_slope_pa_per_n": 5.0,
    "mu1_slope_pa_s_per_n": 5.0,
    "series_resistance_ohm": 5.0,
    "temperature_coeff_per_k": 5.0,
}


def _solve(
    data: FitData, effects: tuple[str, ...], prior: SensorParams, free: tuple[str, ...], loss: str
) -> tuple[SensorParams, FloatArray, FloatArray, tuple[str, ...]]:
    problem = _Problem(data, effects, prior, free)
    if not free or not problem.train.any():
        return prior, np.zeros(0), np.zeros((0, 0)), free
    lo, hi = problem.bounds()
    x0 = np.clip(problem.x0(), lo, hi)
    result = least_squares(
        problem.residual,
        x0,
        bounds=(lo, hi),
        loss=loss,
        f_scale=0.05,
        x_scale="jac",
        max_nfev=400,
    )
    params = problem.params(result.x)
    # re-express x around the fitted parameters (x = 0 there) for the intervals
    around = _Problem(data, effects, params, free)
    x = around.x0()
    return params, x, _jacobian(around, x), free


def _jacobian(problem: _Problem, x: FloatArray) -> FloatArray:
    """Central-difference Jacobian of the residuals (no robust-loss weighting)."""
    base = problem.residual(x)
    jac = np.empty((base.size, x.size))
    for i in range(x.size):
        h = 1e-4 * max(1.0, abs(float(x[i])))
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        jac[:, i] = (problem.residual(up) - problem.residual(down)) / (2 * h)
    return jac


def _sigma(jac: FloatArray, residual: FloatArray, k: int) -> FloatArray:
    """Standard errors of the fitted (scaled) parameters."""
    if k == 0:
        return np.zeros(0)
    n = residual.size
    s2 = float(residual @ residual) / max(n - k, 1)
    cov = np.linalg.pinv(jac.T @ jac) * s2
    diag = np.diag(cov)
    return np.asarray(np.sqrt(np.where(diag > 0, diag, np.inf)))


def _correlation(jac: FloatArray, k: int) -> FloatArray:
    if k == 0:
        return np.zeros((0, 0))
    cov = np.linalg.pinv(jac.T @ jac)
    d = np.sqrt(np.abs(np.diag(cov)))
    d = np.where(d > 0, d, 1.0)
    return np.asarray(cov / np.outer(d, d))


def invert_drift_corrected(data: FitData, effects: Iterable[str], params: SensorParams) -> FloatArray:
    """Each measured resistance inverted with the model, carrying the creep state."""
    model = SensorModel(tuple(effects), replace(params, force_min_n=min(params.force_min_n, 0.01)))
    temp = None if data.temperature_c is None else data.temperature_c[:, None]
    inv, _ = model.track_series(data.resistance_ohm[:, None], data.time_s, temperature_c=temp)
    f = inv.force_n[:, 0]
    return np.asarray(np.where(inv.status[:, 0] == ForceStatus.INVALID, np.nan, f))


def _gap(residual: FloatArray, force_inv: FloatArray, data: FitData, rows: BoolArray) -> Gap:
    r = residual[rows]
    r = r[np.isfinite(r)]
    df = (force_inv - data.force_n)[rows]
    df = df[np.isfinite(df)]
    return Gap(
        log_resistance_rms=float(np.sqrt(np.mean(r * r))) if r.size else math.nan,
        force_rms_n=float(np.sqrt(np.mean(df * df))) if df.size else math.nan,
    )
