"""Curve candidates (gateway.analysis.candidates) and hold detection (gateway.analysis.holds):
regressors in closed form, fits that recover what a record was made with, the ranking on a
synthetic record built by hand, and holds of hand-made series."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.analysis.candidates import fit_curve, rank_candidates
from gateway.analysis.fitting import FitData
from gateway.analysis.holds import (
    MIN_HOLD_S,
    Hold,
    drift_groups_pct,
    find_holds,
    hold_drifts,
    hold_tolerance_n,
)
from gateway.model.curves import DRIFT_FORMS, LineCurve, LookupCurve, PowerLawCurve
from gateway.model.drift import kelvin_unit_series, play_direction_series


def kelvin_response(held: np.ndarray, dt: np.ndarray, tau: float) -> np.ndarray:
    """A symmetric unit Kelvin element from rest (``drift.kelvin_unit_series``)."""
    return kelvin_unit_series(held, dt, tau, tau, 0.0)


def preisach_direction(x: np.ndarray, width: float) -> np.ndarray:
    """The plays' direction from plays at 0 N (``drift.play_direction_series``)."""
    return play_direction_series(x, width, 0.0)


# ---------------------------------------------------------------- Kelvin regressor


def _loop(held: np.ndarray, dt: np.ndarray, tau: float) -> np.ndarray:
    """z_k = e_k z_{k-1} + (1 - e_k) held_k, e_k = exp(-dt_k / tau), from z = 0: plain Python."""
    out, z = [], 0.0
    for h, d in zip(held.tolist(), dt.tolist(), strict=True):
        e = math.exp(-d / tau)
        z = e * z + (1.0 - e) * h
        out.append(z)
    return np.array(out)


def test_kelvin_step_uniform_steps_is_the_closed_form() -> None:
    # held F from the first interval on: z_k = F (1 - exp(-(k + 1) h / tau))
    force, h, tau = 3.0, 0.25, 2.0
    k = np.arange(200)
    z = kelvin_response(np.full(200, force), np.full(200, h), tau)
    np.testing.assert_allclose(z, force * (1.0 - np.exp(-(k + 1) * h / tau)), rtol=1e-12, atol=1e-14)
    # one time constant in (k + 1 = 8): F (1 - 1/e) = 1.896362 N
    assert z[7] == pytest.approx(1.896362, abs=1e-6)


