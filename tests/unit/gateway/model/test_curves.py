"""Static curves with drift correction on top (gateway.model.curves), checked by hand.

Every expected value below is computed from the module docstring's equations, by hand or
with a few lines of arithmetic written out in the test, never by the code under test.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.model import ForceStatus
from gateway.model.curves import (
    CurveChannel,
    CurveError,
    CurveSet,
    CurveState,
    Drift,
    LineCurve,
    LookupCurve,
    PowerLawCurve,
    StaticCurve,
    curve_from_table,
    track_series,
)

OK, NO_CONTACT, INVALID = int(ForceStatus.OK), int(ForceStatus.NO_CONTACT), int(ForceStatus.INVALID)
LOOKUP = LookupCurve((1e3, 1e4, 1e5), (8.0, 2.0, 0.5))


def run(
    cset: CurveSet, resistance_ohm: Sequence[Sequence[float]], time_s: Sequence[float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[CurveState]]:
    """``CurveSet.track`` sample by sample (dt = time since the previous sample, 0 first) from
    a sensor at rest: forces, statuses, static forces, extrapolated flags (samples x channels)
    and the states."""
    state = cset.rested_state()
    out: list[tuple[np.ndarray, ...]] = []
    states = []
    for k, r in enumerate(resistance_ohm):
        dt = time_s[k] - time_s[k - 1] if k else 0.0
        f, s, x, e, state = cset.track(np.asarray(r, dtype=np.float64), state, dt)
        out.append((f, s, x, e))
        states.append(state)
    f, s, x, e = (np.array([o[i] for o in out]) for i in range(4))
    return f, s, x, e, states


def one(channel: CurveChannel, resistance_ohm: Sequence[float], time_s: Sequence[float]) -> np.ndarray:
    """One channel's tracked force over a series through ``CurveSet.track``."""
    return run(CurveSet([channel]), [[r] for r in resistance_ohm], time_s)[0][:, 0]


# ---------------------------------------------------------------- static curves by hand


@pytest.mark.parametrize(
    ("k", "n", "r", "expected"),
    [
        (1e-4, 1.0, 5000.0, 2.0),  # G = 2e-4 S -> F = G / k = 2 N
        (1e-4, 0.5, 5000.0, 4.0),  # F = (G / k)^2 = 4 N
        (1e-4, 2.0, 2500.0, 2.0),  # G = 4e-4 S -> F = 4^(1/2) = 2 N
        (1e-4, 2.0, 1e4, 1.0),  # G = k: 1 N whatever n
        (2e-5, 0.8, 1.0 / (2e-5 * 10.0**0.8), 10.0),  # G = k 10^n -> 10 N
        (1e-4, 1.0, 1e8, 1e-4),  # a tiny conductance is a tiny force, not nothing
    ],
)
def test_power_law_reads_the_hand_force(k: float, n: float, r: float, expected: float) -> None:
    ch = CurveChannel(PowerLawCurve(k, n))
    assert float(ch.curve.force(r)) == pytest.approx(expected, rel=1e-12)
    assert float(ch.static_force(r)) == pytest.approx(expected, rel=1e-12)
    assert float(CurveSet([ch]).static_force(np.array([r]))[0]) == pytest.approx(expected, rel=1e-12)
    assert one(ch, [r], [0.0])[0] == pytest.approx(expected, rel=1e-12)


def test_line_reads_the_hand_force_and_below_its_intercept_no_contact() -> None:
    m, c = 2e-5, 1e-6  # G = m F + c
    ch = CurveChannel(LineCurve(m, c))
    r3 = 1.0 / (2e-5 * 3.0 + 1e-6)  # 16393.44 ohm at 3 N
    assert r3 == pytest.approx(16393.44, abs=0.01)
    r_neg = 1.0 / 0.5e-6  # G = c / 2 -> F = (0.5e-6 - 1e-6) / 2e-5 = -0.025 N
    r_zero = 1.0 / c  # G = c -> 0 N
    assert ch.static_force([r3, r_zero])[0] == pytest.approx(3.0, rel=1e-12)
    assert ch.static_force([r_neg])[0] == pytest.approx(-0.025, rel=1e-9)
    # the tracker reads a force at or below 0 N as 0 N, no contact
    f, s, x, _, _ = run(CurveSet([ch]), [[r3], [r_zero], [r_neg]], [0.0, 1.0, 2.0])
    np.testing.assert_allclose(f[:, 0], [3.0, 0.0, 0.0], rtol=1e-12, atol=1e-15)
    assert s[:, 0].tolist() == [OK, NO_CONTACT, NO_CONTACT]
    assert x[2, 0] == pytest.approx(-0.025, rel=1e-9)  # the static force is what the line reads


