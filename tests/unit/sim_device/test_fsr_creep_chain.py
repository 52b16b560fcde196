"""The FSR emulator's creep chain, run gains and bench effects against numbers worked out by hand.

Expected values come from the closed forms of section 2b of ``sim_device.fsr_emulator``'s
docstring (a Kelvin element under a held step or a linear ramp), from an independent numerical
integration of the element's differential equation (scipy's Runge-Kutta), from limiting cases
(equal loading and recovery time constants are the Burgers model's Kelvin element), or from
the documented distributions. None is read back from the emulator's own intermediate results.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sim_device.fsr_emulator import (
    CreepElement,
    EmulatedRecord,
    FsrEmulator,
    FsrParams,
    Protocol,
    calibration_run,
)

K_S, N = 5e-5, 0.8  # the default static curve


def exact(**changes: object) -> FsrParams:
    """Static curve only, ideal instruments, the same sensitivity in every run."""
    base = FsrParams().ideal_instruments().static_only()
    return replace(base, gain_sigma=0.0, exponent_sigma=0.0, **changes)  # type: ignore[arg-type]


def chain_state(rec: EmulatedRecord) -> np.ndarray:
    """The chain's contribution to the effective force, N (the only creep in ``exact``)."""
    return np.asarray(rec.effective_force_n - rec.true_force_n)


def ramp_response(a: float, f_from: float, f_to: float, ramp_s: float, tau_s: float) -> float:
    """x at the end of a linear ramp from f_from to f_to, starting at equilibrium x = a f_from:
    x = a f_to - a s tau (1 - exp(-d / tau)), s = (f_to - f_from) / d."""
    s = (f_to - f_from) / ramp_s
    return a * f_to - a * s * tau_s * -math.expm1(-ramp_s / tau_s)


# ------------------------------------------------------------------------- loading, recovery


def test_loading_follows_tau_load() -> None:
    a, tau_load, tau_rec, f, ramp_s = 0.2, 2.0, 30.0, 10.0, 0.01
    params = exact(creep_chain=(CreepElement(a, tau_load, tau_rec),))
    rec = FsrEmulator(params, seed=1).run(Protocol().ramp(f, f / ramp_s).hold(30.0), sample_interval_s=0.01)
    x = chain_state(rec)
    x_ramp = ramp_response(a, 0.0, f, ramp_s, tau_load)  # from rest: ~ a F d / (2 tau) = 0.005 N
    assert x_ramp == pytest.approx(a * f * ramp_s / (2 * tau_load), rel=1e-2)
    hold = rec.time_s >= ramp_s
    expected = a * f + (x_ramp - a * f) * np.exp(-(rec.time_s[hold] - ramp_s) / tau_load)
    np.testing.assert_allclose(x[hold], expected, rtol=1e-9, atol=1e-12)
    i = int(np.argmin(np.abs(rec.time_s - (ramp_s + tau_load))))
    assert (x[i] - x_ramp) / (a * f - x_ramp) == pytest.approx(1.0 - math.exp(-1.0), abs=1e-5)
    assert x[-1] == pytest.approx(a * f, rel=1e-6)  # 15 loading time constants: 2 N


