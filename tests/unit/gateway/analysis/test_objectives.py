"""The residuals a fit minimises (``gateway.analysis.objectives.Problem``): exact data read
exactly, and the fixed costs of rows the model or the measurement cannot read."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.analysis.fit_data import FitData
from gateway.analysis.objectives import Objective, Problem
from gateway.model import SensorModel, SensorParams

EFFECTS = ("tunneling", "contact", "creep")
PRIOR = SensorParams()


def _data(bad: dict[int, float], effects: tuple[str, ...] = EFFECTS) -> FitData:
    """20 rows, 1-5 N over 19 s, read by the prior itself; ``bad`` rows' resistances replaced."""
    t = np.arange(20.0)
    f = np.linspace(1.0, 5.0, 20)
    r = SensorModel(effects, PRIOR).simulate(f[:, None], t)[0].total_ohm[:, 0].copy()
    for row, value in bad.items():
        r[row] = value
    held_out = np.zeros(20, dtype=bool)
    held_out[[10, 11]] = True
    return FitData(t, r, f, None, np.ones(20, dtype=bool), held_out)


BAD = {3: np.nan, 5: np.inf, 7: 0.0}
TRAIN_ROWS = [k for k in range(20) if k not in (10, 11)]


def test_log_r_residuals_are_zero_on_exact_rows_and_10_on_unreadable_ones() -> None:
    problem = Problem(_data(BAD), EFFECTS, PRIOR, ("r0_ohm", "e0_pa"), Objective.LOG_R)
    res = problem.residual(problem.x0())
    assert res.size == len(TRAIN_ROWS)  # the training rows only
    expected = [10.0 if k in BAD else 0.0 for k in TRAIN_ROWS]
    assert res == pytest.approx(expected, abs=1e-12)


def test_force_residuals_cost_full_scale_where_undefined() -> None:
    problem = Problem(_data(BAD), EFFECTS, PRIOR, ("r0_ohm", "e0_pa"), Objective.FORCE)
    res = problem.residual(problem.x0())
    full_scale = 5.0  # the largest usable reference force
    expected = [full_scale if k in BAD else 0.0 for k in TRAIN_ROWS]
    assert res == pytest.approx(expected, abs=1e-9)


def test_a_force_residual_is_the_force_error_to_first_order() -> None:
    # without contact, R0 x 1.01 raises ln R_model by ln 1.01 on every row; divided by
    # |d ln R / dF|, from a shift of the force by max(1e-3 N, 1e-3 F), it is the force the model
    # is off by
    effects = ("tunneling", "creep")
    data = _data({}, effects)
    problem = Problem(data, effects, PRIOR, ("r0_ohm",), Objective.FORCE)
    res = problem.residual(np.array([np.log(1.01)]))
    model = SensorModel(effects, SensorParams(r0_ohm=PRIOR.r0_ohm * 1.01))
    step = np.maximum(1e-3, 1e-3 * data.force_n)
    base = np.log(model.simulate(data.force_n[:, None], data.time_s)[0].total_ohm[:, 0])
    up = np.log(model.simulate((data.force_n + step)[:, None], data.time_s)[0].total_ohm[:, 0])
    slope = np.abs((up - base) / step)
    # the model reads a higher resistance than measured: ln 1.01 over the slope, below zero
    assert res == pytest.approx(-np.log(1.01) / slope[TRAIN_ROWS], rel=1e-9)


def test_parameters_outside_their_range_cost_1000_on_every_row() -> None:
    problem = Problem(_data({}), EFFECTS, PRIOR, ("series_resistance_ohm",), Objective.LOG_R)
    res = problem.residual(np.array([-1.0]))  # -1000 ohm: not a resistance
    assert res.tolist() == [1e3] * len(TRAIN_ROWS)