def test_lookup_between_knots_and_beyond_the_ends() -> None:
    # knots (1e3, 8 N), (1e4, 2 N), (1e5, 0.5 N): linear in ln R, per decade -6 N then -1.5 N
    cases = {
        1e3: 8.0,
        1e4: 2.0,
        1e5: 0.5,
        math.sqrt(1e3 * 1e4): 5.0,  # midway in ln R between 8 and 2
        1e4 * 10**0.25: 2.0 - 0.25 * 1.5,  # a quarter of the way from 2 to 0.5
        100.0: 14.0,  # one decade below the first knot, along the first segment: 8 + 6
        10**2.5: 11.0,  # half a decade below: 8 + 3
        1e6: -1.0,  # one decade beyond the last: 0.5 - 1.5
        1e5 * 10**0.5: -0.25,
    }
    r = np.array(list(cases))
    expected = np.array(list(cases.values()))
    np.testing.assert_allclose(LOOKUP.force(r), expected, rtol=1e-12, atol=1e-12)
    ch = CurveChannel(LOOKUP)
    np.testing.assert_allclose(ch.static_force(r), expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(CurveSet([ch] * r.size).static_force(r), expected, rtol=1e-12, atol=1e-12)
    f, s, _, _, _ = run(CurveSet([ch] * r.size), [r.tolist()], [0.0])
    np.testing.assert_allclose(f[0], np.maximum(expected, 0.0), rtol=1e-12, atol=1e-12)
    assert s[0].tolist() == [OK] * 7 + [NO_CONTACT] * 2


def test_a_lookup_with_a_flat_segment_and_of_other_lengths_in_one_set() -> None:
    flat = LookupCurve((100.0, 200.0, 400.0, 800.0), (5.0, 5.0, 1.0, 0.5))
    chans = [CurveChannel(flat), CurveChannel(LOOKUP), CurveChannel(flat)]
    # 150 ohm on the flat segment: 5 N; sqrt(1e4 * 1e5): 1.25 N; 400 * sqrt(2): midway 1 -> 0.5
    r = np.array([150.0, math.sqrt(1e4 * 1e5), 400.0 * math.sqrt(2.0)])
    np.testing.assert_allclose(CurveSet(chans).static_force(r), [5.0, 1.25, 0.75], rtol=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    k=st.floats(1e-7, 1e-2),
    n=st.floats(0.2, 3.0),
    force=st.floats(1e-3, 100.0),
)
def test_power_law_resistance_round_trips(k: float, n: float, force: float) -> None:
    curve = PowerLawCurve(k, n)
    r = float(curve.resistance(force))
    assert r == pytest.approx(1.0 / (k * force**n), rel=1e-12)
    assert float(curve.force(r)) == pytest.approx(force, rel=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    m=st.floats(1e-7, 1e-3),
    c_share=st.floats(-0.5, 0.5),
    force=st.floats(1e-3, 100.0),
)
def test_line_resistance_round_trips(m: float, c_share: float, force: float) -> None:
    c = c_share * m * force  # m F + c stays > 0
    curve = LineCurve(m, c)
    r = float(curve.resistance(force))
    assert r == pytest.approx(1.0 / (m * force + c), rel=1e-12)
    assert float(curve.force(r)) == pytest.approx(force, rel=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(0.05, 3.0), st.floats(0.05, 5.0)), min_size=1, max_size=8),
    r0=st.floats(10.0, 1e5),
    where=st.floats(0.0, 1.0),
)
def test_lookup_resistance_round_trips_inside_its_knots(
    steps: list[tuple[float, float]], r0: float, where: float
) -> None:
    # knots: ln R up by the first of each step, force down by the second (strictly)
    log_r = math.log(r0) + np.concatenate([[0.0], np.cumsum([a for a, _ in steps])])
    force = 20.0 - np.concatenate([[0.0], np.cumsum([b for _, b in steps])])
    curve = LookupCurve(tuple(np.exp(log_r).tolist()), tuple(force.tolist()))
    f = force[-1] + where * (force[0] - force[-1])
    r = float(curve.resistance(f))
    assert float(curve.force(r)) == pytest.approx(f, rel=1e-9, abs=1e-9)
    # and resistance(force(R)) at a resistance between the first and the last knot
    r_in = math.exp(log_r[0] + where * (log_r[-1] - log_r[0]))
    assert float(curve.resistance(curve.force(r_in))) == pytest.approx(r_in, rel=1e-9)


# ---------------------------------------------------------------- sensitivity


