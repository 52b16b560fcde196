"""Force inversion: round trips, flags, and drift correction under creep."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.model import ForceStatus, ModelState, SensorModel, SensorParams

PAPER = "tunneling,contact,creep"
WIDE = SensorParams(force_min_n=0.01, force_max_n=12.0)


@settings(max_examples=300, deadline=None)
@given(
    force_n=st.floats(0.05, 10.0),
    creep_fraction=st.floats(0.0, 1.0),
    effects=st.sampled_from(["tunneling", "tunneling,contact", PAPER]),
)
def test_forward_then_inverse_over_range_and_creep_states(
    force_n: float, creep_fraction: float, effects: str
) -> None:
    m = SensorModel(effects, WIDE)
    p = WIDE
    # any reachable Kelvin strain: between relaxed and fully crept at the top force
    kv_max = p.force_max_n / (p.area_m2 * (p.e1_pa + p.e1_slope_pa_per_n * p.force_max_n))
    state = ModelState(
        np.array([creep_fraction * kv_max]), np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1)
    )
    r = m.resistance(np.array([force_n]), state)
    inv = m.invert(r, state)
    assert inv.status[0] == ForceStatus.OK
    assert inv.force_n[0] == pytest.approx(force_n, rel=1e-6)


@settings(max_examples=100, deadline=None)
@given(force_n=st.lists(st.floats(0.05, 10.0), min_size=1, max_size=16))
def test_static_inverse_is_vectorized_round_trip(force_n: list[float]) -> None:
    m = SensorModel(PAPER, [WIDE] * len(force_n))
    f = np.array(force_n)
    inv = m.invert_static(m.resistance(f))
    np.testing.assert_allclose(inv.force_n, f, rtol=1e-6)


def test_flags_for_bad_and_out_of_range_input() -> None:
    m = SensorModel(PAPER, [SensorParams(force_max_n=5.0)] * 7)
    r = np.array([np.nan, 0.0, -5.0, -np.inf, 1e9, 100.0, 46901.7])
    inv = m.invert_static(r)
    assert inv.status.tolist() == [
        ForceStatus.INVALID,
        ForceStatus.INVALID,
        ForceStatus.INVALID,
        ForceStatus.INVALID,
        ForceStatus.NO_CONTACT,
        ForceStatus.SATURATED,
        ForceStatus.OK,
    ]
    assert np.isnan(inv.force_n[:4]).all()
    assert inv.force_n[4] == 0.0
    assert inv.force_n[5] == 5.0
    assert inv.force_n[6] == pytest.approx(2.0, rel=1e-5)


def test_infinite_resistance_is_no_contact_only_where_the_contact_is_open_at_rest() -> None:
    r = np.array([np.inf, -np.inf])
    with_contact = SensorModel(PAPER, [SensorParams()] * 2).invert_static(r)
    assert with_contact.status.tolist() == [ForceStatus.NO_CONTACT, ForceStatus.INVALID]
    assert with_contact.force_n[0] == 0.0
    for effects in ("tunneling,creep", "tunneling,contact,leakage"):
        inv = SensorModel(effects, [SensorParams()] * 2).invert_static(r)
        assert inv.status.tolist() == [ForceStatus.INVALID, ForceStatus.INVALID], effects


def test_range_edges_are_exact_thresholds() -> None:
    p = SensorParams(force_min_n=0.1, force_max_n=5.0)
    m = SensorModel(PAPER, [p] * 2)
    edges = m.resistance(np.array([0.1, 5.0]))
    inv = m.invert_static(edges)
    assert inv.status.tolist() == [ForceStatus.NO_CONTACT, ForceStatus.SATURATED]
    inside = m.invert_static(edges * np.array([0.999, 1.001]))
    assert inside.status.tolist() == [ForceStatus.OK, ForceStatus.OK]
    assert 0.1 < inside.force_n[0] < 0.11
    assert 4.99 < inside.force_n[1] < 5.0


def _hold_series(
    forces: list[float], seconds: float = 600.0, rate_hz: float = 10.0
) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, seconds + 1e-9, 1.0 / rate_hz)
    return t, np.tile(forces, (t.size, 1))


def test_drift_correction_holds_constant_while_static_drifts() -> None:
    forces = [0.5, 2.0, 5.0]
    m = SensorModel(PAPER, [SensorParams()] * 3)
    t, f = _hold_series(forces)
    measured, _ = m.simulate(f, t)
    corrected, _ = m.track_series(measured.total_ohm, t)
    static = m.invert_static(measured.total_ohm)
    corrected_error = np.abs(corrected.force_n / f - 1).max(axis=0)
    static_end_error = static.force_n[-1] / f[-1] - 1
    print(
        f"\n600 s hold: corrected max rel error {corrected_error}, static drift at 600 s {static_end_error}"
    )
    assert np.all(corrected_error < 1e-3)
    np.testing.assert_allclose(static_end_error, [0.097, 0.111, 0.128], atol=0.001)


def test_online_tracking_equals_series_solution() -> None:
    m = SensorModel(PAPER, [SensorParams()] * 2)
    t, f = _hold_series([0.7, 3.0], seconds=60.0)
    f = f * (1 + 0.3 * np.sin(t / 7.0))[:, None]
    measured, _ = m.simulate(f, t)
    series, end_series = m.track_series(measured.total_ohm, t)
    state = m.initial_state()
    online = np.empty_like(f)
    for k in range(t.size):
        inv, state = m.track(measured.total_ohm[k], state, t[k] - t[k - 1] if k else 0.0)
        online[k] = inv.force_n
    np.testing.assert_allclose(online, f, rtol=1e-8)
    np.testing.assert_allclose(series.force_n, online, rtol=1e-9)
    np.testing.assert_allclose(end_series.kv1_strain, state.kv1_strain, rtol=1e-9)


def test_staircase_up_and_down_is_tracked_and_unloading_recovers() -> None:
    levels = [0.0, 0.5, 1.0, 2.0, 4.0, 5.0, 4.0, 2.0, 1.0, 0.5, 0.0, 2.0]
    hold_s, rate_hz = 60.0, 10.0
    t = np.arange(0.0, hold_s * len(levels), 1.0 / rate_hz)
    f = np.array(levels)[np.minimum((t // hold_s).astype(int), len(levels) - 1)][:, None]
    m = SensorModel(PAPER, SensorParams())
    measured, _ = m.simulate(f, t)
    corrected, end = m.track_series(measured.total_ohm, t)
    loaded = f[:, 0] > 0
    rel = np.abs(corrected.force_n[loaded, 0] / f[loaded, 0] - 1)
    assert rel.max() < 1e-3, rel.max()
    unloaded = ~loaded
    assert np.all(corrected.status[unloaded, 0] == ForceStatus.NO_CONTACT)
    assert np.all(corrected.force_n[unloaded, 0] == 0.0)
    # the last reload to 2 N after a 60 s unloaded rest reads right: the state recovered
    static = m.invert_static(measured.total_ohm)
    assert abs(corrected.force_n[-1, 0] - 2.0) < 2e-3
    assert abs(static.force_n[-1, 0] - 2.0) > abs(corrected.force_n[-1, 0] - 2.0)
    assert end.last_force_n[0] == pytest.approx(2.0, rel=1e-6)


def test_invalid_samples_hold_the_state_and_do_not_leak_nan() -> None:
    m = SensorModel(PAPER, [SensorParams()] * 2)
    t, f = _hold_series([2.0, 2.0], seconds=30.0)
    measured, _ = m.simulate(f, t)
    r = measured.total_ohm.copy()
    r[100:110, 0] = np.nan
    r[50, 1] = 0.0
    out, end = m.track_series(r, t)
    assert np.all(out.status[100:110, 0] == ForceStatus.INVALID)
    assert out.status[50, 1] == ForceStatus.INVALID
    good = out.status == ForceStatus.OK
    assert np.abs(out.force_n[good] - 2.0).max() < 2e-3
    assert np.isfinite(end.kv1_strain).all() and np.isfinite(end.last_force_n).all()


def test_series_with_every_effect_matches_the_online_loop() -> None:
    from gateway.model import EFFECT_NAMES

    m = SensorModel(EFFECT_NAMES, SensorParams())
    t = np.arange(0.0, 120.0, 0.2)
    f = (1.5 + np.sin(t / 5.0))[:, None]
    temp = (25.0 + 0.1 * t)[:, None]
    measured, _ = m.simulate(f, t, temperature_c=temp)
    series, _ = m.track_series(measured.total_ohm, t, temperature_c=temp)
    state = m.initial_state()
    for k in range(t.size):
        inv, state = m.track(measured.total_ohm[k], state, t[k] - t[k - 1] if k else 0.0, temp[k])
        assert inv.force_n[0] == pytest.approx(f[k, 0], rel=1e-7)
        assert series.force_n[k, 0] == pytest.approx(f[k, 0], rel=1e-7)


_SPECIAL_OHM = [np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-300, 1.0, 1e12, np.finfo(np.float64).max]


@settings(max_examples=200, deadline=None)
@given(
    picks=st.lists(
        st.one_of(
            st.floats(0.02, 11.0).map(lambda f: ("force", f)),
            st.sampled_from(_SPECIAL_OHM).map(lambda r: ("ohm", r)),
        ),
        min_size=1,
        max_size=12,
    ),
    creep_fraction=st.floats(0.0, 1.0),
    guess_n=st.one_of(st.none(), st.floats(0.0, 20.0), st.sampled_from([np.nan, np.inf, -1.0])),
    effects=st.sampled_from([PAPER, "tunneling", "tunneling,contact,creep,series_resistance,leakage"]),
)
def test_the_polling_path_and_the_bulk_path_of_the_inversion_agree(
    picks: list[tuple[str, float]], creep_fraction: float, guess_n: float | None, effects: str
) -> None:
    """One sample per channel (the poll loop's lean path) and the same sample as a (1, N)
    series (the broadcasting path) give the same statuses and forces, for resistances
    inside the range, at and beyond its ends, and invalid ones, from any start guess."""
    n = len(picks)
    params = SensorParams(force_min_n=0.05, force_max_n=10.0, series_resistance_ohm=500.0,
                          leakage_resistance_ohm=5e6)  # fmt: skip
    m = SensorModel(effects, [params] * n)
    kv = creep_fraction * 1e-3
    state = ModelState(np.full(n, kv), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n))
    forces = np.array([v if kind == "force" else 1.0 for kind, v in picks])
    r = m.resistance(forces, state)
    r = np.array([r[i] if kind == "force" else v for i, (kind, v) in enumerate(picks)])
    guess = None if guess_n is None else np.full(n, guess_n)
    lean = m.invert(r, state, guess_n=guess)
    bulk = m.invert(r[None, :], state, guess_n=None if guess is None else guess[None, :])
    np.testing.assert_array_equal(lean.status, bulk.status[0])
    np.testing.assert_allclose(lean.force_n, bulk.force_n[0], rtol=1e-9, equal_nan=True)
    ok = lean.status == ForceStatus.OK
    np.testing.assert_allclose(lean.force_n[ok], forces[ok], rtol=1e-6)
    assert np.isnan(lean.force_n[lean.status == ForceStatus.INVALID]).all()
    assert np.isfinite(lean.force_n[lean.status != ForceStatus.INVALID]).all()


def test_a_static_inversion_reads_alike_on_every_call_and_after_a_warm_one() -> None:
    """The inverter keeps the force range's end resistances of a static inversion (no state,
    no temperature): later calls, and calls after a warm or tracked one, read what a fresh
    model reads."""
    from gateway.model import SensorModel, SensorParams

    def fresh() -> SensorModel:
        return SensorModel("tunneling,contact,creep,temperature", [SensorParams()] * 3)

    r = fresh().resistance(np.array([0.2, 3.0, 9.0]))
    r_out = np.array([r[0], 1e12, 1e-3])  # in range, no contact (0 N), saturated (force_max)
    model = fresh()
    first = model.invert_static(r_out)
    model.invert_static(r_out, temperature_c=np.array([60.0, 60.0, 60.0]))
    model.invert(r_out, model.settled_state(np.array([1.0, 1.0, 1.0])))
    again = model.invert_static(r_out)
    want = fresh().invert_static(r_out)
    for got in (first, again):
        np.testing.assert_array_equal(got.force_n, want.force_n)
        np.testing.assert_array_equal(got.status, want.status)
    assert want.force_n[1] == 0.0 and want.force_n[2] == 10.0
    np.testing.assert_allclose(want.force_n[0], 0.2, rtol=1e-8)
