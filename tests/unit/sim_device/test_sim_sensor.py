"""The simulator's own sensor physics against numbers, with no gateway code.

Parameters: the spec's defaults and validation. Physics: the spec's derived constants and its
table ("What these values give"), eq. 12 and eq. 9 evaluated by hand, and the Kelvin
element's numerical (Runge-Kutta) integration against the paper's closed form, eq. 15.
The hand values were computed separately with CODATA constants; they are quoted to more
digits than the tolerances need.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device import sensor
from sim_device.sensor import PaperSensor, SensorParamsError, SimSensorParams

AREA_M2 = 1.9635e-5

#: The interchange contract's parameter names (the gateway's ``SensorParams`` field names
#: without its inversion range), with the defaults of ``docs/parameters.md``.
SPEC_DEFAULTS = {
    "barrier_height_ev": 0.05,
    "particle_diameter_m": 500e-9,
    "volume_fraction": 0.2873,
    "area_m2": 1.9635e-5,
    "r0_ohm": 200e3,
    "rho1_ohm_m": 1.68e-8,
    "rho2_ohm_m": 1.0,
    "hardness_pa": 30e6,
    "e0_pa": 15e6,
    "e0_slope_pa_per_n": 1.0e6,
    "e1_pa": 150e6,
    "e1_slope_pa_per_n": 10e6,
    "mu1_pa_s": 1.5e10,
    "mu1_slope_pa_s_per_n": 1.0e9,
    "e2_pa": 300e6,
    "mu2_pa_s": 3.0e11,
    "hysteresis_strain": 2e-4,
    "hysteresis_force_n": 0.5,
    "temperature_coeff_per_k": -0.005,
    "reference_temperature_c": 25.0,
    "series_resistance_ohm": 500.0,
    "leakage_resistance_ohm": 2e6,
}


def one(
    force_n: list[float], times_s: list[float], params: SimSensorParams | None = None
) -> sensor.PaperResistance:
    """One default sensor run over a load history given per sample."""
    s = PaperSensor([params or SimSensorParams()])
    return s.run(np.array(force_n, dtype=np.float64)[:, None], np.array(times_s, dtype=np.float64), 0.0)


# ------------------------------------------------------------------------ parameters
def test_defaults_are_the_spec_values_under_the_contract_names() -> None:
    values = SimSensorParams().as_dict()
    assert list(values) == list(SPEC_DEFAULTS)
    assert values == SPEC_DEFAULTS
    assert all(type(v) is float for v in values.values())


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("r0_ohm", -1.0, r"r0_ohm = -1.0 is outside \(0, inf\)"),
        ("r0_ohm", 0.0, r"r0_ohm = 0.0 is outside \(0, inf\)"),
        ("volume_fraction", 0.6, r"volume_fraction = 0.6 is outside \(0, 0.523599\)"),
        ("e1_pa", math.inf, r"e1_pa = inf is outside \(0, inf\)"),
        ("mu1_pa_s", math.nan, r"mu1_pa_s = nan is outside \(0, inf\)"),
        ("hysteresis_strain", 0.2, r"hysteresis_strain = 0.2 is outside \[0, 0.1\]"),
        ("temperature_coeff_per_k", -0.3, r"temperature_coeff_per_k = -0.3 is outside \[-0.2, 0.2\]"),
        ("area_m2", "1e-5", r"area_m2 = '1e-5' must be a number"),
        ("e0_pa", True, r"e0_pa = True must be a number"),
    ],
)
def test_invalid_parameters_are_refused_with_the_field_and_its_range(
    name: str, value: object, message: str
) -> None:
    with pytest.raises(SensorParamsError, match=message):
        SimSensorParams(**{name: value})  # type: ignore[arg-type]


def test_limits_that_are_allowed() -> None:
    p = SimSensorParams(
        leakage_resistance_ohm=math.inf,  # no leakage path
        rho1_ohm_m=0.0,
        e1_slope_pa_per_n=0.0,
        hysteresis_strain=0.0,
        r0_ohm=np.float32(150e3),  # type: ignore[arg-type]
        e0_pa=20_000_000,
    )
    assert p.leakage_resistance_ohm == math.inf and p.rho1_ohm_m == 0.0
    assert type(p.r0_ohm) is float and p.r0_ohm == 150e3
    assert type(p.e0_pa) is float and p.e0_pa == 20e6


def test_overrides_are_validated_and_the_parameters_are_frozen() -> None:
    base = SimSensorParams()
    changed = base.with_overrides({"r0_ohm": 120e3})
    assert changed.r0_ohm == 120e3 and changed.e0_pa == base.e0_pa and base.r0_ohm == 200e3
    assert SimSensorParams(**changed.as_dict()) == changed
    with pytest.raises(SensorParamsError, match="unknown sensor parameter 'r0_ohms'"):
        base.with_overrides({"r0_ohms": 1.0})
    with pytest.raises(SensorParamsError, match="hardness_pa"):
        base.with_overrides({"hardness_pa": -5.0})
    with pytest.raises(dataclasses.FrozenInstanceError):
        base.r0_ohm = 1.0  # type: ignore[misc]


# ------------------------------------------------------------------------ physics
def test_derived_constants_are_the_spec_values() -> None:
    """gamma s0 of eq. 4 and 8: 2.2912e9 1/m x 110.74 nm = 253.7 (spec); 253.72616 by hand."""
    gamma_s0 = float(PaperSensor([SimSensorParams()]).gamma_s0[0])
    assert gamma_s0 == pytest.approx(253.7, abs=0.05)
    assert gamma_s0 == pytest.approx(253.72616, rel=1e-7)
    # D doubled doubles s0, a barrier 4x higher doubles gamma (eq. 4: gamma ~ sqrt(phi))
    assert PaperSensor([SimSensorParams(particle_diameter_m=1e-6)]).gamma_s0[0] == pytest.approx(2 * gamma_s0)
    assert PaperSensor([SimSensorParams(barrier_height_ev=0.2)]).gamma_s0[0] == pytest.approx(2 * gamma_s0)


def test_contact_resistance_is_eq12_for_two_electrodes() -> None:
    """2 R_con = (rho1 + rho2) / 2 sqrt(pi H / F): 4854.0649 ohm at 1 N; F^-1/2; open at F <= 0."""
    s = PaperSensor([SimSensorParams()])
    got = s.contact_ohm(np.array([1.0, 4.0, 0.25, 0.0, -1.0]))
    np.testing.assert_allclose(got[:3], [4854.064863, 2427.032431, 9708.129726], rtol=1e-9)
    assert np.isposinf(got[3:]).all()


def test_polymer_resistance_is_eq9() -> None:
    """R0 (1 - eps) exp(-gamma s0 eps): R0 unstrained, 15658.367 ohm at eps = 1 %."""
    s = PaperSensor([SimSensorParams()])
    got = s.polymer_ohm(np.array([0.0, 0.01, 1.0]))
    np.testing.assert_allclose(got, [200e3, 15658.367, 0.0], rtol=1e-7, atol=0.0)


def test_elastic_strain_uses_e0_at_the_applied_force() -> None:
    """eps = F / (A E0(F)), E0(2 N) = 17 MPa: 0.0059917 at 2 N."""
    s = PaperSensor([SimSensorParams()])
    got = s.elastic_strain(np.array([2.0, 0.0, -1.0]))
    np.testing.assert_allclose(got, [2.0 / (AREA_M2 * 17e6), 0.0, 0.0], rtol=1e-15)
    assert got[0] == pytest.approx(0.0059917, rel=1e-5)


#: docs/parameters.md, "What these values give": F -> (R at t=0 ohm, 2 R_con share %,
#: strain at t=0 %, R drop after a 600 s hold %), as printed.
SPEC_TABLE = {
    0.5: ("138.5e3", "5.0", "0.164", "3.9"),
    1.0: ("93.8e3", "5.2", "0.318", "7.4"),
    2.0: ("46.9e3", "7.3", "0.599", "13.1"),
    5.0: ("9.98e3", "21.8", "1.273", "21.6"),
    8.0: ("3.91e3", "43.9", "1.771", "20.3"),
}


def _half_unit(printed: str) -> float:
    mantissa, _, exponent = printed.partition("e")
    return 0.5 * 10.0 ** (int(exponent or 0) - len(mantissa.partition(".")[2]))


@pytest.mark.parametrize("force_n", sorted(SPEC_TABLE))
def test_the_spec_table_to_its_printed_digits(force_n: float) -> None:
    out = one([force_n, force_n], [0.0, 600.0])
    r0, contact0, strain0 = out.total_ohm[0, 0], out.contact_ohm[0, 0], out.strain[0, 0]
    got = (r0, 100.0 * contact0 / r0, 100.0 * strain0, 100.0 * (1.0 - out.total_ohm[1, 0] / r0))
    for value, printed in zip(got, SPEC_TABLE[force_n], strict=True):
        assert value == pytest.approx(float(printed), abs=_half_unit(printed)), (force_n, printed)


def eq15(force_n: float, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's creep solution (eq. 15) with the spec's E0, E1, mu1 at ``force_n``:
    (elastic F/(A E0), Kelvin F/(A E1) (1 - exp(-E1 t / mu1)))."""
    e0 = 15e6 + 1e6 * force_n
    e1 = 150e6 + 10e6 * force_n
    mu1 = 1.5e10 + 1e9 * force_n
    elastic = np.full_like(t_s, force_n / (AREA_M2 * e0))
    return elastic, force_n / (AREA_M2 * e1) * -np.expm1(-e1 / mu1 * t_s)