def test_recovery_after_a_step_down_follows_tau_recovery() -> None:
    a, tau_load, tau_rec, f_hi, f_lo, rate = 0.2, 1.0, 8.0, 20.0, 5.0, 1000.0
    params = exact(creep_chain=(CreepElement(a, tau_load, tau_rec),))
    proto = Protocol().ramp(f_hi, rate).hold(40.0).ramp(f_lo, rate).hold(60.0)
    rec = FsrEmulator(params, seed=2).run(proto, sample_interval_s=0.01)
    x = chain_state(rec)
    # charged after 40 tau_load (x = a F_hi = 4 N to 1e-17), then the 15 ms ramp down recovers:
    # x0 = a F_lo + a (F_hi - F_lo) (tau/d) (1 - exp(-d/tau)) = 1 + 3 x 0.999063 = 3.997189 N
    t_step = f_hi / rate + 40.0
    d = (f_hi - f_lo) / rate
    x0 = ramp_response(a, f_hi, f_lo, d, tau_rec)
    assert x0 == pytest.approx(3.997189, abs=1e-6)
    hold = rec.time_s >= t_step + d
    u = rec.time_s[hold] - (t_step + d)
    np.testing.assert_allclose(x[hold], a * f_lo + (x0 - a * f_lo) * np.exp(-u / tau_rec), rtol=1e-9)
    i = int(np.argmin(np.abs(u - tau_rec)))
    # the sample nearest to tau_rec lies within 5 ms of it: e^-1 to within 0.37 x 0.005 / 8
    assert (x[hold][i] - a * f_lo) / (x0 - a * f_lo) == pytest.approx(math.exp(-1.0), abs=2.5e-4)
    # with tau_load instead, 8 s after the step the excess would be e^-8 of it, not e^-1
    assert (x[hold][i] - a * f_lo) > 100 * (x0 - a * f_lo) * math.exp(-8.0)


def test_a_set_reads_low_after_a_high_load_and_recovers() -> None:
    """A negative amplitude: x charges to a F_hi < 0, so F_eff at a low load after a high one
    is below the rested value and recovers with tau_recovery; R = 1 / (k F_eff^n)."""
    a, tau_load, tau_rec, rate = -0.05, 0.2, 10.0, 1000.0
    params = exact(creep_chain=(CreepElement(a, tau_load, tau_rec),))
    high = Protocol().ramp(3.3, rate).hold(10.0).ramp(25.5, rate).hold(20.0).ramp(3.3, rate).hold(30.0)
    rec = FsrEmulator(params, seed=3).run(high, sample_interval_s=0.01)
    t_step = 3.3 / rate + 10.0 + 22.2 / rate + 20.0
    d = 22.2 / rate
    # charged: a 25.5 = -1.275 N; the 22 ms ramp down recovers it to
    # -0.165 - 0.05 x 1000 x 10 (1 - e^-0.00222) = -1.273769 N
    x0 = ramp_response(a, 25.5, 3.3, d, tau_rec)
    assert x0 == pytest.approx(-1.273769, abs=1e-6)
    for u in (0.5, 5.0, 10.0, 29.0):
        i = int(np.argmin(np.abs(rec.time_s - (t_step + d + u))))
        uu = rec.time_s[i] - (t_step + d)
        f_eff = 3.3 + a * 3.3 + (x0 - a * 3.3) * math.exp(-uu / tau_rec)
        assert rec.effective_force_n[i] == pytest.approx(f_eff, rel=1e-9)
        assert rec.sensor_resistance_ohm[i] == pytest.approx(1.0 / (K_S * f_eff**N), rel=1e-9)
    # rested at 3.3 N (the lead): F_eff = 3.3 (1 + a) = 3.135 N; 0.5 s after the high load it is
    # 3.3 - 0.165 - 1.108769 e^-0.05 = 2.080306 N: the conductance reads 28 % lower
    lead = int(np.argmin(np.abs(rec.time_s - 10.0)))
    assert rec.effective_force_n[lead] == pytest.approx(3.135, abs=1e-6)
    after = int(np.argmin(np.abs(rec.time_s - (t_step + d + 0.5))))  # within 5 ms of 0.5 s
    uu = rec.time_s[after] - (t_step + d)
    f_after = 3.135 + (x0 - a * 3.3) * math.exp(-uu / tau_rec)
    assert f_after == pytest.approx(2.080306, abs=1e-3)
    ratio = rec.sensor_resistance_ohm[lead] / rec.sensor_resistance_ohm[after]
    assert ratio == pytest.approx((f_after / 3.135) ** N, rel=1e-9)  # about 0.7203