def test_gain_reads_the_conductance_scaled_and_offset_adds() -> None:
    # power law n = 1: G = 2e-4 S at 5 kohm -> 2 N; gain 2 reads 4e-4 S -> 4 N; offset adds
    r = 5000.0
    assert float(CurveChannel(PowerLawCurve(1e-4, 1.0), gain=2.0).static_force(r)) == pytest.approx(4.0)
    both = CurveChannel(PowerLawCurve(1e-4, 1.0), gain=2.0, offset_n=0.5, force_min_n=0.6)
    assert float(both.static_force(r)) == pytest.approx(4.5, rel=1e-12)
    # n = 0.5: gain 2 -> (4e-4 / 1e-4)^2 = 16 N
    sq = CurveChannel(PowerLawCurve(1e-4, 0.5), gain=2.0)
    assert float(sq.static_force(r)) == pytest.approx(16.0, rel=1e-12)
    # line: (2 G - c) / m = (4e-4 - 1e-6) / 2e-5 = 19.95 N, offset -0.95 -> 19 N
    line = CurveChannel(LineCurve(2e-5, 1e-6), gain=2.0, offset_n=-0.95)
    assert float(line.static_force(r)) == pytest.approx(19.0, rel=1e-12)
    # lookup: gain 10 reads R / 10, one decade lower: 1e5 ohm reads the 1e4 knot, 2 N, + 0.25
    lk = CurveChannel(LOOKUP, gain=10.0, offset_n=0.25)
    assert float(lk.static_force(1e5)) == pytest.approx(2.25, rel=1e-12)
    chans = [both, sq, line, lk]
    rs = np.array([r, r, r, 1e5])
    np.testing.assert_allclose(CurveSet(chans).static_force(rs), [4.5, 16.0, 19.0, 2.25], rtol=1e-12)
    f, s, _, _, _ = run(CurveSet(chans), [rs.tolist()], [0.0])
    np.testing.assert_allclose(f[0], [4.5, 16.0, 19.0, 2.25], rtol=1e-12)
    assert s[0].tolist() == [OK] * 4
    assert both.with_sensitivity(1.0, 0.0) == CurveChannel(PowerLawCurve(1e-4, 1.0), force_min_n=0.6)


# ---------------------------------------------------------------- statuses and the range


def test_open_invalid_no_contact_and_extrapolated() -> None:
    kinds: list[StaticCurve] = [PowerLawCurve(1e-4, 1.0), LineCurve(2e-5, -1e-6), LOOKUP]
    for curve in kinds:
        # an offset must not make an open sensor read a load
        ch = CurveChannel(curve, Drift(creep_fraction=0.1), offset_n=0.3, force_min_n=2.0)
        r = [math.inf, math.nan, 0.0, -5.0, -math.inf]
        f, s, x, e, _ = run(CurveSet([ch] * len(r)), [r], [0.0])
        assert s[0].tolist() == [NO_CONTACT] + [INVALID] * 4, curve
        assert f[0, 0] == 0.0 and x[0, 0] == 0.0
        assert np.isnan(f[0, 1:]).all() and np.isnan(x[0, 1:]).all()
        assert not e[0].any()
        assert ch.static_force([math.inf])[0] == 0.0
        assert np.isnan(ch.static_force([math.nan, 0.0, -5.0])).all()
        series, static = track_series(ch, r, [0.0, 1.0, 2.0, 3.0, 4.0], from_rest=True)
        assert series[0] == 0.0 and np.isnan(series[1:]).all() and static[0] == 0.0


def test_outside_the_calibrated_range_the_force_is_read_and_flagged() -> None:
    ch = CurveChannel(PowerLawCurve(1e-4, 1.0), force_min_n=0.5, force_max_n=3.0)
    # G / k: 0.2, 0.5, 2, 3, 4, 30 N
    rs = [1.0 / (1e-4 * f) for f in (0.2, 0.5, 2.0, 3.0, 4.0, 30.0)]
    f, s, _, e, _ = run(CurveSet([ch] * 6), [rs], [0.0])
    np.testing.assert_allclose(f[0], [0.2, 0.5, 2.0, 3.0, 4.0, 30.0], rtol=1e-12)  # not clipped
    assert e[0].tolist() == [True, False, False, False, True, True]
    assert not np.isin(s[0], [NO_CONTACT, INVALID]).any()


