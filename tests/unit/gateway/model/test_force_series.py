"""``ForceSeries``: a fit's force history, with the state effects' series reused while the
parameters they read are unchanged (``gateway.model.series``), and the play operator's clamp.

A reused series must be the one a new solve gives: every parameter a state effect's series
reads must be named in its ``series_parameters`` (else a changed value would reuse a stale
series), and a model driven through one history with parameter sets that change one value at
a time (as a finite-difference Jacobian does) must give ``simulate``'s numbers bit for bit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.model import SensorModel, SensorParams
from gateway.model.params import ChannelParams, parameter_names
from gateway.model.physics import _clip, play_series
from gateway.model.series import KEPT_SERIES, ForceSeries
from gateway.model.submodels import Creep, Creep2, Hysteresis, StrainState

ALL_EFFECTS = ("tunneling", "contact", "creep", "creep2", "hysteresis", "temperature", "series_resistance")


def _history(seed: int = 0, rows: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """A staircase of holds and ramps from 0 to 8 N at irregular times, with noise (N, s)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.05, 2.0, rows))
    levels = np.repeat(rng.uniform(0.0, 8.0, rows // 40 + 1), 40)[:rows]
    return np.maximum(levels + rng.normal(0.0, 0.05, rows), 0.0), t


def _scaled(params: SensorParams, name: str, factor: float) -> SensorParams:
    value = getattr(params, name)
    if name == "force_max_n":
        return replace(params, force_max_n=value * factor)
    if name == "volume_fraction":
        return replace(params, volume_fraction=value * 0.9)
    if name == "temperature_coeff_per_k":
        return replace(params, temperature_coeff_per_k=value * 0.5)
    if name == "reference_temperature_c":
        return replace(params, reference_temperature_c=value + 3.0)
    if name == "hysteresis_strain":
        return replace(params, hysteresis_strain=value * 0.5)
    return replace(params, **{name: value * factor if value else 1.0})


@pytest.mark.parametrize("kind", [Creep, Creep2, Hysteresis])
def test_a_state_series_changes_with_its_series_parameters_and_with_nothing_else(
    kind: type[StrainState],
) -> None:
    force, t = _history()
    h = ForceSeries.of(force[:, None], t, 1)
    base = SensorParams()
    path0 = kind(ChannelParams.stack(base)).state_series(h.force_n, h.held_n, h.dt_s, h.state0)[0]
    assert path0 is not None
    for name in parameter_names():
        effect = kind(ChannelParams.stack(_scaled(base, name, 1.5)))
        path, end = effect.state_series(h.force_n, h.held_n, h.dt_s, h.state0)
        assert path is not None
        if name in kind.series_parameters:
            assert not np.array_equal(path, path0), f"{kind.__name__}: {name} changes nothing"
        else:
            assert np.array_equal(path, path0), f"{kind.__name__} reads {name}: add it to series_parameters"
        # series is the two steps: the path, then the strain made from it
        strain, end_again = effect.series(h.force_n, h.held_n, h.dt_s, h.state0)
        assert strain is not None and end_again.keys() == end.keys()
        assert np.array_equal(strain, effect.path_strain(path))


def test_the_hysteresis_strain_is_minus_h_times_the_load_direction() -> None:
    # one step up from rest to 5 N with F_h = 0.5 N: the play moves 4.95 N, the direction goes to
    # 1 - exp(-9.9) and the strain before the next sample is -h times that
    params = ChannelParams.stack(SensorParams(hysteresis_strain=1e-3, hysteresis_force_n=0.5))
    h = ForceSeries.of(np.array([[5.0], [5.0]]), np.array([0.0, 1.0]), 1)
    strain, end = Hysteresis(params).series(h.force_n, h.held_n, h.dt_s, h.state0)
    assert strain is not None
    assert strain[:, 0] == pytest.approx([0.0, -1e-3 * (1.0 - np.exp(-9.9))], rel=1e-12)
    assert end["play_n"][0] == pytest.approx(4.95) and end["direction"][0] == pytest.approx(
        1.0 - np.exp(-9.9)
    )


def test_a_model_driven_through_one_history_reads_as_simulate_one_parameter_at_a_time() -> None:
    force, t = _history(seed=3)
    temp = 25.0 + 5.0 * np.sin(t / 50.0)[:, None]
    history = ForceSeries.of(force[:, None], t, 1)
    base = SensorParams(leakage_resistance_ohm=5e5)
    effects = (*ALL_EFFECTS, "leakage")
    # a Jacobian's pattern: the base point, then each parameter moved alone, back to the base in between
    moved = ["r0_ohm", "e1_pa", "hysteresis_force_n", "mu2_pa_s", "rho2_ohm_m", "e1_slope_pa_per_n"]
    moved += ["e0_pa", "area_m2", "hardness_pa", "hysteresis_strain", "series_resistance_ohm"]
    for params in [base, *(_scaled(base, name, 1.001) for name in moved), base]:
        model = SensorModel(effects, params)
        reused = model.total_ohm(history, temp)
        fresh = model.simulate(force[:, None], t, temperature_c=temp)[0].total_ohm
        assert np.array_equal(reused, fresh)
    assert len(history._solved) <= KEPT_SERIES


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    rows=st.integers(1, 300),
    scale=st.floats(1e-3, 1e3),
    effects=st.lists(st.sampled_from(ALL_EFFECTS), max_size=7),
)
def test_total_ohm_is_simulates_total_on_any_history(
    seed: int, rows: int, scale: float, effects: list[str]
) -> None:
    force, t = _history(seed, rows)
    params = replace(SensorParams(), e1_pa=SensorParams().e1_pa * scale, hysteresis_force_n=0.5 * scale)
    model = SensorModel(effects, params)
    history = ForceSeries.of(force[:, None], t, 1)
    assert np.array_equal(model.total_ohm(history), model.simulate(force[:, None], t)[0].total_ohm)
    assert np.array_equal(model.total_ohm(history), model.total_ohm(history))  # reused: the same


def test_the_clamp_is_np_clip_with_its_nans_and_its_signed_zeros() -> None:
    rng = np.random.default_rng(7)
    x, low = rng.normal(size=(2, 500, 1))
    high = low + np.abs(rng.normal(size=(500, 1)))
    x[::7], low[::11] = np.nan, np.nan
    assert np.array_equal(_clip(x, low, high), np.clip(x, low, high), equal_nan=True)
    zeros = np.array([0.0, -0.0])
    for xs, lows, highs in [(zeros, zeros[::-1], np.ones(2)), (zeros, -np.ones(2), zeros[::-1])]:
        got, want = _clip(xs, lows, highs), np.clip(xs, lows, highs)
        assert np.array_equal(np.signbit(got), np.signbit(want))


def test_the_play_follows_the_force_within_its_dead_band() -> None:
    # hand-computed: radius 1 N from p0 = 0; F = 3 pulls the play to 2, F = 2.5 leaves it,
    # F = 0 pulls it to 1, F = 0.5 leaves it, F = -4 pulls it to -3
    force = np.array([[3.0], [2.5], [0.0], [0.5], [-4.0]])
    play = play_series(force, np.array([1.0]), np.zeros(1))
    assert play[:, 0].tolist() == [2.0, 2.0, 1.0, 1.0, -3.0]