def test_kelvin_step_jittered_steps_and_a_step_in_the_held_force() -> None:
    rng = np.random.default_rng(11)
    dt = rng.uniform(0.0, 1.0, 300)
    dt[::7] = 0.0  # repeated times
    tau, force, m = 3.0, 2.0, 120
    held = np.where(np.arange(300) >= m, force, 0.0)
    z = kelvin_response(held, dt, tau)
    elapsed = np.cumsum(dt)
    # zero before row m; from there z_k = F (1 - exp(-(T_k - T_{m-1}) / tau))
    expected = np.where(np.arange(300) >= m, force * (1.0 - np.exp(-(elapsed - elapsed[m - 1]) / tau)), 0.0)
    np.testing.assert_allclose(z, expected, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(
        kelvin_response(np.full(300, force), dt, tau), force * (1.0 - np.exp(-elapsed / tau)), rtol=1e-12
    )


def test_kelvin_response_equals_the_loop_over_many_time_constants_and_huge_gaps() -> None:
    rng = np.random.default_rng(5)
    n, tau = 6000, 1.5
    dt = rng.exponential(0.5 * tau, n)  # about 2000 tau in all: several of the 600-tau chunks
    dt[[0, 17, 1800, 1801, 4000, n - 1]] = 1000.0 * tau  # gaps of 1000 tau, one first, two in a row
    dt[rng.integers(0, n, 50)] = 0.0
    held = rng.uniform(0.0, 10.0, n)
    held[rng.integers(0, n, 300)] = 0.0
    z = kelvin_response(held, dt, tau)
    assert np.isfinite(z).all()
    np.testing.assert_allclose(z, _loop(held, dt, tau), rtol=1e-9, atol=1e-9)
    # after a gap of 1000 tau the element has forgotten everything but the interval's force
    assert z[1801] == pytest.approx(held[1801], rel=1e-12)


@settings(max_examples=100, deadline=None)
@given(
    samples=st.lists(st.tuples(st.floats(0.0, 50.0), st.floats(0.0, 20.0)), min_size=1, max_size=60),
    tau=st.floats(0.01, 100.0),
)
def test_kelvin_response_equals_the_loop(samples: list[tuple[float, float]], tau: float) -> None:
    dt = np.array([d for d, _ in samples])
    held = np.array([h for _, h in samples])
    z = kelvin_response(held, dt, tau)
    np.testing.assert_allclose(z, _loop(held, dt, tau), rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------- hysteresis regressor


def test_preisach_direction_on_a_hand_made_series() -> None:
    """Plays of widths 0.25, 0.5, 1 and 2 (w = 1) on the reading x, from p = 0:
    p_j <- clip(p_j, x - w_j, x + w_j), s = mean_j (p_j - x) / w_j.

    x = 5, 10: every play drags at x - w_j: s = -1 (loading).
    x = 9.5: plays (9.75, 9.5, 9, 8) -> s_j = (+1, 0, -0.5, -0.75): s = -0.0625.
    x = 9: plays (9.25, 9.5, 9, 8) -> (+1, +1, 0, -0.5): s = 0.375.
    x = 6, 2: every play at x + w_j: s = +1 (unloading).
    x = 2.5: plays (2.25, 2.5, 3, 4) -> (-1, 0, 0.5, 0.75): s = 0.0625.
    NaN leaves the plays; x = 2.5 again reads the same s.
    """
    x = np.array([5.0, 10.0, 9.5, 9.0, 6.0, 2.0, 2.5, math.nan, 2.5])
    s = preisach_direction(x, 1.0)
    expected = [-1.0, -1.0, -0.0625, 0.375, 1.0, 1.0, 0.0625]
    np.testing.assert_allclose(s[:7], expected, rtol=0, atol=1e-15)
    assert s[8] == pytest.approx(0.0625, abs=1e-15)
    # the width scales: the same series in mN with w = 1000 mN reads the same s
    np.testing.assert_allclose(preisach_direction(1000.0 * x, 1000.0)[:7], expected, atol=1e-12)


# ---------------------------------------------------------------- static curve fits


def test_fit_curve_recovers_a_power_law_and_a_line() -> None:
    f = np.linspace(0.1, 10.0, 60)
    curve = fit_curve("power_law", f, 1.0 / (2e-4 * f**0.7))
    assert isinstance(curve, PowerLawCurve)
    assert curve.coefficient_s == pytest.approx(2e-4, rel=1e-6)
    assert curve.exponent == pytest.approx(0.7, rel=1e-6)
    line = fit_curve("line", f, 1.0 / (3e-5 * f + 2e-6))
    assert isinstance(line, LineCurve)
    assert line.slope_s_per_n == pytest.approx(3e-5, rel=1e-9)
    assert line.intercept_s == pytest.approx(2e-6, rel=1e-6)


def test_fit_curve_lookup_reads_its_training_points() -> None:
    f = np.linspace(0.1, 10.0, 60)
    r = 1.0 / (2e-4 * f**0.7)
    lk = fit_curve("lookup", f, r)
    assert isinstance(lk, LookupCurve)
    assert all(b > a for a, b in zip(lk.resistance_ohm, lk.resistance_ohm[1:], strict=False))
    assert all(b <= a for a, b in zip(lk.force_n, lk.force_n[1:], strict=False))
    # within 1 % of full scale everywhere (linear in ln R between knots at the medians of two
    # or three rows, where F = (G / k)^(1/n) bends most at the light end: about 0.06 N there),
    # and within 0.2 % of full scale from 1 N up, where it bends less
    err = lk.force(r) - f
    assert np.max(np.abs(err)) < 0.01 * 10.0
    assert np.max(np.abs(err[f >= 1.0])) < 0.002 * 10.0


def test_fit_curve_refuses_what_it_cannot_fit() -> None:
    f = np.linspace(0.1, 10.0, 20)
    with pytest.raises(ValueError, match="at least four rows"):
        fit_curve("power_law", f[:3], 1.0 / f[:3])
    with pytest.raises(ValueError, match="at least four rows"):
        fit_curve("line", np.full(10, 2.0), np.full(10, 1e4))  # one force only
    with pytest.raises(ValueError, match="does not rise with force"):
        fit_curve("power_law", f, 1e3 * f)  # conductance falling with force
    with pytest.raises(ValueError, match="does not rise with force"):
        fit_curve("line", f, 1e3 * f)
    with pytest.raises(ValueError, match="unknown curve kind 'spline'"):
        fit_curve("spline", f, 1.0 / f)


# ---------------------------------------------------------------- ranking a synthetic record

K_TRUE, N_TRUE, A_TRUE, TAU_TRUE = 1e-4, 0.8, 0.15, 10.0
LEVELS = [0.5, 2.0, 1.0, 4.0, 3.0, 1.5, 5.0, 2.5, 0.8, 3.5, 4.5, 1.2]
HOLD_S, REST_S, DT_S = 30.0, 10.0, 0.2


def creep_record(noise: float = 0.002) -> FitData:
    """A power-law sensor (k = 1e-4 S/N^0.8) with one Kelvin element (a = 0.15, tau = 10 s):
    10 s unloaded, then a hold of 30 s at each level above, sampled every 0.2 s.
    The sensor reads x = F + z, z <- e z + (1 - e) a F_prev (the curves' convention), and
    R = 1 / (k x^n) times a log-normal noise of 0.2 %; every third cycle is held out."""
    t = np.arange(0.0, len(LEVELS) * (HOLD_S + REST_S), DT_S)
    cycle = (t // (HOLD_S + REST_S)).astype(int)
    # every cycle rests first: the record starts unloaded, its load history known
    in_hold = (t - cycle * (HOLD_S + REST_S)) >= REST_S - 1e-9
    force = np.where(in_hold, np.array(LEVELS)[cycle], 0.0)
    x = np.empty_like(force)
    z = 0.0
    for k in range(t.size):
        e = math.exp(-(t[k] - t[k - 1]) / TAU_TRUE) if k else 1.0
        z = e * z + (1.0 - e) * A_TRUE * (force[k - 1] if k else 0.0)
        x[k] = force[k] + z
    with np.errstate(divide="ignore"):
        r = 1.0 / (K_TRUE * x**N_TRUE)
    r = r * np.exp(noise * np.random.default_rng(1).standard_normal(t.size))
    usable = np.isfinite(r) & (force > 0)
    return FitData(t, r, force, None, usable, cycle % 3 == 1)


def static_hold_drift_pct() -> float:
    """The hold drift (% FS) the sensor's own static curve shows, by hand. The element sees
    each level L for exactly 30 s from the hold's first sample (the force held over each
    interval is the previous sample's), then 0 N for 10 s: within a hold, at t from its first
    sample, z = a L + (z0 - a L) e^(-t/tau); z0 of the next hold = z(30 s) e^(-1). The static
    reading's error is z; ``hold_drift_pct`` takes its mean over the last 15 rows minus the
    first 15 of each held-out hold, RMS over those holds, of the 5 N full scale."""
    t = np.arange(round(HOLD_S / DT_S)) * DT_S
    n = t.size // 10
    z0, changes = 0.0, []
    for c, level in enumerate(LEVELS):
        z = A_TRUE * level + (z0 - A_TRUE * level) * np.exp(-t / TAU_TRUE)
        if c % 3 == 1:
            changes.append(float(np.mean(z[-n:]) - np.mean(z[:n])))
        z_end = A_TRUE * level + (z0 - A_TRUE * level) * math.exp(-HOLD_S / TAU_TRUE)
        z0 = z_end * math.exp(-REST_S / TAU_TRUE)
    return 100.0 * math.sqrt(float(np.mean(np.square(changes)))) / max(LEVELS)


def test_rank_candidates_finds_the_creep_it_was_made_with() -> None:
    data = creep_record()
    ranked = rank_candidates(data)
    by_name = {c.name: c for c in ranked}
    assert len(by_name) == len(ranked)
    rms_sorted = [c.held_out_force_rms_n for c in ranked]
    assert rms_sorted == sorted(rms_sorted)
    for kind in ("power_law", "line"):
        for form in DRIFT_FORMS:
            assert f"{kind} + {form}" in by_name

    best = ranked[0]
    assert best.kind == "power_law"
    assert DRIFT_FORMS[best.drift_form][0] >= 1, best.name  # a power law with creep
    # its creep: the fraction and the time constant (refined off the grid) within 10 %
    assert best.channel.drift.creep_fraction == pytest.approx(A_TRUE, rel=0.10)
    assert best.channel.drift.creep_tau_s == pytest.approx(TAU_TRUE, rel=0.10)
    assert abs(best.channel.drift.hysteresis_fraction) < 0.05  # none was put in

    # the candidate of exactly the record's form recovers all of it
    creep = by_name["power_law + creep"]
    assert creep.channel.drift.creep_fraction == pytest.approx(A_TRUE, rel=0.02)
    assert creep.channel.drift.creep_tau_s == pytest.approx(TAU_TRUE, rel=0.02)
    assert isinstance(creep.channel.curve, PowerLawCurve)
    assert creep.channel.curve.coefficient_s == pytest.approx(K_TRUE, rel=0.02)
    assert creep.channel.curve.exponent == pytest.approx(N_TRUE, rel=0.01)
    # 0.2 % noise in R is about 0.25 % in force: a few mN at these loads
    assert creep.held_out_force_rms_n < 0.02

    static = by_name["power_law + static"]
    assert best.held_out_force_rms_n < 0.5 * static.held_out_force_rms_n
    assert creep.held_out_force_rms_n < 0.5 * static.held_out_force_rms_n
    assert best.drift.worst_pct_fs < 1.0 and creep.drift.worst_pct_fs < 1.0
    share = static_hold_drift_pct()
    assert share == pytest.approx(5.05, abs=0.01)  # the creep's share, by hand (above)
    assert static.drift.worst_pct_fs > 0.8 * share
    # every candidate read every row of the record, tracked
    assert all(c.force_n.shape == data.time_s.shape for c in ranked)


def test_without_real_time_no_time_driven_form_is_ranked() -> None:
    ranked = rank_candidates(creep_record(), real_time=False)
    assert ranked
    assert {c.drift_form for c in ranked} <= {"static", "hysteresis"}
    assert {c.channel.drift.creep_fraction for c in ranked} == {0.0}
    assert {c.channel.drift.creep2_fraction for c in ranked} == {0.0}


def test_rank_candidates_by_kind_and_form() -> None:
    ranked = rank_candidates(creep_record(), kinds=("line",), forms=("static", "creep"))
    assert sorted(c.name for c in ranked) == ["line + creep", "line + static"]


def test_hold_drift_by_hand() -> None:
    """Two holds: 2 N for 10 s with an error rising 0.05 N/s, then 1 N with a constant error.
    The first without its first and last 0.5 s (``EDGE_GUARD_S``): 91 rows, 9 per edge, mean
    error 0.05 x 0.9 = 0.045 N at the start and 0.05 x 9.1 = 0.455 N at the end: a change of
    0.41 N, of a 4 N full scale 10.25 %; the second, right after a higher load, changes 0."""
    t1 = np.round(np.arange(101) * 0.1, 10)
    t = np.concatenate([t1, 10.0 + np.arange(1, 21) * 0.5, 20.5 + t1])
    ref = np.concatenate([np.full(101, 2.0), np.zeros(20), np.full(101, 1.0)])
    force = ref + np.concatenate([0.05 * t1, np.zeros(20), np.full(101, 0.3)])
    rows = np.ones(t.size, dtype=bool)
    drifts = hold_drifts(t, ref, force, rows)
    assert [d.after_higher for d in drifts] == [False, True]
    assert drifts[0].change_n == pytest.approx(0.41, rel=1e-9)
    assert drifts[1].start_error_n == pytest.approx(0.3, rel=1e-12)
    assert drifts[1].change_n == pytest.approx(0.0)
    groups = drift_groups_pct(drifts, 4.0)
    assert groups.others_pct_fs == pytest.approx(100 * 0.41 / 4, rel=1e-9)
    assert groups.after_higher_pct_fs == pytest.approx(0.0, abs=1e-9)
    assert (groups.after_higher_holds, groups.other_holds) == (1, 1)
    # a hold measured on part of its rows: its longest run of them, if it lasts MIN_HOLD_S
    rows[:60] = False  # rows 60..100 (4 s); 6.5-9.5 s after the guard: 3 rows per edge, 2.8 s apart
    first = hold_drifts(t, ref, force, rows)[0]
    assert first.hold.start == 65 and first.change_n == pytest.approx(0.05 * 2.8, rel=1e-9)
    rows[:80] = False  # 2 s left: no longer a hold to measure
    assert len(hold_drifts(t, ref, force, rows)) == 1
    # no hold left: NaN
    rows[:] = False
    assert math.isnan(drift_groups_pct(hold_drifts(t, ref, force, rows), 4.0).others_pct_fs)


def test_holds_at_levels_with_unloads_between() -> None:
    t = np.arange(60) * 0.5
    f = np.concatenate([np.zeros(10), np.full(20, 2.0), np.zeros(10), np.full(20, 5.0)])
    holds = find_holds(t, f)
    assert hold_tolerance_n(f) == pytest.approx(0.1)  # 2 % of 5 N
    assert holds == (Hold(10, 30, 5.0, 14.5, 2.0), Hold(40, 60, 20.0, 29.5, 5.0))
    assert holds[0].n_rows == 20 and holds[0].duration_s == 9.5
    assert holds[0].edges() == (slice(10, 12), slice(28, 30))  # 10 % of 20 rows: 2 each


def test_holds_with_noise_within_the_tolerance() -> None:
    rng = np.random.default_rng(2)
    t = np.arange(100) * 0.1
    f = 3.0 + rng.uniform(-0.05, 0.05, 100)  # spans < 0.1 N = 2 x (2 % of ~3.05 N)
    (hold,) = find_holds(t, f)
    assert (hold.start, hold.stop) == (0, 100)
    assert hold.level_n == pytest.approx(float(np.mean(f)), rel=1e-12)
    # noise wider than the tolerance cuts it into pieces, none a hold of 3 s
    wide = 3.0 + 0.5 * np.sign(np.sin(np.arange(100)))
    assert find_holds(t, wide) == ()


def test_a_ramp_is_no_hold_and_its_top_joins_the_hold_within_tolerance() -> None:
    # 0 -> 5 N in steps of 0.125 N every 0.125 s (exact binary fractions), then 5 N for 5 s
    k = np.arange(81)
    t = k * 0.125
    f = np.minimum(k * 0.125, 5.0)
    holds = find_holds(t, f, tolerance_n=0.25)
    # rows within 2 x 0.25 N of 5 N: from 4.5 N, row 36 at 4.5 s, to the end
    assert holds == (Hold(36, 81, 4.5, 10.0, float(np.mean(f[36:]))),)
    # a ramp alone is no hold: each 0.5 N span lasts 0.5 s
    assert find_holds(t[:40], f[:40], tolerance_n=0.25) == ()


def test_too_short_holds_and_breaks() -> None:
    assert MIN_HOLD_S == 3.0
    t = np.arange(40) * 0.5
    # 7 rows = 3.0 s first to last: a hold; 6 rows = 2.5 s: none
    f = np.concatenate([np.zeros(5), np.full(7, 2.0), np.zeros(5), np.full(6, 2.0), np.zeros(17)])
    holds = find_holds(t, f)
    assert [(h.start, h.stop) for h in holds] == [(5, 12)]
    assert [(h.start, h.stop) for h in find_holds(t, f, min_duration_s=2.5)] == [(5, 12), (17, 23)]
    # a NaN ends a run: 2 N over 20 rows with a NaN at row 8 -> rows 0-7 (3.5 s) and 9-19 (5 s)
    g = np.full(20, 2.0)
    g[8] = math.nan
    assert [(h.start, h.stop) for h in find_holds(np.arange(20) * 0.5, g)] == [(0, 8), (9, 20)]
    # unloaded noise is never a hold
    assert find_holds(t, np.full(40, 0.01), tolerance_n=0.05) == ()


def test_find_holds_refuses_bad_arguments() -> None:
    with pytest.raises(ValueError, match="one length"):
        find_holds(np.arange(3.0), np.arange(4.0))
    with pytest.raises(ValueError, match="tolerance_n"):
        find_holds(np.arange(3.0), np.arange(3.0), tolerance_n=-1.0)
    with pytest.raises(ValueError, match="min_duration_s"):
        find_holds(np.arange(3.0), np.arange(3.0), min_duration_s=math.nan)
    assert find_holds(np.array([]), np.array([])) == ()