def test_invalid_samples_keep_the_held_force_and_the_dynamics_run_on() -> None:
    # creep a1 = 0.5, tau = 2 s: 4 N from t = 0; a NaN at t = 1 s; the element relaxes across it
    a1, tau, k = 0.5, 2.0, 1e-4
    ch = CurveChannel(PowerLawCurve(k, 1.0), Drift(creep_fraction=a1, creep_tau_s=tau))
    t = [0.0, 1.0, 3.0]
    x = [4.0 * (1.0 + a1 * (1.0 - math.exp(-ti / tau))) for ti in t]
    r = [1.0 / (k * x[0]), math.nan, 1.0 / (k * x[2])]
    f, s, _, _, states = run(CurveSet([ch]), [[v] for v in r], t)
    assert s[:, 0].tolist() == [OK, INVALID, OK]
    assert np.isnan(f[1, 0]) and states[1].last_force_n[0] == 4.0
    assert f[2, 0] == pytest.approx(4.0, rel=1e-12)
    np.testing.assert_allclose(track_series(ch, r, t, from_rest=True)[0], f[:, 0], rtol=1e-12)


# ---------------------------------------------------------------- creep by hand


@pytest.mark.parametrize("two", [False, True])
def test_a_held_step_under_creep_reads_the_applied_force(two: bool) -> None:
    """A sensor with Kelvin elements (a1, tau1) [and (a2, tau2)] under F held from t_L.

    Each element: z <- e z + (1 - e) a F_prev with e = exp(-dt / tau). Open before t_L (F = 0)
    it stays 0; at t_L, z is still 0 (F_prev = 0) and x = F; from there F_prev = F and the
    steps telescope: z(t_k) = a F (1 - prod e) = a F (1 - exp(-(t_k - t_L) / tau)) exactly,
    for any spacing of the samples. So the sensor reads x = F (1 + sum a (1 - exp(-t/tau))).
    """
    k, n, force = 1e-4, 0.8, 2.0
    a1, tau1 = 0.2, 5.0
    a2, tau2 = (0.1, 60.0) if two else (0.0, 300.0)
    drift = Drift(creep_fraction=a1, creep_tau_s=tau1, creep2_fraction=a2, creep2_tau_s=tau2)
    ch = CurveChannel(PowerLawCurve(k, n), drift)
    t = np.array([0.0, 0.7, 1.0, 1.5, 2.2, 2.3, 5.0, 10.0, 10.05, 20.0, 40.0, 100.0, 400.0])
    t_load = 1.0  # open before
    since = t - t_load
    x = force * (1.0 + a1 * (1.0 - np.exp(-since / tau1)) + a2 * (1.0 - np.exp(-since / tau2)))
    r = np.where(since < 0, np.inf, 1.0 / (k * x**n))
    f_set, status, static, _, states = run(CurveSet([ch]), r[:, None].tolist(), t.tolist())
    f_series, x_series = track_series(ch, r, t, from_rest=True)
    loaded = since >= 0
    expected = np.where(loaded, force, 0.0)
    np.testing.assert_allclose(f_set[:, 0], expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f_series, expected, rtol=1e-12, atol=1e-12)
    assert status[:, 0].tolist() == [NO_CONTACT] * 2 + [OK] * 11
    # the static reading drifts up to F (1 + a1 + a2); here the hand values at a few times
    np.testing.assert_allclose(static[loaded, 0], x[loaded], rtol=1e-12)
    np.testing.assert_allclose(x_series[loaded], x[loaded], rtol=1e-12)
    assert static[2, 0] == pytest.approx(2.0, rel=1e-12)  # at t_L: no creep yet
    # 4 s after t_L: 2 (1 + 0.2 (1 - e^-0.8)) = 2 (1 + 0.2 x 0.550671) = 2.220268 N (one element)
    one_element = 2.0 * (1.0 + 0.2 * (1.0 - math.exp(-0.8)))
    assert one_element == pytest.approx(2.220268, abs=1e-6)
    if not two:
        assert static[6, 0] == pytest.approx(one_element, rel=1e-12)
    assert static[-1, 0] == pytest.approx(force * (1.0 + a1 + a2), rel=1e-3 if two else 1e-12)
    # the state: z1 = a1 F (1 - e^(-99/5)) at t = 100 s
    assert states[11].z1[0] == pytest.approx(0.4 * (1.0 - math.exp(-99.0 / 5.0)), rel=1e-12)


