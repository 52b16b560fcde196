"""What a fit minimises, and the reference-force zero offset (used by ``fitting``; both
read the record through ``fit_data.FitData``, below them).

Two objectives:

- ``"log_r"`` (the default): ln R_measured - ln R_model per row, weighted by 1/sigma of the
  measurement model, soft-L1 with ``f_scale`` = 0.05 (about 5 % in resistance). This is the
  maximum-likelihood fit when the log-resistance noise is what the measurement model says.
- ``"force"``: the same log-residual divided by the model's local sensitivity,
  (ln R_measured - ln R_model) / |d ln R_model / dF|, which is to first order the force error
  the model makes when it reads that row. Every row then counts in newtons, as the held-out
  force RMS (the number calibration is judged by) does. The sensitivity is a forward
  difference in the driving force, re-simulating the whole history at F + h with
  h = max(1e-3 N, 1e-3 |F|), and is floored at 1 % of 1/full scale so that a flat stretch of
  the model cannot divide by zero. The residuals are not weighted by the measurement model
  (that would turn it back into the log-R objective); ``f_scale`` is 5 % of the record's full
  scale (its largest usable reference force): force errors beyond the accuracy a calibration
  is meant to reach are treated as outliers by the soft-L1 loss.

The reference zero offset ``force_offset_n`` (fitted by ``fit_channel(...,
fit_force_offset=True)``) is the amount added to the reference force to get the force that
drives the model: F_model = F_ref + offset. A load cell that reads -0.1 N with nothing on it
has offset +0.1 N. It is fitted on a linear scale of 0.1 N, within +-max(0.5 N, 10 % of full
scale) and no lower than what drives the smallest loaded row at 0.1 % of full scale (the model
cannot read a loaded row at 0 N), with a signed (clipped Wald) 95 % interval. When it ends at
that lower bound the data would move the zero further than a loaded row allows: the estimate
is then a bound, and its interval is one-sided.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np
from numpy.typing import NDArray

from ..keys import Choice
from ..model import SensorModel, SensorParams
from ..model.series import ForceSeries
from .fit_data import FitData

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
#: name of the reference-force zero offset in estimates and correlations (not a SensorParams field)
OFFSET = "force_offset_n"
#: the offset is fitted as offset / OFFSET_SCALE
OFFSET_SCALE = 0.1
LOG_R_F_SCALE = 0.05
#: soft-L1 scale of the force objective, as a share of full scale
FORCE_F_SCALE_SHARE = 0.05
#: sensitivity floor, as a share of 1 / full scale
SENSITIVITY_FLOOR_SHARE = 0.01
#: force histories a problem keeps (at the offsets of a Jacobian's base point and offset column,
#: each stepped up or not)
KEPT_HISTORIES = 4


class Objective(Choice):
    """What the physical model's fit minimises: log-resistance residuals, force residuals
    (started from the log-R fit), or both, keeping the one that reads held-out force better."""

    AUTO = "auto"
    LOG_R = "log_r"
    FORCE = "force"

    @property
    def option(self) -> str:
        """The command line's spelling (``log-r``)."""
        return self.value.replace("_", "-")


#: The objectives one fit minimises (``auto`` chooses between two fits; it is none itself).
FIT_OBJECTIVES = (Objective.LOG_R, Objective.FORCE)


def check_objective(objective: str) -> Objective:
    """``objective`` as one of ``FIT_OBJECTIVES``; ``ValueError`` naming them otherwise."""
    if objective not in FIT_OBJECTIVES:
        raise ValueError(f"objective must be one of {', '.join(FIT_OBJECTIVES)}, got {objective!r}")
    return Objective(objective)


def full_scale(force_n: FloatArray, usable: BoolArray) -> float:
    """The record's largest usable reference force (1 N when there is none)."""
    f = force_n[usable & np.isfinite(force_n)]
    top = float(f.max()) if f.size else 0.0
    return top if top > 0 else 1.0


def f_scale(objective: str, force_n: FloatArray, usable: BoolArray) -> float:
    """The soft-L1 scale: 0.05 in ln R, or 5 % of full scale in newtons."""
    if check_objective(objective) is Objective.LOG_R:
        return LOG_R_F_SCALE
    return FORCE_F_SCALE_SHARE * full_scale(force_n, usable)


