"""The FSR emulator (sim_device.fsr_emulator) against numbers worked out by hand.

Expected values come from the equations in the module's docstring evaluated by hand (the
numbers are written out, with the formula next to them), from limiting cases, or from
statistics of the documented distributions; none is read back from the emulator's own
intermediate results.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.measurement import time_is_real
from gateway.analysis.records import read_record
from sim_device.cli import main
from sim_device.fsr_emulator import (
    DEFAULT_HOLD_LEVELS_N,
    EmulatedRecord,
    FsrEmulator,
    FsrParams,
    Protocol,
    calibration_run,
    hold_protocol,
    ohmmeter_reading,
    staircase,
    write_record,
)

K_S, N = 5e-5, 0.8  # the default static curve


def exact(**changes: object) -> FsrParams:
    """Static curve only, ideal instruments, the same sensitivity in every run."""
    base = FsrParams().ideal_instruments().static_only()
    return replace(base, gain_sigma=0.0, exponent_sigma=0.0, **changes)  # type: ignore[arg-type]


def at_level(rec: EmulatedRecord, level_n: float) -> np.ndarray:
    """Sample indices where the applied force is held at ``level_n``."""
    return np.nonzero(np.abs(rec.true_force_n - level_n) < 1e-9)[0]


def conductance(rec: EmulatedRecord) -> np.ndarray:
    return 1.0 / rec.sensor_resistance_ohm


def gain_ratio(on: EmulatedRecord, off: EmulatedRecord) -> np.ndarray:
    """G_on / G_off where the sensor is loaded (nan where both are open)."""
    loaded = off.true_force_n > 0.05
    out = np.full(off.n_samples, np.nan)
    out[loaded] = off.sensor_resistance_ohm[loaded] / on.sensor_resistance_ohm[loaded]
    return out


# ------------------------------------------------------------------------------- static curve


def test_static_curve_is_k_f_to_the_n_plus_the_lead() -> None:
    proto = Protocol().rest(1).ramp(0.2, 1).hold(3).ramp(1, 1).hold(3).ramp(5, 1).hold(3)
    proto = proto.ramp(40, 10).hold(3).unload(10).rest(2).ramp(0.04, 1).hold(3)
    rec = FsrEmulator(exact(), seed=3).run(proto)
    # R = 1 / (k F^n) + R_lead, k = 5e-5 S, n = 0.8, R_lead = 1 ohm
    for level, expected in ((0.2, 72478.96637), (1.0, 20001.0), (5.0, 5519.918646), (40.0, 1046.639553)):
        idx = at_level(rec, level)
        assert idx.size > 20
        np.testing.assert_allclose(rec.resistance_ohm[idx], expected, rtol=1e-8)
        np.testing.assert_allclose(rec.static_resistance_ohm[idx], expected - 1.0, rtol=1e-8)
        np.testing.assert_allclose(rec.effective_force_n[idx], level, rtol=1e-12)
    # at or below the 0.05 N threshold the sensor is open
    assert np.all(np.isinf(rec.resistance_ohm[at_level(rec, 0.04)]))
    assert np.all(np.isinf(rec.resistance_ohm[rec.true_force_n == 0.0]))


def test_leakage_caps_the_open_circuit() -> None:
    proto = Protocol().rest(2).ramp(1, 1).hold(3)
    rec = FsrEmulator(exact(leakage_ohm=1e7), seed=3).run(proto)
    np.testing.assert_allclose(rec.resistance_ohm[rec.true_force_n == 0.0], 1e7 + 1.0, rtol=1e-12)
    # 1 / (k 1^n + 1/R_leak) + 1 = 1 / 5.01e-5 + 1 = 19960.0798 + 1
    np.testing.assert_allclose(rec.resistance_ohm[at_level(rec, 1.0)], 19961.07984, rtol=1e-9)


def test_default_curve_spans_the_typical_fsr_range() -> None:
    p = FsrParams()
    r = [1.0 / (p.k_s * f**p.exponent) for f in (0.2, 40.0)]
    assert 40e3 < r[0] < 100e3
    assert 0.9e3 < r[1] < 2e3
    assert 0.8 <= p.exponent <= 1.1


# ------------------------------------------------------------------------------------ creep


def test_held_step_shows_the_fast_time_constant() -> None:
    a, tau, f, ramp_s = 0.06, 5.0, 10.0, 0.01  # ramp to 10 N at 1000 N/s, then hold
    params = exact(a_fast=a, tau_fast_s=tau)
    rec = FsrEmulator(params, seed=1).run(Protocol().ramp(f, f / ramp_s).hold(60.0), sample_interval_s=0.01)
    x = rec.effective_force_n - rec.true_force_n
    # Kelvin element under a linear ramp of length d: x(d) = a F (1 - (tau/d) (1 - exp(-d/tau)))
    x_ramp = a * f * (1.0 - (tau / ramp_s) * -math.expm1(-ramp_s / tau))
    assert x_ramp == pytest.approx(a * f * ramp_s / (2 * tau), rel=1e-3)  # ~ a F d / (2 tau)
    hold = rec.time_s >= ramp_s
    expected = a * f + (x_ramp - a * f) * np.exp(-(rec.time_s[hold] - ramp_s) / tau)
    np.testing.assert_allclose(x[hold], expected, rtol=1e-9, atol=1e-12)
    i = int(np.argmin(np.abs(rec.time_s - (ramp_s + tau))))
    assert (x[i] - x_ramp) / (a * f - x_ramp) == pytest.approx(1.0 - math.exp(-1.0), abs=1e-6)
    assert x[-1] == pytest.approx(a * f, rel=1e-5)  # 12 time constants


def test_held_step_tends_to_one_plus_a1_plus_a2_times_f_plus_flow() -> None:
    a1, t1, a2, t2, eta, f = 0.06, 5.0, 0.06, 100.0, 2e4, 20.0
    params = exact(a_fast=a1, tau_fast_s=t1, a_slow=a2, tau_slow_s=t2, eta_flow_s=eta)
    d = 0.02  # ramp time at 1000 N/s
    rec = FsrEmulator(params, seed=2).run(Protocol().ramp(f, f / d).hold(3000.0), sample_interval_s=0.5)
    # after the ramp: x_i(d) = a_i F (1 - (tau_i/d) (1 - exp(-d/tau_i))) (about a_i F d / (2 tau_i)),
    # flow (F^2 - 0.05^2) / (2 * 1000 N/s) / eta (the ramp above the 0.05 N threshold)
    x1_d = a1 * f * (1 - (t1 / d) * -math.expm1(-d / t1))
    x2_d = a2 * f * (1 - (t2 / d) * -math.expm1(-d / t2))
    flow_d = (f**2 - 0.05**2) / 2000.0 / eta
    for hold_s in (5.0, 100.0, 2500.0):
        i = int(np.argmin(np.abs(rec.time_s - d - hold_s)))
        tt = rec.time_s[i] - d
        x1 = a1 * f + (x1_d - a1 * f) * math.exp(-tt / t1)
        x2 = a2 * f + (x2_d - a2 * f) * math.exp(-tt / t2)
        expected = f + x1 + x2 + flow_d + f * tt / eta
        assert rec.effective_force_n[i] == pytest.approx(expected, rel=1e-9)
        # without the ramp's small terms: F (1 + a1 (1 - e^-t/tau1) + a2 (1 - e^-t/tau2)) + F t / eta
        simple = f * (1 + a1 * -math.expm1(-tt / t1) + a2 * -math.expm1(-tt / t2)) + f * tt / eta
        assert rec.effective_force_n[i] == pytest.approx(simple, abs=a1 * f * d / (2 * t1) + 1e-4)
    i = int(np.argmin(np.abs(rec.time_s - d - 2500.0)))
    # limit: (1 + a1 + a2) F + F t / eta = 22.4 N + 2.5 N
    assert rec.effective_force_n[i] == pytest.approx(22.4 + 2.5, abs=1e-3)


def test_flow_grows_while_loaded_and_recovers_after_unloading() -> None:
    params = exact(eta_flow_s=2e4, tau_recovery_s=200.0)
    high = Protocol().ramp(40, 20).hold(100).unload(20).rest(50).ramp(5, 20).hold(20)
    rested = Protocol().rest(154.0).ramp(5, 20).hold(20)
    a = FsrEmulator(params, seed=4).run(high, sample_interval_s=0.05)
    b = FsrEmulator(params, seed=4).run(rested, sample_interval_s=0.05)
    # flow after 40 N: (integral of F over the loaded time) / eta
    #   = ((40^2 - 0.05^2) / (2 * 20) * 2 + 40 * 100) / 2e4 = 0.20399999 N,
    # unloaded for 50 s + 2 x 0.0025 s below 0.05 N: times exp(-50.005 / 200),
    # then + ((5^2 - 0.05^2) / 40 + 5 * 20) / 2e4 for the 5 N load: 0.1639026 N at the end
    assert a.effective_force_n[-1] - a.true_force_n[-1] == pytest.approx(0.16390263, abs=2e-6)
    assert b.effective_force_n[-1] - b.true_force_n[-1] == pytest.approx(0.00503125, abs=2e-6)
    assert a.time_s[-1] == pytest.approx(b.time_s[-1], abs=0.1)


def test_a_low_load_after_a_high_load_reads_higher_than_after_rest() -> None:
    high = Protocol().ramp(40, 2).hold(40).unload(2).rest(10).ramp(5, 2).hold(30)
    rested = Protocol().rest(high.duration_s - 32.5).ramp(5, 2).hold(30)
    emu = FsrEmulator(FsrParams(), seed=8)  # every default, noise included
    a, b = emu.run(high, run_index=0), emu.run(rested, run_index=0)
    last_a = a.time_s > a.time_s[-1] - 10
    last_b = b.time_s > b.time_s[-1] - 10
    r_after_high = float(np.median(a.resistance_ohm[last_a]))
    r_after_rest = float(np.median(b.resistance_ohm[last_b]))
    # a lower resistance reads as a higher force: more than 5 % (noise is 0.5 % per sample)
    assert r_after_high < 0.95 * r_after_rest
    # and the memory fades: the difference shrinks over the 5 N hold
    early_a = (a.time_s > a.time_s[-1] - 30) & (a.time_s < a.time_s[-1] - 25)
    early_b = (b.time_s > b.time_s[-1] - 30) & (b.time_s < b.time_s[-1] - 25)
    gap_early = np.median(b.resistance_ohm[early_b]) / np.median(a.resistance_ohm[early_a])
    assert gap_early > r_after_rest / r_after_high


def test_results_do_not_depend_on_the_internal_step_or_the_sampling() -> None:
    proto = calibration_run(cycles=3, hold_s=5, rest_s=5)
    fine = FsrEmulator(replace(FsrParams(), internal_step_s=0.01), seed=5).run(proto)
    coarse = FsrEmulator(replace(FsrParams(), internal_step_s=0.7), seed=5).run(proto)
    np.testing.assert_allclose(fine.effective_force_n, coarse.effective_force_n, rtol=1e-10)
    np.testing.assert_allclose(fine.sensor_resistance_ohm, coarse.sensor_resistance_ohm, rtol=1e-10)
    # another sampling: the states at common instants are the same (exact integration)
    dense = FsrEmulator(replace(FsrParams(), jitter_fraction=0.0), seed=5).run(proto, sample_interval_s=0.05)
    sparse = FsrEmulator(replace(FsrParams(), jitter_fraction=0.0), seed=5).run(proto, sample_interval_s=0.5)
    common = np.searchsorted(dense.time_s, sparse.time_s[:-1] - 1e-9)
    np.testing.assert_allclose(dense.time_s[common], sparse.time_s[:-1], atol=1e-8)
    np.testing.assert_allclose(dense.effective_force_n[common], sparse.effective_force_n[:-1], rtol=1e-7)


# ------------------------------------------------------------------------------- hysteresis


def _h_by_hand(force: np.ndarray, loading: bool, f_max: float, widths: np.ndarray, amp: float) -> np.ndarray:
    """H on the virgin loading branch (-A mean(min(F/r, 1))) or on unloading from f_max
    (-A mean(max(-1, 1 - (f_max - F)/r)))."""
    f = force[:, None]
    d = np.minimum(f / widths, 1.0) if loading else np.maximum(-1.0, 1.0 - (f_max - f) / widths)
    return np.asarray(-amp * d.mean(axis=1))


@pytest.mark.parametrize("rate_n_per_s", [1.0, 20.0])
def test_hysteresis_loop_is_the_same_at_slow_and_fast_loading(rate_n_per_s: float) -> None:
    # Tolerance 1e-9: the play operators are evaluated exactly at each sample (the protocol
    # is monotone between its knots, where it reverses), so the loop is a function of the
    # force path only; 1 and 20 N/s sample it at different forces, and only rounding remains.
    params = exact(hysteresis_amplitude=0.07)
    proto = Protocol().ramp(49, rate_n_per_s).unload(rate_n_per_s)
    rec = FsrEmulator(params, seed=6).run(proto, sample_interval_s=0.01)
    widths = np.array(params.hysteresis_widths_n)
    loaded = rec.true_force_n > 0.05
    ratio = np.full(rec.n_samples, np.nan)
    ratio[loaded] = rec.static_resistance_ohm[loaded] / rec.sensor_resistance_ohm[loaded]  # 1 + H
    up = loaded & (rec.time_s <= 49 / rate_n_per_s)
    down = loaded & (rec.time_s > 49 / rate_n_per_s)
    assert up.sum() > 100 and down.sum() > 100
    np.testing.assert_allclose(
        ratio[up], 1 + _h_by_hand(rec.true_force_n[up], True, 49, widths, 0.07), rtol=1e-9
    )
    np.testing.assert_allclose(
        ratio[down], 1 + _h_by_hand(rec.true_force_n[down], False, 49, widths, 0.07), rtol=1e-9
    )


def test_unloading_reads_a_higher_conductance_than_loading() -> None:
    params = exact(hysteresis_amplitude=0.07)
    rec = FsrEmulator(params, seed=6).run(Protocol().ramp(49, 1).unload(1), sample_interval_s=0.05)
    g = conductance(rec)
    up = rec.time_s <= 49.0
    for f in (10.0, 20.0, 30.0):
        g_up = np.interp(f, rec.true_force_n[up], g[up])
        g_down = np.interp(f, rec.true_force_n[~up][::-1], g[~up][::-1])
        # mid-range, at least 2 x 8 N from the reversal: G_static (1 -+ 0.07)
        g_static = K_S * f**N
        assert g_up == pytest.approx(0.93 * g_static, rel=1e-3)
        assert g_down == pytest.approx(1.07 * g_static, rel=1e-3)
        assert g_down > g_up


# -------------------------------------------------------------------------- runs and meters


def test_run_to_run_gain_and_exponent_are_applied() -> None:
    params = replace(FsrParams().ideal_instruments().static_only(), gain_sigma=0.15, exponent_sigma=0.02)
    emu = FsrEmulator(params, seed=11)
    proto = Protocol().ramp(10, 5).hold(5)
    recs = [emu.run(proto, run_index=i) for i in range(3)]
    for rec in recs:
        c = rec.conditions
        idx = at_level(rec, 10.0)
        np.testing.assert_allclose(
            rec.sensor_resistance_ohm[idx], 1.0 / (c.gain * K_S * 10.0**c.exponent), rtol=1e-12
        )
        assert c == emu.conditions(rec.run)  # reproducible from the seed and run index
    assert len({r.conditions.gain for r in recs}) == 3


def test_run_gains_are_lognormal_and_within_a_factor_two() -> None:
    emu = FsrEmulator(FsrParams(), seed=12)
    conds = [emu.conditions(i) for i in range(400)]
    log_gain = np.log([c.gain for c in conds])
    # ln g = clip(0.15 z, +-ln(2)/2): std = 0.15 sqrt(E[clip(z, c)^2]), c = ln(2)/0.3
    c = math.log(2.0) / 0.3
    phi = math.exp(-c * c / 2) / math.sqrt(2 * math.pi)
    big_phi = 0.5 * (1 + math.erf(c / math.sqrt(2)))
    second_moment = (2 * big_phi - 1) - 2 * c * phi + 2 * c * c * (1 - big_phi)
    assert np.std(log_gain) == pytest.approx(0.15 * math.sqrt(second_moment), rel=0.15)  # ~4 s.e.
    assert abs(np.mean(log_gain)) < 4 * 0.15 / math.sqrt(400)
    # the clip at +-ln(2)/2 is reached on both sides in 400 draws (|z| > 2.3: 2 % of them) and
    # never passed, so the gains of any two runs differ by 2x at most, and here by exactly 2x
    bound = math.log(2.0) / 2.0
    assert (
        np.count_nonzero(log_gain >= bound - 1e-12) >= 1 and np.count_nonzero(log_gain <= -bound + 1e-12) >= 1
    )
    assert np.max(np.abs(log_gain)) <= bound + 1e-12
    assert math.exp(log_gain.max() - log_gain.min()) == pytest.approx(2.0, rel=1e-9)
    assert np.std([c.exponent for c in conds]) == pytest.approx(0.02, rel=0.15)
    assert np.std([c.load_cell_offset_n for c in conds]) == pytest.approx(0.03, rel=0.15)
    none = FsrEmulator(replace(FsrParams(), gain_sigma=0.0, exponent_sigma=0.0), seed=12)
    assert {(none.conditions(i).gain, none.conditions(i).exponent) for i in range(5)} == {(1.0, 0.8)}


def test_timestamps_increase_with_bounded_jitter() -> None:
    rec = FsrEmulator(FsrParams(), seed=13).run(Protocol().ramp(5, 1).hold(495), sample_interval_s=0.1)
    dt = np.diff(rec.time_s)
    assert rec.time_s[0] == 0.0
    assert np.all(dt > 0)
    assert dt.min() >= 0.08 - 1e-12 and dt.max() <= 0.12 + 1e-12
    # intervals 0.1 (1 + 0.2 u), u ~ U(-1, 1): mean 0.1, std 0.02 / sqrt(3) = 0.011547
    assert dt.mean() == pytest.approx(0.1, rel=0.005)
    assert dt.std() == pytest.approx(0.011547, rel=0.05)
    assert 500.0 - 0.12 < rec.time_s[-1] <= 500.0
    still = FsrEmulator(replace(FsrParams(), jitter_fraction=0.0), seed=13).run(Protocol().hold(10))
    np.testing.assert_allclose(np.diff(still.time_s), 0.1, rtol=1e-9)


def test_ohmmeter_quantisation_by_hand() -> None:
    values = [123.456, 1234.567, 19999.4, 19999.6, 1.5e7, 2.5e7, math.inf, 199.996, 0.5, 54321.09, 1.99997e7]
    # 200 ohm range: 0.01 ohm steps; 2 k: 0.1; 20 k: 1; 200 k: 10; 20 M: 1000; 200.00 on 2 k;
    # 19999.6 rounds to 20000 counts on 20 k, so the 200 k range shows 20000 (2000 counts);
    # 19.9997 Mohm rounds to 20000 counts on the top range: over range
    expected = [123.46, 1234.6, 19999.0, 20000.0, 1.5e7, math.inf, math.inf, 200.0, 0.5, 54320.0, math.inf]
    assert ohmmeter_reading(values).tolist() == expected
    assert ohmmeter_reading(values, counts=0).tolist() == values


def test_run_readings_are_quantised_and_open_is_inf() -> None:
    rec = FsrEmulator(FsrParams(), seed=14).run(hold_protocol((0.3, 5.0, 40.0), hold_s=5, rest_s=5))
    open_ = rec.true_force_n <= 0.05
    assert open_.any() and np.all(np.isinf(rec.resistance_ohm[open_]))
    assert np.all(np.isfinite(rec.resistance_ohm[~open_]))
    r = rec.resistance_ohm[~open_]
    full_scale = 200.0 * 10.0 ** np.floor(np.log10(r / 200.0) + 1)  # the range the reading is on
    counts = r / (full_scale / 20000)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert counts.max() < 20000 and counts.min() >= 2000 - 1e-6
    # relative noise 0.5 % on R + 1 ohm (quantisation adds <= 0.025 %)
    rel = r / (rec.sensor_resistance_ohm[~open_] + 1.0) - 1.0
    assert np.std(rel) == pytest.approx(0.005, rel=0.15)


def test_load_cell_noise_offset_and_no_negative_forces() -> None:
    emu = FsrEmulator(FsrParams(), seed=19)  # a run whose zero offset is near 0 (-0.009 N)
    rec = emu.run(Protocol().rest(100).ramp(10, 5).hold(200))
    assert abs(rec.conditions.load_cell_offset_n) < 0.02
    held = at_level(rec, 10.0)
    err = rec.force_n[held] - 10.0
    assert np.mean(err) == pytest.approx(
        rec.conditions.load_cell_offset_n, abs=4 * 0.02 / math.sqrt(held.size)
    )
    assert np.std(err) == pytest.approx(0.02, rel=0.1)
    np.testing.assert_allclose(rec.force_n * 1000, np.round(rec.force_n * 1000), atol=1e-6)
    assert rec.force_n.min() >= 0.0
    # at zero load every reading offset + noise < 0.0005 N (rounded to 0 or below) shows 0:
    # a fraction Phi((0.0005 - offset) / 0.02) of the ~1000 rest samples (s.e. <= 0.016)
    rest = rec.true_force_n == 0.0
    zeros = float(np.mean(rec.force_n[rest] == 0.0))
    z = (0.0005 - rec.conditions.load_cell_offset_n) / 0.02
    assert zeros == pytest.approx(0.5 * (1 + math.erf(z / math.sqrt(2))), abs=0.07)


# ------------------------------------------------------------------------------- protocols


def test_protocol_builders() -> None:
    p = hold_protocol([5, 20], hold_s=10, rest_s=20, rate_n_per_s=1, lead_s=5)
    # 5 + (5 + 10 + 5 + 20) + (20 + 10 + 20 + 20)
    assert p.duration_s == pytest.approx(115.0)
    assert p.force_at(np.array([5.0, 10.0, 15.0, 30.0, 65.0, 70.0])).tolist() == [0, 5, 5, 0, 20, 20]
    assert p.rate_at(np.array([7.0, 12.0, 22.0])).tolist() == [1.0, 0.0, -1.0]
    assert p.loading_cycles(0.05) == 2
    s = staircase((5, 10), step_s=10, rate_n_per_s=1, rest_s=10, lead_s=0)
    # up 5 (5 s) hold 10, up 10 (5 s) hold 10, down to 5 (5 s) hold 10, unload (5 s), rest 10
    assert s.duration_s == pytest.approx(60.0)
    assert s.loading_cycles(0.05) == 1
    c = calibration_run()
    _, forces = c.knots()
    assert forces.max() == pytest.approx(49.0)
    assert c.loading_cycles(0.05) == 1 + 6 + 6
    peaks = [f for i, f in enumerate(forces[1:-1], 1) if forces[i - 1] == 0 and f > 0]
    assert peaks != sorted(peaks)  # levels in a non-monotone order
    assert list(DEFAULT_HOLD_LEVELS_N) != sorted(DEFAULT_HOLD_LEVELS_N)
    with pytest.raises(ValueError, match="rate_n_per_s"):
        Protocol().ramp(5, 0)


# ----------------------------------------------------------------- out-of-catalogue effects


def test_out_of_catalogue_effects_are_off_by_default() -> None:
    p = FsrParams()
    assert (p.wear_per_cycle, p.rate_gain_s, p.humidity) == (0.0, 0.0, 0.0)
    assert p.out_of_catalogue() == {}
    rec = FsrEmulator(exact(), seed=17).run(hold_protocol([10] * 3, hold_s=5, rest_s=5, rate_n_per_s=20))
    np.testing.assert_allclose(rec.sensor_resistance_ohm[rec.true_force_n > 0.05],
                               rec.static_resistance_ohm[rec.true_force_n > 0.05], rtol=1e-12)  # fmt: skip


def test_wear_lowers_k_per_loading_cycle_and_carries_over_runs() -> None:
    proto = hold_protocol([10] * 4, hold_s=5, rest_s=5)
    emu = FsrEmulator(exact(wear_per_cycle=0.1), seed=18)
    runs = emu.run_many(proto, 2)
    assert [r.cycles for r in runs] == [4, 4]
    # 1 / (k 10^0.8) = 3169.786 ohm, times 1 / 0.9^(m - 1) in the m-th loading cycle
    for run_no, rec in enumerate(runs):
        held = at_level(rec, 10.0)
        starts = np.nonzero(np.diff(held) > 1)[0] + 1
        for m, chunk in enumerate(np.split(held, starts), start=1 + 4 * run_no):
            np.testing.assert_allclose(rec.sensor_resistance_ohm[chunk], 3169.786 / 0.9 ** (m - 1), rtol=1e-6)


def test_rate_gain_scales_conductance_with_the_loading_rate() -> None:
    proto = Protocol().ramp(40, 20).hold(5).unload(20).rest(1)
    off = FsrEmulator(exact(), seed=19).run(proto, sample_interval_s=0.02)
    on = FsrEmulator(exact(rate_gain_s=0.5), seed=19).run(proto, sample_interval_s=0.02)
    ratio = gain_ratio(on, off)
    loaded = on.true_force_n > 0.05
    t = on.time_s
    # 1 + 0.5 s * (dF/dt) / 50 N: +20 N/s -> 1.2, hold -> 1, -20 N/s -> 0.8
    np.testing.assert_allclose(ratio[loaded & (t < 2.0)], 1.2, rtol=1e-12)
    np.testing.assert_allclose(ratio[loaded & (t > 2.0) & (t < 7.0)], 1.0, rtol=1e-12)
    np.testing.assert_allclose(ratio[loaded & (t > 7.0)], 0.8, rtol=1e-12)
    strong = FsrEmulator(exact(rate_gain_s=5.0), seed=19).run(proto, sample_interval_s=0.02)
    down = loaded & (t > 7.0)
    # 1 + 5 * (-20) / 50 = -1 is floored at 0.1
    np.testing.assert_allclose(gain_ratio(strong, off)[down], 0.1, rtol=1e-12)


def test_humidity_is_a_slow_sinusoid_unrelated_to_load() -> None:
    proto = Protocol().ramp(10, 10).hold(600)
    off = FsrEmulator(exact(), seed=20).run(proto)
    on = FsrEmulator(exact(humidity=0.05), seed=20).run(proto)
    phase = on.conditions.humidity_phase_rad
    loaded = on.true_force_n > 0.05
    expected = 1 + 0.05 * np.sin(2 * math.pi * on.time_s[loaded] / 300.0 + phase)
    np.testing.assert_allclose(gain_ratio(on, off)[loaded], expected, rtol=1e-12)
    with pytest.raises(ValueError, match="humidity"):
        FsrParams(humidity=1.5)


# ---------------------------------------------------------------------- records and the CLI


def test_written_record_reads_with_the_gateway_reader(tmp_path: Path) -> None:
    emu = FsrEmulator(FsrParams(), seed=21)
    recs = emu.run_many(hold_protocol([5, 20], hold_s=5, rest_s=5, lead_s=1), 2)
    path = tmp_path / "fsr.csv"
    path.write_text("old\n", encoding="utf-8")
    assert write_record(path, recs, gap_s=60.0) == path
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fsr.csv"]  # no temporary left
    record = read_record(path, require_force=True)
    meta = record.metadata
    assert time_is_real(meta) and meta["time"] == "real"
    assert meta["sensor"] == "emulated FSR (sim_device.fsr_emulator)"
    second = recs[0].time_s[-1] + 60.0
    assert meta["runs"] == f"0.000000, {second:.6f}"
    assert meta["seed"] == "21" and meta["protocol"] == "holds"
    assert meta["out_of_catalogue"] == "none"
    ch = record.channel("0")
    assert list(record.channels) == ["0"]
    n0, n1 = recs[0].n_samples, recs[1].n_samples
    assert ch.n_samples == n0 + n1
    assert np.all(np.diff(ch.time_s) > 0)
    assert ch.time_s[n0] == pytest.approx(second, abs=1e-6)
    np.testing.assert_allclose(ch.time_s[n0:], recs[1].time_s + second, atol=1e-6)
    both_r = np.concatenate([r.resistance_ohm for r in recs])
    both_f = np.concatenate([r.force_n for r in recs])
    np.testing.assert_array_equal(np.isinf(ch.resistance_ohm), np.isinf(both_r))
    finite = np.isfinite(both_r)
    np.testing.assert_allclose(ch.resistance_ohm[finite], both_r[finite], rtol=1e-9)
    assert ch.force_n is not None
    np.testing.assert_allclose(ch.force_n, both_f, rtol=1e-9, atol=1e-12)
    assert ch.unusable_counts()["open_circuit"] > 0


def test_write_record_refuses_mixed_parameters_and_leaves_the_file(tmp_path: Path) -> None:
    proto = Protocol().ramp(5, 5).hold(2)
    a = FsrEmulator(FsrParams(), seed=1).run(proto)
    b = FsrEmulator(replace(FsrParams(), humidity=0.1), seed=1).run(proto)
    path = tmp_path / "x.csv"
    path.write_text("old\n", encoding="utf-8")
    with pytest.raises(ValueError, match="same FsrParams"):
        write_record(path, [a, b])
    assert path.read_text(encoding="utf-8") == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv"]


def test_cli_fsr_record_writes_a_readable_file(tmp_path: Path) -> None:
    out = tmp_path / "cli.csv"
    args = ["fsr-record", str(out), "--runs", "2", "--seed", "5", "--protocol", "staircase",
            "--wear-per-cycle", "0.01", "--humidity", "0.05"]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert str(out) in result.output
    record = read_record(out, require_force=True)
    assert record.metadata["seed"] == "5"
    assert record.metadata["protocol"] == "staircase"
    assert len(record.metadata["runs"].split(",")) == 2
    assert "wear_per_cycle=0.01" in record.metadata["out_of_catalogue"]
    assert "humidity=0.05" in record.metadata["out_of_catalogue"]
    assert record.channel("0").n_samples > 1000


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["--humidity", "1.5"], 1, "humidity"),
        (["--protocol", "nosuch"], 2, "nosuch"),
        (["--runs", "0"], 2, "--runs"),
    ],
)
def test_cli_fsr_record_bad_options(tmp_path: Path, args: list[str], code: int, message: str) -> None:
    result = CliRunner().invoke(main, ["fsr-record", str(tmp_path / "o.csv"), *args])
    assert result.exit_code == code, result.output
    assert message in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "o.csv").exists()