KELVIN_REL = 1e-9


@pytest.mark.parametrize("period_s", [0.001, 0.01, 0.1, 1.0, 10.0, 30.0, 600.0])
def test_integrated_creep_follows_eq15_at_every_sample_period(period_s: float) -> None:
    """A step held at three forces, sampled every ``period_s`` for up to 1200 s (2000
    samples at most): the Kelvin strain within 1e-9 relative of eq. 15 (RK4's truncation is
    ~1e-10 at most; rounding dominates short periods), the total strain within 1e-11."""
    n = max(3, min(2000, round(1200.0 / period_s)))
    t = np.asarray(np.arange(n) * period_s, dtype=np.float64)
    forces = (0.5, 2.0, 8.0)
    out = PaperSensor([SimSensorParams()] * 3).run(np.ones((n, 3)) * np.array(forces), t, 0.0)
    for j, f in enumerate(forces):
        elastic, kelvin = eq15(f, t)
        np.testing.assert_allclose(out.strain[1:, j] - elastic[1:], kelvin[1:], rtol=KELVIN_REL, atol=0.0)
        np.testing.assert_allclose(out.strain[:, j], elastic + kelvin, rtol=1e-11, atol=0.0)


def test_coarse_runge_kutta_steps_would_miss_eq15(monkeypatch: pytest.MonkeyPatch) -> None:
    """The sub-steps are what make the integration accurate: one RK4 step across 30 s
    (z = -0.3) misses eq. 15 by 7.4e-5 relative, R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24."""
    monkeypatch.setattr(sensor, "MAX_STEP_OF_TAU", 1.0)
    out = one([2.0, 2.0], [0.0, 30.0])
    _, kelvin = eq15(2.0, np.array([30.0]))
    got = out.strain[1, 0] - 2.0 / (AREA_M2 * 17e6)
    assert got / kelvin[0] - 1.0 == pytest.approx(-7.45e-5, rel=1e-2)
    assert abs(got / kelvin[0] - 1.0) > 100 * KELVIN_REL