def test_recovery_after_unloading_decays_with_tau() -> None:
    """4 N from t = 0 to t = 8 s (samples every second), unloaded from t = 9 s.

    The interval ending at t = 9 s still holds 4 N: z(9) = a F (1 - e^(-9/tau)); from there
    F_prev = 0 and z(t) = z(9) e^(-(t - 9)/tau). a = 0.25, tau = 4 s:
    z(9) = 1 - e^-2.25 = 0.894601, z(13) = z(9) / e = 0.329106, z(21) = z(9) e^-3 = 0.044540.
    The sensor unloaded reads x = z (the recovery); the tracker reads 0 N.
    """
    a, tau, k = 0.25, 4.0, 1e-4
    ch = CurveChannel(PowerLawCurve(k, 1.0), Drift(creep_fraction=a, creep_tau_s=tau))
    t = np.arange(0.0, 22.0)
    z = np.where(
        t <= 8,
        a * 4.0 * (1.0 - np.exp(-t / tau)),
        a * 4.0 * (1.0 - math.exp(-9.0 / tau)) * np.exp(-(t - 9.0) / tau),
    )
    applied = np.where(t <= 8, 4.0, 0.0)
    r = 1.0 / (k * (applied + z))
    f, _, static, _, states = run(CurveSet([ch]), r[:, None].tolist(), t.tolist())
    np.testing.assert_allclose(f[:, 0], applied, atol=1e-12)
    np.testing.assert_allclose(track_series(ch, r, t, from_rest=True)[0], applied, atol=1e-12)
    z1 = np.array([s.z1[0] for s in states])
    assert z1[9] == pytest.approx(0.894601, abs=1e-6)
    assert z1[13] == pytest.approx(0.329106, abs=1e-6)
    assert z1[21] == pytest.approx(0.044540, abs=1e-6)
    assert static[13, 0] == pytest.approx(0.329106, abs=1e-6)  # what a static curve reads: 0.33 N
    # a low load after the high one: 1 N from t = 9 s reads high at first on the static curve
    low = np.where(t <= 8, 4.0, 1.0)
    z_low = np.where(
        t <= 8,
        a * 4.0 * (1.0 - np.exp(-t / tau)),
        a * 1.0 + (a * 4.0 * (1.0 - math.exp(-9.0 / tau)) - a) * np.exp(-(t - 9.0) / tau),
    )
    r_low = 1.0 / (k * (low + z_low))
    f_low, _, static_low, _, _ = run(CurveSet([ch]), r_low[:, None].tolist(), t.tolist())
    np.testing.assert_allclose(f_low[:, 0], low, rtol=1e-12)
    # at t = 9: 1 + 0.894601 = 1.8946 N on the static curve (+89 %), the tracker 1 N
    assert static_low[9, 0] == pytest.approx(1.894601, abs=1e-6)


# ---------------------------------------------------------------- the vectorised tracker


def _channel(kind: int, p: tuple[float, float], drift: Drift, gain: float, offset: float) -> CurveChannel:
    curve: StaticCurve
    if kind == 0:
        curve = PowerLawCurve(10.0 ** (-3.0 - 2.0 * p[0]), 0.3 + 2.0 * p[1])
    elif kind == 1:
        curve = LineCurve(10.0 ** (-5.0 - p[0]), (p[1] - 0.5) * 1e-5)
    else:
        step = 1.0 + 4.0 * p[1]
        curve = LookupCurve((300.0, 3e3, 3e4, 3e5), (10.0 * step, 3.0 * step, step, 0.2 * step - 0.5 * p[0]))
    # a curve that reads a force at zero conductance starts above it (``with_range``)
    wide = CurveChannel(curve, drift, gain=gain, offset_n=offset, force_min_n=1e6, force_max_n=2e6)
    return wide.with_range(0.5, 8.0)


drifts = st.builds(
    Drift,
    creep_fraction=st.floats(-0.5, 1.0),
    creep_tau_s=st.floats(0.05, 100.0),
    creep2_fraction=st.floats(-0.5, 1.0),
    creep2_tau_s=st.floats(1.0, 1000.0),
    hysteresis_fraction=st.floats(-0.5, 0.5),
    hysteresis_width_n=st.floats(0.01, 5.0),
)
channels = st.builds(
    _channel,
    kind=st.integers(0, 2),
    p=st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0)),
    drift=drifts,
    gain=st.floats(0.5, 2.0),
    offset=st.floats(-0.5, 0.5),
)
resistances = st.one_of(
    st.floats(2.0, 6.5).map(lambda e: 10.0**e),
    st.sampled_from([math.inf, math.nan, 0.0, -100.0]),
)
series = st.lists(st.tuples(st.floats(0.0, 5.0), resistances), min_size=1, max_size=40)


@settings(max_examples=200, deadline=None)
@given(channel=channels, samples=series, t0=st.floats(-10.0, 10.0), from_rest=st.booleans())
def test_track_sample_by_sample_equals_track_series(
    channel: CurveChannel, samples: list[tuple[float, float]], t0: float, from_rest: bool
) -> None:
    """The vectorised tracker and the series tracker read the same forces, from rest and from
    the equilibrium at the first load alike."""
    t = (t0 + np.cumsum([dt for dt, _ in samples])).tolist()
    r = [v for _, v in samples]
    cset = CurveSet([channel])
    state = cset.rested_state() if from_rest else cset.initial_state()
    f, x = np.full(len(r), np.nan), np.full(len(r), np.nan)
    for k, v in enumerate(r):
        dt = t[k] - t[k - 1] if k else 0.0
        fk, _, xk, _, state = cset.track(np.array([v]), state, dt)
        f[k], x[k] = fk[0], xk[0]
    f_series, x_series = track_series(channel, r, t, from_rest=from_rest)
    np.testing.assert_allclose(f, f_series, rtol=1e-9, atol=1e-12, equal_nan=True)
    np.testing.assert_allclose(x, x_series, rtol=1e-9, atol=1e-12, equal_nan=True)


