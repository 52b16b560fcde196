"""The paper's equations against hand-computed numbers and the spec table."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.model import SensorModel, SensorParams
from gateway.model.physics import (
    contact_coefficient_ohm_sqrt_n,
    interparticle_separation_m,
    kelvin_held_strain,
    kelvin_step,
    tunneling_decay_per_m,
)

FORCES_N = np.array([0.5, 1.0, 2.0, 5.0, 8.0])
# linqstat-parameters.md, "What these values give"
SPEC_R_TOTAL_T0_OHM = np.array([138.5e3, 93.8e3, 46.9e3, 9.98e3, 3.91e3])
SPEC_CONTACT_SHARE = np.array([0.050, 0.052, 0.073, 0.218, 0.439])
SPEC_STRAIN_T0 = np.array([0.00164, 0.00318, 0.00599, 0.01273, 0.01771])
SPEC_DROP_600S = np.array([0.039, 0.074, 0.131, 0.216, 0.203])


@pytest.fixture
def paper() -> SensorModel:
    return SensorModel("tunneling,contact,creep", [SensorParams()] * FORCES_N.size)


def _close_to_printed(value: np.ndarray, printed: np.ndarray) -> None:
    """The spec prints 3-4 significant digits: agree within 0.1 % or half a printed digit."""
    digits = np.array([len(f"{p:.4g}".replace(".", "").replace("0.", "").lstrip("0")) for p in printed])
    half_digit = 0.5 * 10.0 ** (np.floor(np.log10(np.abs(printed))) - digits + 1)
    tolerance = np.maximum(1e-3 * np.abs(printed), half_digit)
    assert np.all(np.abs(value - printed) <= tolerance), (value, printed)


def test_gamma_s0_and_exponent_scale_to_four_digits() -> None:
    gamma = tunneling_decay_per_m(0.05)
    s0 = interparticle_separation_m(500e-9, 0.2873)
    assert float(gamma) == pytest.approx(2.2912e9, rel=5e-5)
    assert float(s0) == pytest.approx(110.74e-9, rel=5e-5)
    assert float(gamma * s0) == pytest.approx(253.7, rel=2e-4)


def test_gamma_by_hand() -> None:
    # 4 pi / h * sqrt(2 m phi), CODATA 2022 values written out (what scipy 1.15+ ships)
    h, m_e, q = 6.62607015e-34, 9.1093837139e-31, 1.602176634e-19
    expected = 4 * np.pi / h * np.sqrt(2 * m_e * 0.05 * q)
    assert float(tunneling_decay_per_m(0.05)) == pytest.approx(expected, rel=1e-12)


def test_spec_table_at_t0(paper: SensorModel) -> None:
    b = paper.held_step(FORCES_N, 0.0)
    _close_to_printed(b.total_ohm, SPEC_R_TOTAL_T0_OHM)
    _close_to_printed(b.contact_ohm / b.total_ohm, SPEC_CONTACT_SHARE)
    _close_to_printed(b.strain, SPEC_STRAIN_T0)


def test_spec_table_drop_after_600s_hold(paper: SensorModel) -> None:
    r0 = paper.held_step(FORCES_N, 0.0).total_ohm
    r600 = paper.held_step(FORCES_N, 600.0).total_ohm
    _close_to_printed(1.0 - r600 / r0, SPEC_DROP_600S)


def test_spec_table_naive_static_inversion_after_600s(paper: SensorModel) -> None:
    r600 = paper.held_step(FORCES_N, 600.0).total_ohm
    read = paper.invert_static(r600).force_n
    assert read[0] == pytest.approx(0.549, abs=0.0006)
    assert read[2] == pytest.approx(2.22, abs=0.006)
    assert read[3] == pytest.approx(5.64, abs=0.006)
    assert read[0] / 0.5 - 1 == pytest.approx(0.097, abs=0.0006)
    assert read[3] / 5.0 - 1 == pytest.approx(0.128, abs=0.0006)


def test_polymer_resistance_by_hand_at_half_newton() -> None:
    p = SensorParams()
    strain = 0.5 / (p.area_m2 * (p.e0_pa + p.e0_slope_pa_per_n * 0.5))
    gs0 = float(tunneling_decay_per_m(0.05) * interparticle_separation_m(500e-9, 0.2873))
    polymer = 200e3 * (1 - strain) * np.exp(-gs0 * strain)
    contact = (1.0 + 1.68e-8) / 2 * np.sqrt(np.pi * 30e6 / 0.5)
    b = SensorModel("tunneling,contact", p).breakdown(np.array([0.5]))
    assert float(b.polymer_ohm[0]) == pytest.approx(polymer, rel=1e-12)
    assert float(b.contact_ohm[0]) == pytest.approx(contact, rel=1e-12)
    assert float(b.total_ohm[0]) == pytest.approx(polymer + contact, rel=1e-12)


def test_contact_is_open_at_rest_not_nan() -> None:
    b = SensorModel("tunneling,contact", SensorParams()).breakdown(np.array([0.0, -1.0, 1.0]))
    assert np.isinf(b.contact_ohm[0]) and np.isinf(b.contact_ohm[1]) and np.isfinite(b.contact_ohm[2])
    assert np.isinf(b.total_ohm[:2]).all() and not np.isnan(b.total_ohm).any()
    # both contacts, eq. 12 by hand: 2 (rho1 + rho2)/4 sqrt(pi H / F)
    k = float(contact_coefficient_ohm_sqrt_n(1.68e-8, 1.0, 30e6))
    assert k == pytest.approx(2 * (1.0 + 1.68e-8) / 4 * np.sqrt(np.pi * 30e6), rel=1e-15)


def test_without_contact_unloaded_sensor_reads_r0() -> None:
    total = SensorModel("tunneling", SensorParams()).resistance(np.array([0.0]))
    assert float(total[0]) == pytest.approx(200e3, rel=1e-15)


def test_long_time_strain_limit() -> None:
    p = SensorParams()
    f = 3.0
    e0 = p.e0_pa + p.e0_slope_pa_per_n * f
    e1 = p.e1_pa + p.e1_slope_pa_per_n * f
    mu1 = p.mu1_pa_s + p.mu1_slope_pa_s_per_n * f
    assert float(kelvin_held_strain(f, 1e6, p.area_m2, e1, mu1)) == pytest.approx(
        f / (p.area_m2 * e1), rel=1e-12
    )
    assert float(kelvin_held_strain(f, 0.0, p.area_m2, e1, mu1)) == 0.0
    b = SensorModel("tunneling,creep", p).held_step(np.array([f]), 1e6)
    assert float(b.strain[0]) == pytest.approx(f / p.area_m2 * (1 / e0 + 1 / e1), rel=1e-12)


def test_kelvin_stepping_matches_closed_form_creep() -> None:
    p = SensorParams()
    f, dt = 4.0, 0.37
    e1 = p.e1_pa + p.e1_slope_pa_per_n * f
    mu1 = p.mu1_pa_s + p.mu1_slope_pa_s_per_n * f
    kv = 0.0
    for _ in range(1000):
        kv = float(kelvin_step(kv, f / p.area_m2, e1, mu1, dt))
    closed = f / (p.area_m2 * e1) * (1 - np.exp(-e1 * 1000 * dt / mu1))
    assert kv == pytest.approx(closed, rel=1e-12)


def test_simulated_hold_equals_eq17_closed_form() -> None:
    m = SensorModel("tunneling,contact,creep", [SensorParams()] * 3)
    t = np.arange(0.0, 600.0 + 1e-9, 0.1)
    forces = np.tile([0.5, 2.0, 5.0], (t.size, 1))
    simulated, _ = m.simulate(forces, t)
    closed = m.held_step(forces, t[:, None])
    np.testing.assert_allclose(simulated.total_ohm, closed.total_ohm, rtol=1e-12)


def test_resistance_strictly_falls_with_force() -> None:
    force = np.linspace(0.05, 10.0, 4000)
    for effects in ("tunneling", "tunneling,contact", "tunneling,contact,creep"):
        m = SensorModel(effects, SensorParams())
        r = m.resistance(force[:, None])[:, 0]
        assert np.all(np.diff(r) < 0), effects
        r600 = m.held_step(force[:, None], 600.0).total_ohm[:, 0]
        assert np.all(np.diff(r600) < 0), effects


def test_per_channel_parameters_are_vectorized() -> None:
    params = [SensorParams(r0_ohm=r) for r in (150e3, 200e3, 250e3)]
    many = SensorModel("tunneling,contact,creep", params).held_step(np.array([2.0, 2.0, 2.0]), 60.0)
    for i, p in enumerate(params):
        one = SensorModel("tunneling,contact,creep", p).held_step(np.array([2.0]), 60.0)
        assert float(many.total_ohm[i]) == pytest.approx(float(one.total_ohm[0]), rel=1e-14)