def offset_bounds(force_n: FloatArray, usable: BoolArray) -> tuple[float, float]:
    """The offset's allowed range: +-max(0.5 N, 10 % of full scale), and no lower than what
    drives the smallest usable reference force at 0.1 % of full scale (a loaded row driven at
    0 N or less is outside what the model can read)."""
    scale = full_scale(force_n, usable)
    half = max(0.5, 0.1 * scale)
    f = force_n[usable & np.isfinite(force_n)]
    lowest = float(f.min()) if f.size else 0.0
    return max(-half, -lowest + 1e-3 * scale), half


def force_step(force_n: FloatArray) -> FloatArray:
    """The step of the sensitivity's forward difference: max(1e-3 N, 1e-3 |F|)."""
    return np.asarray(np.maximum(1e-3, 1e-3 * np.abs(force_n)))


def force_residual(
    log_residual: FloatArray, log_r_model: FloatArray, log_r_up: FloatArray, step: FloatArray, floor: float
) -> FloatArray:
    """(ln R_meas - ln R_model) / |d ln R_model / dF| on the given rows, NaN where undefined:
    to first order the force error the model makes when it reads the row.

    ``log_r_up`` is ln R_model driven at F + ``step``; the sensitivity is floored at ``floor``
    (in 1/N), and a NaN sensitivity (the model undefined at F + step) takes the floor too. Near
    F = 0 a contact term (R ~ 1/F) makes the first order too small: a row driven at F -> 0
    costs about F ln(F_read / F) -> 0 whatever it reads. Nothing drives a loaded row there but
    the zero offset, and its bounds keep every loaded row at 0.1 % of full scale or more."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        s = np.fmax(np.abs((log_r_up - log_r_model) / step), floor)  # fmax: NaN gives the floor
        return np.asarray(log_residual / s)


class Problem:
    """The least-squares problem of one fit: parameters, bounds and residuals.

    ``names`` are the free parameters (``OFFSET`` among them when the zero offset is fitted);
    ``offset`` is the offset's starting value, or its fixed value when it is not fitted."""

    def __init__(
        self,
        data: FitData,
        effects: tuple[str, ...],
        prior: SensorParams,
        names: tuple[str, ...],
        objective: str = "log_r",
        offset: float = 0.0,
    ):
        self.data = data
        self.effects = effects
        self.prior = prior
        self.names = names
        self.objective = check_objective(objective)
        self.offset0 = offset
        self.temp = None if data.temperature_c is None else data.temperature_c[:, None]
        self.train = data.train
        self.weight = data.weights()[self.train]
        scale = full_scale(data.force_n, data.usable)
        self.floor = SENSITIVITY_FLOOR_SHARE / scale
        self.penalty = scale  # a force error of full scale where the model is undefined
        self.step = force_step(data.force_n + offset)
        self._histories: OrderedDict[tuple[float, bool], ForceSeries] = OrderedDict()
        with np.errstate(divide="ignore", invalid="ignore"):
            self.log_measured = np.log(data.resistance_ohm)
        self._rows = np.flatnonzero(self.train)  # the training rows, as indices
        #: per free name: fitted on a linear scale (value = x scale) or in log space (prior e^x)
        self._scales = [
            (
                n,
                n in LINEAR_PARAMETERS,
                LINEAR_PARAMETERS[n] if n in LINEAR_PARAMETERS else getattr(prior, n, 0.0),
            )
            for n in names
        ]
        self._log_measured_train = self.log_measured[self._rows]
        self._step_train = self.step[self._rows]

    def params(self, x: FloatArray) -> SensorParams:
        values = {}
        for (name, linear, scale), xi in zip(self._scales, x.tolist(), strict=True):
            if linear:
                values[name] = xi * scale
            elif name != OFFSET:
                values[name] = scale * math.exp(xi)
        return self.prior.replaced(values)

    def offset(self, x: FloatArray) -> float:
        """The reference zero offset at x (the fixed starting value when it is not fitted)."""
        if OFFSET in self.names:
            return float(x[self.names.index(OFFSET)]) * OFFSET_SCALE
        return self.offset0

    def x0(self) -> FloatArray:
        x = []
        for name in self.names:
            if name == OFFSET:
                x.append(self.offset0 / OFFSET_SCALE)
                continue
            value = getattr(self.prior, name)
            x.append(value / LINEAR_PARAMETERS[name] if name in LINEAR_PARAMETERS else 0.0)
        return np.array(x, dtype=np.float64)

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        lo, hi = [], []
        for name in self.names:
            if name == OFFSET:
                low, high = offset_bounds(self.data.force_n, self.data.usable)
                lo.append(low / OFFSET_SCALE)
                hi.append(high / OFFSET_SCALE)
            elif name == "temperature_coeff_per_k":
                lo.append(-20.0)
                hi.append(20.0)
            elif name in LINEAR_PARAMETERS:
                lo.append(0.0)
                hi.append(max(100.0, 100.0 * getattr(self.prior, name) / LINEAR_PARAMETERS[name]))
            else:
                lo.append(-LOG_BOUND)
                hi.append(LOG_BOUND)
        return np.array(lo), np.array(hi)

    def model_ohm(self, params: SensorParams, offset: float | None = None, up: bool = False) -> FloatArray:
        """The model's resistance on every row, driven by the record's force history plus the
        offset (and plus the sensitivity's ``step`` when ``up``)."""
        return self._ohm(SensorModel(self.effects, params), self.offset0 if offset is None else offset, up)

    def _ohm(self, model: SensorModel, offset: float, up: bool) -> FloatArray:
        return np.asarray(model.total_ohm(self._history(offset, up), self.temp)[:, 0])

    def _history(self, offset: float, up: bool) -> ForceSeries:
        """The force history at this offset (stepped up or not): the last few are kept, with the
        state series solved on them (``ForceSeries``), since most residuals share them."""
        key = (offset, up)
        history = self._histories.pop(key, None)
        if history is None:
            force = self.data.force_n + offset + (self.step if up else 0.0)
            history = ForceSeries.of(force[:, None], self.data.time_s, 1)
        self._histories[key] = history
        if len(self._histories) > KEPT_HISTORIES:
            self._histories.popitem(last=False)
        return history

    def log_residual(self, params: SensorParams, offset: float | None = None) -> FloatArray:
        """ln R_measured - ln R_model on every row (NaN where either side is not finite)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return _finite_or_nan(self.log_measured - np.log(self.model_ohm(params, offset)))

    def residual(self, x: FloatArray) -> FloatArray:
        try:
            params, offset = self.params(x), self.offset(x)
            if self.objective is Objective.FORCE:
                return self._force_residual(params, offset)
            ohm = self.model_ohm(params, offset)[self._rows]
        except ValueError:
            return np.full(self._rows.size, 1e3)
        with np.errstate(divide="ignore", invalid="ignore"):
            res = self._log_measured_train - np.log(ohm)
        # a row where either side is not finite costs 10 (np.nan_to_num of its NaN, in effect)
        return np.asarray(np.where(np.isfinite(res), res, 10.0) * self.weight)

    def _force_residual(self, params: SensorParams, offset: float) -> FloatArray:
        sensor = SensorModel(self.effects, params)
        rows = self._rows
        with np.errstate(divide="ignore", invalid="ignore"):
            base = np.log(self._ohm(sensor, offset, False)[rows])
            up = np.log(self._ohm(sensor, offset, True)[rows])
            log_res = _finite_or_nan(self._log_measured_train - base)
        res = force_residual(log_res, base, up, self._step_train, self.floor)
        # undefined (NaN) or infinite: a force error of full scale, of the infinity's sign
        return np.asarray(np.where(np.isfinite(res), res, np.where(res < 0.0, -self.penalty, self.penalty)))


def log_ratio(measured: FloatArray, model: FloatArray) -> FloatArray:
    """ln measured - ln model, NaN where it is not finite."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return _finite_or_nan(np.log(measured) - np.log(model))


def _finite_or_nan(x: FloatArray) -> FloatArray:
    return np.asarray(np.where(np.isfinite(x), x, np.nan))