@settings(max_examples=150, deadline=None)
@given(
    chans=st.lists(channels, min_size=3, max_size=3),
    samples=st.lists(
        st.tuples(st.floats(0.0, 5.0), st.tuples(resistances, resistances, resistances)),
        min_size=1,
        max_size=25,
    ),
)
def test_each_channel_of_a_mixed_set_reads_as_alone(
    chans: list[CurveChannel], samples: list[tuple[float, tuple[float, float, float]]]
) -> None:
    t = np.cumsum([dt for dt, _ in samples]).tolist()
    r = [list(v) for _, v in samples]
    together = run(CurveSet(chans), r, t)
    for j, ch in enumerate(chans):
        alone = run(CurveSet([ch]), [[row[j]] for row in r], t)
        for got, want in zip(together[:4], alone[:4], strict=True):
            np.testing.assert_allclose(got[:, j], want[:, 0], rtol=1e-12, atol=1e-15, equal_nan=True)


def test_a_set_at_positions_and_a_static_set_carry_no_dynamics() -> None:
    chans = [CurveChannel(PowerLawCurve(1e-4, 1.0)), CurveChannel(LOOKUP)]
    cset = CurveSet(chans, positions=[3, 7])
    assert cset.positions.tolist() == [3, 7] and len(cset) == 2 and not cset.dynamic
    f, _, _, _, states = run(cset, [[5000.0, 1e4], [5000.0, 1e4]], [0.0, 100.0])
    np.testing.assert_allclose(f, [[2.0, 2.0], [2.0, 2.0]], rtol=1e-12)
    assert np.all(states[-1].z1 == 0.0)
    np.testing.assert_array_equal(states[-1].last_force_n, [2.0, 2.0])


# ---------------------------------------------------------------- calibration-file tables


def _table(text: str) -> dict[str, object]:
    return tomllib.loads(text)


def test_valid_tables_of_each_kind() -> None:
    assert curve_from_table(_table('kind = "power_law"\ncoefficient_s = 1e-4\nexponent = 0.8')) == (
        CurveChannel(PowerLawCurve(1e-4, 0.8))
    )
    line = curve_from_table(
        _table(
            'kind = "line"\nslope_s_per_n = 2e-5\nintercept_s = -1e-6\ngain = 1.5\noffset_n = -0.1\n'
            "creep_fraction = 0.1\ncreep_tau_s = 12.0\nhysteresis_fraction = -0.05\n"
            "hysteresis_width_n = 0.3\nforce_min_n = 0.2\nforce_max_n = 9.5\nheld_out_force_rms_n = 0.04"
        )
    )
    assert line == CurveChannel(
        LineCurve(2e-5, -1e-6),
        Drift(creep_fraction=0.1, creep_tau_s=12.0, hysteresis_fraction=-0.05, hysteresis_width_n=0.3),
        gain=1.5,
        offset_n=-0.1,
        force_min_n=0.2,
        force_max_n=9.5,
    )
    assert line.drift.form == "creep+hysteresis" and line.describe() == "line + creep+hysteresis"
    lookup = curve_from_table(
        _table(
            'kind = "lookup"\nresistance_ohm = [1000, 1e4, 1e5]\nforce_n = [8, 2, 0.5]\n'
            "creep2_fraction = 0.05\ncreep2_tau_s = 600\nforce_max_n = inf"
        )
    )
    assert lookup.curve == LOOKUP and lookup.force_max_n == math.inf
    assert lookup.drift == Drift(creep2_fraction=0.05, creep2_tau_s=600.0)
    assert lookup.drift.form == "creep2"
    assert float(lookup.static_force(math.sqrt(1e3 * 1e4))) == pytest.approx(5.0)
    # what a table holds, written back, reads the same channel
    for ch in (line, lookup):
        again = {"kind": ch.curve.kind, **ch.curve.table(), **ch.drift.table(), "gain": ch.gain}
        again |= {"offset_n": ch.offset_n, "force_min_n": ch.force_min_n, "force_max_n": ch.force_max_n}
        assert curve_from_table(again) == ch


BASE_POWER = 'kind = "power_law"\ncoefficient_s = 1e-4\nexponent = 0.8\n'


