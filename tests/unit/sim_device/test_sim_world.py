"""World effects: exact integrators, and each effect visible above 1 % at its documented size."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from sim_device import ArrayConfig, Scenario, SimArray
from sim_device.world import activation_energy_ev, arrhenius_factor, kelvin_series, play_operator


@settings(max_examples=60, deadline=None)
@given(
    force=arrays(np.float64, st.tuples(st.integers(1, 80), st.integers(1, 3)), elements=st.floats(0, 8)),
    radius=st.floats(0.05, 2.0),
    p0=st.floats(-2, 8),
)
def test_play_operator_matches_the_sequential_definition(force: np.ndarray, radius: float, p0: float) -> None:
    n = force.shape[1]
    r = np.full(n, radius)
    start = np.full(n, p0)
    out = play_operator(force.copy(), r, start)
    p = start.copy()
    for k in range(force.shape[0]):
        p = np.clip(p, force[k] - r, force[k] + r)
        np.testing.assert_allclose(out[k], p, rtol=0, atol=1e-12)


def test_kelvin_series_is_the_exact_step_update() -> None:
    rng = np.random.default_rng(3)
    held = rng.uniform(0, 5, size=(50, 2))
    area, e, mu = np.array([2e-5, 2e-5]), np.array([3e8, 2e8]), np.array([3e11, 1e11])
    x = np.array([1e-4, 0.0])
    out = kelvin_series(held, 7.0, area, e, mu, x)
    for k in range(50):
        target = held[k] / (area * e)
        x = target + (x - target) * np.exp(-e * 7.0 / mu)
        np.testing.assert_allclose(out[k], x, rtol=1e-10)


def test_arrhenius_slope_at_reference_is_the_coefficient() -> None:
    coeff, ref = np.array([-0.005]), np.array([25.0])
    h = 1e-3
    slope = (np.log(arrhenius_factor(np.array([25.0 + h]), coeff, ref)) - np.log(
        arrhenius_factor(np.array([25.0 - h]), coeff, ref))) / (2 * h)  # fmt: skip
    assert slope[0] == pytest.approx(-0.005, rel=1e-5)
    assert activation_energy_ev(-0.005) == pytest.approx(0.0383, abs=2e-4)


def _resistance(effects: tuple[str, ...], scenario: str | Scenario, t_s: float) -> np.ndarray:
    cfg = ArrayConfig(scenario=scenario, world_effects=effects, noise_lsb_rms=0.0, param_spread=False)
    array = SimArray(cfg, clock=lambda: 0.0)
    array.advance(t_s, exact=True)
    return np.asarray(array.latest().true_resistance_ohm[0])


def test_creep2_lowers_a_long_hold_by_several_percent() -> None:
    paper = _resistance((), Scenario.constant(2.0), 1800.0)
    creep2 = _resistance(("creep2",), Scenario.constant(2.0), 1800.0)
    assert creep2[0] / paper[0] < 0.95


def test_hysteresis_separates_loading_and_unloading() -> None:
    cfg = ArrayConfig(scenario="ramps", world_effects=("hysteresis",), noise_lsb_rms=0.0, param_spread=False)
    array = SimArray(cfg, clock=lambda: 0.0)
    up_t = 5.0 + 2.5 / 0.1  # 2.5 N while loading at 0.1 N/s
    down_t = 5.0 + 50.0 + 2.5 / 0.1  # 2.5 N while unloading
    array.advance(up_t, exact=True)
    r_up = array.latest().true_resistance_ohm[0, 0]
    array.advance(down_t, exact=True)
    r_down = array.latest().true_resistance_ohm[0, 0]
    assert array.latest().force_n[0, 0] == pytest.approx(2.5)
    assert r_up / r_down > 1.05, "loading reads a higher resistance than unloading"


def test_temperature_step_changes_resistance() -> None:
    at_35 = 605.0 + 20.0 + 200.0
    paper = _resistance((), "temperature-step", at_35)
    warm = _resistance(("temperature",), "temperature-step", at_35)
    ratio = warm[0] / paper[0]
    assert 0.93 < ratio < 0.97  # about -0.5 %/K on the polymer part over +10 K


def test_series_and_leakage_are_visible() -> None:
    paper = _resistance((), Scenario.constant(5.0), 1.0)
    series = _resistance(("series_resistance",), Scenario.constant(5.0), 1.0)
    assert series[0] - paper[0] == pytest.approx(500.0)
    assert series[0] / paper[0] > 1.04
    low = _resistance(("leakage",), Scenario.constant(0.5), 1.0)
    low_paper = _resistance((), Scenario.constant(0.5), 1.0)
    assert low[0] / low_paper[0] < 0.95
    idle = _resistance(("leakage",), "idle", 1.0)
    assert idle[0] == pytest.approx(2e6)
    assert np.isinf(_resistance((), "idle", 1.0)[0])
