"""The physical model's start when the load history is not known (``SensorModel.unknown_state``):
a sensor that is already loaded and settled is read at its load from the first sample on, never
as a load just applied to a rested sensor (issue 32: "it never starts from rest")."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.model import PAPER_EFFECTS, SensorModel, SensorParams
from gateway.model.inversion import ForceStatus

DYNAMIC = ("tunneling,contact,creep", "tunneling,contact,creep,creep2,hysteresis", PAPER_EFFECTS)


def settled_resistance(model: SensorModel, force_n: float) -> np.ndarray:
    """The resistance of a step of ``force_n`` held for 1e9 s: the paper's closed form (eq. 15-17)."""
    f = np.full(model.n_channels, force_n)
    return np.asarray(model.held_step(f, np.full(model.n_channels, 1e9)).total_ohm)


@settings(max_examples=25, deadline=None)
@given(force_n=st.floats(0.2, 9.0), effects=st.sampled_from(DYNAMIC))
def test_a_settled_load_reads_its_force_from_the_first_sample_and_stays(force_n: float, effects: str) -> None:
    model = SensorModel(effects, [SensorParams()])
    r = settled_resistance(model, force_n)
    times = np.arange(0.0, 30.0, 0.25)
    series = np.tile(r, (times.size, 1))
    inv, _ = model.track_series(series, times, model.unknown_state())
    np.testing.assert_allclose(inv.force_n[:, 0], force_n, rtol=1e-7)
    # sample by sample, the same
    state = model.unknown_state()
    for dt in (0.0, 0.25, 0.25, 5.0):
        one, state = model.track(r, state, dt)
        assert one.force_n[0] == pytest.approx(force_n, rel=1e-7)
    # from rest the same resistance reads as a load just applied: too high
    rest, _ = model.track_series(series, times, model.initial_state())
    assert rest.force_n[0, 0] > force_n * 1.01


def test_without_state_effects_the_unknown_start_is_the_rested_one() -> None:
    model = SensorModel("tunneling,contact", [SensorParams()] * 3)
    r = np.asarray(model.resistance(np.array([0.5, 2.0, 7.0])))
    times = np.arange(0.0, 5.0, 0.5)
    a, _ = model.track_series(np.tile(r, (times.size, 1)), times, model.unknown_state())
    b, _ = model.track_series(np.tile(r, (times.size, 1)), times, model.initial_state())
    np.testing.assert_array_equal(a.force_n, b.force_n)


def test_a_first_sample_without_a_reading_waits_and_no_contact_starts_at_rest() -> None:
    model = SensorModel("tunneling,contact,creep", [SensorParams()] * 2)
    r = settled_resistance(model, 4.0)
    state = model.unknown_state()
    # channel 0 has no reading, channel 1 reads an unloaded sensor: the first stays unknown
    inv, state = model.track(np.array([math.nan, math.inf]), state, 0.1)
    assert inv.status.tolist() == [ForceStatus.INVALID, ForceStatus.NO_CONTACT]
    assert math.isnan(state.last_force_n[0]) and state.last_force_n[1] == 0.0 and state.kv1_strain[1] == 0.0
    # then both read the settled 4 N: channel 0 from its equilibrium, channel 1 as a load just applied
    inv, state = model.track(np.array([r[0], r[1]]), state, 0.1)
    assert inv.force_n[0] == pytest.approx(4.0, rel=1e-7)
    assert inv.force_n[1] > 4.0 * 1.01
    assert not np.isnan(state.last_force_n).any()


def test_the_equilibrium_is_the_settled_state_at_that_force() -> None:
    model = SensorModel("tunneling,contact,creep,creep2,hysteresis", [SensorParams()])
    p = SensorParams()
    inv, state = model.equilibrium_state(settled_resistance(model, 3.0))
    assert inv.force_n[0] == pytest.approx(3.0, rel=1e-7)
    # every Kelvin element at sigma / E (eq. 14 settled), the load held, the direction loading
    e1 = p.e1_pa + p.e1_slope_pa_per_n * 3.0
    assert state.kv1_strain[0] == pytest.approx(3.0 / (p.area_m2 * e1), rel=1e-7)
    assert state.last_force_n[0] == pytest.approx(3.0, rel=1e-7)
    assert 0.0 < state.direction[0] <= 1.0