@pytest.mark.parametrize(
    ("text", "key", "allowed"),
    [
        (BASE_POWER + "exponnent = 1\n", "exponnent", "allowed: kind, gain, offset_n"),
        ('kind = "power_law"\ncoefficient_s = 1e-4\n', "exponent", "required key is missing"),
        ('kind = "line"\nslope_s_per_n = 1e-5\n', "intercept_s", "line tables need slope_s_per_n and"),
        ('kind = "spline"\n', "kind", "allowed: power_law, line, lookup"),
        ("coefficient_s = 1e-4\nexponent = 1\n", "kind", "allowed: power_law, line, lookup"),
        (BASE_POWER.replace("0.8", "-0.8"), "exponent", "allowed: (0, 10]"),
        (BASE_POWER.replace("0.8", "0"), "exponent", "allowed: (0, 10]"),
        (BASE_POWER.replace("0.8", "12"), "exponent", "allowed: (0, 10]"),
        (BASE_POWER.replace("0.8", "nan"), "exponent", "finite"),
        (BASE_POWER.replace("0.8", "true"), "exponent", "finite"),
        (BASE_POWER.replace("1e-4", "0"), "coefficient_s", "allowed: (0, inf) S/N^n"),
        (BASE_POWER.replace("1e-4", '"1e-4"'), "coefficient_s", "finite"),
        ('kind = "line"\nslope_s_per_n = -1e-5\nintercept_s = 0\n', "slope_s_per_n", "(0, inf) S/N"),
        ('kind = "line"\nslope_s_per_n = 1e-5\nintercept_s = inf\n', "intercept_s", "finite"),
        (
            'kind = "lookup"\nresistance_ohm = [1e3, 1e3]\nforce_n = [2, 1]\n',
            "resistance_ohm[1]",
            "strictly increasing",
        ),
        (
            'kind = "lookup"\nresistance_ohm = [1e4, 1e3]\nforce_n = [2, 1]\n',
            "resistance_ohm[1]",
            "strictly increasing",
        ),
        (
            'kind = "lookup"\nresistance_ohm = [1e3, 1e4, 1e5]\nforce_n = [2, 1, 1.5]\n',
            "force_n[2]",
            "must not increase",
        ),
        ('kind = "lookup"\nresistance_ohm = [1e3, 1e4]\nforce_n = [2, 2]\n', "force_n", "force range"),
        ('kind = "lookup"\nresistance_ohm = [1e3]\nforce_n = [2]\n', "resistance_ohm", "at least 2"),
        ('kind = "lookup"\nresistance_ohm = [1e3, 1e4]\nforce_n = [2, 1, 0]\n', "force_n", "3 forces for 2"),
        ('kind = "lookup"\nresistance_ohm = 5\nforce_n = [2, 1]\n', "resistance_ohm", "an array of numbers"),
        (
            'kind = "lookup"\nresistance_ohm = [0, 1e3]\nforce_n = [2, 1]\n',
            "resistance_ohm[0]",
            "(0, inf) ohm",
        ),
        ('kind = "lookup"\nresistance_ohm = [1e3, 1e4]\nforce_n = [2, nan]\n', "force_n[1]", "finite"),
        (BASE_POWER + "creep_fraction = 6\n", "creep_fraction", "allowed: [-0.9, 5.0]"),
        (BASE_POWER + "creep_fraction = -0.95\n", "creep_fraction", "allowed: [-0.9, 5.0]"),
        (BASE_POWER + "creep2_fraction = 5.5\n", "creep2_fraction", "allowed: [-0.9, 5.0]"),
        (BASE_POWER + "hysteresis_fraction = 0.95\n", "hysteresis_fraction", "allowed: [-0.9, 0.9]"),
        (BASE_POWER + "creep_tau_s = 0\n", "creep_tau_s", "allowed: (0, inf) s"),
        (BASE_POWER + "creep2_tau_s = -300\n", "creep2_tau_s", "allowed: (0, inf) s"),
        (BASE_POWER + "hysteresis_width_n = 0\n", "hysteresis_width_n", "allowed: (0, inf) N"),
        (BASE_POWER + "gain = 0\n", "gain", "allowed: (0, inf)"),
        (BASE_POWER + "offset_n = nan\n", "offset_n", "finite"),
        (BASE_POWER + "force_min_n = -1\n", "force_min_n", "allowed: [0, inf) N"),
        (BASE_POWER + "force_min_n = 2\nforce_max_n = 2\n", "force_max_n", "(force_min_n = 2.0, inf] N"),
    ],
)
def test_bad_tables_name_the_key_and_the_allowed_range(text: str, key: str, allowed: str) -> None:
    with pytest.raises(CurveError) as info:
        curve_from_table(_table(text))
    assert info.value.key == key, str(info.value)
    assert str(info.value).startswith(f"{key}: ")
    assert allowed in str(info.value), str(info.value)