def test_a_new_force_acts_on_the_kelvin_element_from_its_sample_on() -> None:
    """Zero-order hold: the force of a sample is held until the next one."""
    out = one([0.0, 2.0, 2.0], [0.0, 1.0, 2.0])
    target = 2.0 / (AREA_M2 * 170e6)  # sigma / E1(2 N)
    elastic = 2.0 / (AREA_M2 * 17e6)
    assert out.strain[0, 0] == 0.0 and out.total_ohm[0, 0] == math.inf
    assert out.strain[1, 0] == pytest.approx(elastic, rel=1e-15)  # nothing crept yet
    assert out.strain[2, 0] - elastic == pytest.approx(target * -math.expm1(-0.01), rel=1e-9)  # tau 100 s


def test_unloading_relaxes_the_kelvin_strain_with_tau_at_zero_force() -> None:
    """600 s at 2 N: e_kv = 2 / (A 170 MPa) (1 - e^-6) = 5.976850e-4; unloaded, it decays with
    mu1(0) / E1(0) = 100 s: 2.198760e-4 after 100 s; the contact is open, R infinite."""
    out = one([2.0, 0.0, 0.0], [0.0, 600.0, 700.0])
    np.testing.assert_allclose(out.strain[1:, 0], [5.976850e-4, 2.198760e-4], rtol=1e-6)
    assert np.isposinf(out.total_ohm[1:, 0]).all() and np.isposinf(out.contact_ohm[1:, 0]).all()
    np.testing.assert_allclose(
        out.polymer_ohm[2, 0], 200e3 * (1 - 2.198760e-4) * math.exp(-253.72616 * 2.198760e-4), rtol=1e-6
    )


def test_running_in_pieces_equals_running_at_once() -> None:
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.01, 20.0, 300))
    force = np.clip(rng.normal(2.0, 1.5, (300, 3)), 0.0, None)
    params = [SimSensorParams(), SimSensorParams(e1_pa=120e6), SimSensorParams(mu1_pa_s=2e10)]
    whole = PaperSensor(params).run(force, t, 0.0)
    pieces = PaperSensor(params)
    parts, start = [], 0.0
    for lo, hi in ((0, 1), (1, 57), (57, 58), (58, 300)):
        parts.append(pieces.run(force[lo:hi], t[lo:hi], start).total_ohm)
        start = float(t[hi - 1])
    np.testing.assert_allclose(np.vstack(parts), whole.total_ohm, rtol=1e-13)
    loaded = force > 0.0
    assert np.isfinite(whole.total_ohm[loaded]).all() and np.isposinf(whole.total_ohm[~loaded]).all()