def test_a_large_set_takes_the_contact_off() -> None:
    """F_eff <= 0 is no contact: open without leakage, the leakage with it."""
    params = exact(creep_chain=(CreepElement(-0.9, 0.1, 20.0),))
    proto = Protocol().ramp(40.0, 1000.0).hold(5.0).ramp(1.0, 1000.0).hold(5.0)
    rec = FsrEmulator(params, seed=4).run(proto, sample_interval_s=0.05)
    low = rec.time_s > proto.duration_s - 4.0
    # x ~ -36 N e^(-t/20) - 0.9 (1 - ...) + ...: far below -1 N for the whole low hold
    assert np.all(rec.effective_force_n[low] < 0.0)
    assert np.all(np.isinf(rec.sensor_resistance_ohm[low]))
    leaky = FsrEmulator(replace(params, leakage_ohm=1e6), seed=4).run(proto, sample_interval_s=0.05)
    np.testing.assert_allclose(leaky.sensor_resistance_ohm[low], 1e6, rtol=1e-12)


# ---------------------------------------------------------- exactness against an integration


def _integrated(element: CreepElement, proto: Protocol, times: np.ndarray) -> np.ndarray:
    """dx/dt = (a F - x) / tau, tau = tau_load if |a F| > |x| else tau_recovery, by RK45."""
    a = element.amplitude

    def rhs(t: float, y: np.ndarray) -> list[float]:
        target = a * float(proto.force_at(t))
        tau = element.tau_load_s if abs(target) > abs(y[0]) else element.tau_recovery_s
        return [(target - y[0]) / tau]

    knots, _ = proto.knots()
    out = np.empty(times.size)
    y0 = [0.0]
    for t0, t1 in itertools.pairwise(knots):  # piece by piece: F is smooth on each
        inside = (times >= t0) & (times < t1)
        when = np.append(times[inside], t1)
        sol = solve_ivp(rhs, (t0, t1), y0, t_eval=when, rtol=1e-11, atol=1e-13, max_step=0.05)
        out[inside] = sol.y[0, :-1]
        y0 = [float(sol.y[0, -1])]
    out[times >= knots[-1]] = y0[0]
    return out


@pytest.mark.parametrize("amplitude", [0.3, -0.3])
def test_regime_changes_within_a_ramp_match_an_integration(amplitude: float) -> None:
    """Up and down ramps with no hold: the element switches from loading to recovery inside
    the down ramp (and back inside the next up ramp), where the closed form solves for it."""
    element = CreepElement(amplitude, 1.0, 5.0)
    proto = Protocol().ramp(20.0, 2.0).ramp(5.0, 3.0).ramp(15.0, 4.0).ramp(0.0, 2.0).hold(5.0)
    rec = FsrEmulator(exact(creep_chain=(element,)), seed=5).run(proto, sample_interval_s=0.1)
    expected = _integrated(element, proto, rec.time_s)
    np.testing.assert_allclose(chain_state(rec), expected, atol=1e-7)
    # both regimes really occur: somewhere |x| exceeds |a F| (recovering) and somewhere not
    x, target = chain_state(rec), amplitude * rec.true_force_n
    assert np.any(np.abs(x) > np.abs(target) + 0.1) and np.any(np.abs(x) < np.abs(target) - 0.1)


def test_equal_time_constants_are_the_burgers_kelvin_element() -> None:
    """Limiting case: tau_load = tau_recovery is the symmetric Kelvin element (a_fast, tau_fast),
    integrated there by another method (sub-steps and a linear filter)."""
    proto = calibration_run(cycles=3, hold_s=5, rest_s=5)
    kelvin = FsrEmulator(exact(a_fast=0.08, tau_fast_s=4.0), seed=6).run(proto)
    chain = FsrEmulator(exact(creep_chain=(CreepElement(0.08, 4.0, 4.0),)), seed=6).run(proto)
    np.testing.assert_allclose(chain.effective_force_n, kelvin.effective_force_n, rtol=1e-9, atol=1e-12)