# ---------------------------------------------------------------- hysteresis by hand


def test_hysteresis_loading_reads_low_unloading_high_by_hand() -> None:
    """beta = 0.1, w = 1 N: plays of widths 0.25, 0.5, 1, 2 N on the reading x, from 0;
    s = mean_j (p_j - x) / w_j and F = x / (1 + beta s) (no creep).

    x = 5, 10 (loading, steps wider than every play): s = -1, F = x / 0.9: the sensor reads
    (1 - beta) F. x = 9.5: plays (9.75, 9.5, 9, 8), s = (1 + 0 - 0.5 - 0.75) / 4 = -0.0625.
    x = 9: plays (9.25, 9.5, 9, 8), s = (1 + 1 + 0 - 0.5) / 4 = 0.375. x = 6, 2 (unloading):
    s = +1, F = x / 1.1: the sensor reads (1 + beta) F. x = 2.5: plays (2.25, 2.5, 3, 4),
    s = (-1 + 0 + 0.5 + 0.75) / 4 = 0.0625.
    """
    k = 1e-4
    ch = CurveChannel(PowerLawCurve(k, 1.0), Drift(hysteresis_fraction=0.1, hysteresis_width_n=1.0))
    x = [5.0, 10.0, 9.5, 9.0, 6.0, 2.0, 2.5]
    s = [-1.0, -1.0, -0.0625, 0.375, 1.0, 1.0, 0.0625]
    expected = [xi / (1.0 + 0.1 * si) for xi, si in zip(x, s, strict=True)]
    assert expected[:2] == pytest.approx([5.0 / 0.9, 10.0 / 0.9])
    assert expected[4:6] == pytest.approx([6.0 / 1.1, 2.0 / 1.1])
    r = [1.0 / (k * xi) for xi in x]
    t = [float(i) for i in range(len(x))]
    f, status, static, _, states = run(CurveSet([ch]), [[v] for v in r], t)
    np.testing.assert_allclose(f[:, 0], expected, rtol=1e-12)
    np.testing.assert_allclose(static[:, 0], x, rtol=1e-12)
    assert status[:, 0].tolist() == [OK] * 7
    np.testing.assert_allclose(states[2].play_n[0], [9.75, 9.5, 9.0, 8.0], rtol=1e-12)
    np.testing.assert_allclose(states[6].play_n[0], [2.25, 2.5, 3.0, 4.0], rtol=1e-12)
    np.testing.assert_allclose(track_series(ch, r, t, from_rest=True)[0], expected, rtol=1e-12)
    # rate-independent: the same readings at other times read the same forces
    np.testing.assert_allclose(one(ch, r, [0.0, 0.01, 5.0, 5.5, 100.0, 100.1, 1e4]), expected, rtol=1e-12)
    # an invalid sample leaves the plays where they were
    f2, _, _, _, _ = run(CurveSet([ch]), [[v] for v in [*r[:2], math.nan, r[2]]], [0.0, 1.0, 2.0, 3.0])
    assert math.isnan(f2[2, 0]) and f2[3, 0] == pytest.approx(expected[2], rel=1e-12)


def test_creep_and_hysteresis_together_by_hand() -> None:
    """a1 = 0.2, tau = 5 s, beta = 0.1, w = 0.5 N: 4 N from t = 0, held for 10 s. The sensor
    reads x = F (1 + beta s) + z with s = -1 (loaded from 0 in one step wider than 2 w) and
    z = a1 F (1 - e^(-t/tau)): x(10 s) = 3.6 + 0.8 (1 - e^-2) = 4.291732 N; the tracker: 4 N."""
    k = 1e-4
    drift = Drift(creep_fraction=0.2, creep_tau_s=5.0, hysteresis_fraction=0.1, hysteresis_width_n=0.5)
    ch = CurveChannel(PowerLawCurve(k, 1.0), drift)
    t = np.array([0.0, 1.0, 2.5, 10.0])
    x = 4.0 * 0.9 + 0.8 * (1.0 - np.exp(-t / 5.0))
    assert x[-1] == pytest.approx(4.291732, abs=1e-6)
    f, _, _, _, _ = run(CurveSet([ch]), [[1.0 / (k * v)] for v in x], t.tolist())
    np.testing.assert_allclose(f[:, 0], 4.0, rtol=1e-12)
    np.testing.assert_allclose(track_series(ch, 1.0 / (k * x), t, from_rest=True)[0], 4.0, rtol=1e-12)