def test_the_chain_does_not_depend_on_the_sampling() -> None:
    params = replace(
        FsrParams(),
        jitter_fraction=0.0,
        creep_chain=(CreepElement(0.05, 2.0, 0.3), CreepElement(-0.04, 0.3, 12.0)),
    )
    proto = calibration_run(cycles=3, hold_s=5, rest_s=5)
    dense = FsrEmulator(params, seed=7).run(proto, sample_interval_s=0.05)
    sparse = FsrEmulator(params, seed=7).run(proto, sample_interval_s=0.5)
    common = np.searchsorted(dense.time_s, sparse.time_s[:-1] - 1e-9)
    np.testing.assert_allclose(dense.time_s[common], sparse.time_s[:-1], atol=1e-8)
    np.testing.assert_allclose(dense.effective_force_n[common], sparse.effective_force_n[:-1], rtol=1e-7)


@pytest.mark.parametrize(
    ("element", "message"),
    [
        ((1.5, 1.0, 1.0), "amplitude must be in \\(-1, 1\\)"),
        ((0.1, 0.0, 1.0), "tau_load_s must be > 0"),
        ((0.1, 1.0, math.inf), "tau_recovery_s must be finite"),
    ],
)
def test_bad_creep_elements_are_refused(element: tuple[float, float, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        CreepElement(*element)


def test_amplitudes_summing_to_minus_one_are_refused() -> None:
    with pytest.raises(ValueError, match="must sum to more than -1"):
        FsrParams(a_fast=0.0, a_slow=0.0, creep_chain=(CreepElement(-0.6, 1, 1), CreepElement(-0.5, 1, 1)))


# ------------------------------------------------------------------------------ run gains


def test_a_run_gain_of_two_halves_the_resistance_at_every_load() -> None:
    params = exact(run_gains=(1.0, 2.0))
    emu = FsrEmulator(params, seed=8)
    proto = Protocol().ramp(5.0, 5.0).hold(3.0).ramp(40.0, 10.0).hold(3.0)
    one, two, three = (emu.run(proto, run_index=i) for i in range(3))
    assert (one.conditions.gain, two.conditions.gain, three.conditions.gain) == (1.0, 2.0, 1.0)
    np.testing.assert_array_equal(one.time_s, two.time_s)
    loaded = one.true_force_n > 0.05
    np.testing.assert_allclose(two.sensor_resistance_ohm[loaded], 0.5 * one.sensor_resistance_ohm[loaded])
    # at 40 N: 1 / (2 k 40^0.8) = 1 / (1e-4 x 19.127) = 522.8 ohm
    at_40 = np.abs(two.true_force_n - 40.0) < 1e-9
    np.testing.assert_allclose(two.sensor_resistance_ohm[at_40], 522.8198, rtol=1e-6)
    with pytest.raises(ValueError, match="run_gains must be > 0"):
        FsrParams(run_gains=(1.0, 0.0))


# ---------------------------------------------------------------------- bench: lag, noise, time


def test_the_load_cell_lags_the_sensor() -> None:
    params = replace(exact(), load_cell_lag_s=0.4)  # ideal_instruments set no lag: set it after
    proto = Protocol().rest(1.0).ramp(10.0, 2.0).hold(3.0)
    rec = FsrEmulator(params, seed=9).run(proto, sample_interval_s=0.05)
    # the reference reads F(t - 0.4 s): 0 until 1.4 s, then 2 N/s x (t - 1.4 s) up to 10 N
    expected = np.clip(2.0 * (rec.time_s - 1.4), 0.0, 10.0)
    np.testing.assert_allclose(rec.force_n, expected, atol=1e-9)
    # the sensor is not lagged: its force is 2 (t - 1) on the ramp
    ramp = (rec.time_s > 1.0) & (rec.time_s < 6.0)
    np.testing.assert_allclose(rec.true_force_n[ramp], 2.0 * (rec.time_s[ramp] - 1.0), atol=1e-9)


def test_absolute_ohmmeter_noise_adds_in_quadrature() -> None:
    base = replace(exact(), ohmmeter_noise_rel=0.05, ohmmeter_noise_ohm=60.0, lead_ohm=1.0)
    proto = Protocol().ramp(40.0, 100.0).hold(400.0)
    rec = FsrEmulator(base, seed=10).run(proto)
    held = rec.true_force_n == 40.0
    wired = rec.sensor_resistance_ohm[held] + 1.0  # 1 / (k 40^0.8) + 1 = 1046.64 ohm
    assert wired[0] == pytest.approx(1046.640, abs=1e-3)
    # sqrt((0.05 x 1046.64)^2 + 60^2) = 79.61 ohm; 4000 samples: s.e. of the std ~1.1 %
    assert np.std(rec.resistance_ohm[held] - wired) == pytest.approx(79.61, rel=0.05)
    at_rest = FsrEmulator(base, seed=10).run(Protocol().hold(5.0))
    assert np.all(np.isinf(at_rest.resistance_ohm))  # open stays open, never nan


def test_bursts_of_samples() -> None:
    params = replace(exact(), burst_size=5, burst_gap_s=0.12)
    rec = FsrEmulator(params, seed=11).run(Protocol().hold(10.0), sample_interval_s=0.02)
    dt = np.diff(rec.time_s)
    # four intervals of 0.02 s, then one of 0.12 s: a mean of 0.04 s, 251 samples in 10 s
    np.testing.assert_allclose(dt[:10], [0.02] * 4 + [0.12] + [0.02] * 4 + [0.12], rtol=1e-9)
    assert rec.n_samples == 251
    jittered = replace(params, jitter_fraction=0.5)
    t = FsrEmulator(jittered, seed=11).run(Protocol().hold(200.0), sample_interval_s=0.02).time_s
    gaps, inner = np.diff(t)[4::5], np.delete(np.diff(t), np.s_[4::5])
    assert gaps.min() >= 0.11 - 1e-12 and gaps.max() <= 0.13 + 1e-12  # 0.12 +- 0.5 x 0.02
    assert inner.min() >= 0.01 - 1e-12 and inner.max() <= 0.03 + 1e-12
    assert np.mean(np.diff(t)) == pytest.approx(0.04, rel=0.01)
    with pytest.raises(ValueError, match="burst_gap_s must be > jitter_fraction"):
        FsrEmulator(replace(jittered, burst_gap_s=0.005)).run(Protocol().hold(1.0), sample_interval_s=0.02)
    with pytest.raises(ValueError, match="burst_gap_s must be > 0"):
        FsrParams(burst_size=5)


def test_static_force_reads_the_static_curve_back() -> None:
    params = exact(leakage_ohm=270e3, lead_ohm=1.0, run_gains=(1.5,))
    rec = FsrEmulator(params, seed=12).run(Protocol().ramp(30.0, 5.0).hold(2.0).unload(5.0).rest(1.0))
    loaded = rec.true_force_n > 0.05
    np.testing.assert_allclose(rec.static_force_n()[loaded], rec.true_force_n[loaded], rtol=1e-9)
    # at the leakage (unloaded), and open, the static lookup reads 0 N
    assert np.all(rec.static_force_n()[~loaded] < 1e-6)
    assert rec.static_force_n(np.array([np.inf]))[0] == 0.0
    # 1 / (1.5 k 10^0.8) + 1 ohm = 2114.1909 ohm reads 10 N with the leakage off
    no_leak = FsrEmulator(exact(run_gains=(1.5,)), seed=12).run(Protocol().ramp(1.0, 1.0))
    assert no_leak.static_force_n(np.array([2114.1909]))[0] == pytest.approx(10.0, rel=1e-6)
