"""Effects are named, switchable terms with an exact off form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway.model import (
    EFFECT_NAMES,
    PAPER_EFFECTS,
    SensorModel,
    SensorParams,
    UnknownEffectError,
    parse_effects,
)


def test_names_are_the_spec_names_in_order() -> None:
    assert EFFECT_NAMES == (
        "tunneling",
        "contact",
        "creep",
        "creep2",
        "hysteresis",
        "temperature",
        "series_resistance",
        "leakage",
    )


def test_parse_adds_tunneling_and_orders() -> None:
    assert parse_effects("creep, contact") == ("tunneling", "contact", "creep")
    assert parse_effects([]) == ("tunneling",)


@pytest.mark.parametrize(
    ("typo", "suggestion"), [("contcat", "contact"), ("creeep", "creep"), ("leak", "leakage")]
)
def test_unknown_effect_suggests_closest(typo: str, suggestion: str) -> None:
    with pytest.raises(UnknownEffectError, match=f"unknown effect '{typo}'; did you mean '{suggestion}'"):
        parse_effects(f"tunneling,{typo}")


def test_off_forms_reduce_exactly_to_the_baseline() -> None:
    force = np.linspace(0.1, 8.0, 50)[:, None]
    base = SensorModel("tunneling,contact,creep", SensorParams()).resistance(force)
    neutral = SensorParams(
        series_resistance_ohm=0.0,
        leakage_resistance_ohm=math.inf,
        temperature_coeff_per_k=0.0,
        hysteresis_strain=0.0,
    )
    everything = SensorModel(EFFECT_NAMES, neutral).resistance(force, temperature_c=60.0)
    np.testing.assert_allclose(everything, base, rtol=1e-14)


def test_series_and_leakage_by_hand() -> None:
    force = np.array([2.0])
    p = SensorParams(series_resistance_ohm=1000.0, leakage_resistance_ohm=1e6)
    core = SensorModel("tunneling,contact", p).resistance(force)[0]
    series = SensorModel("tunneling,contact,series_resistance", p).resistance(force)[0]
    both = SensorModel("tunneling,contact,series_resistance,leakage", p).resistance(force)[0]
    assert series == pytest.approx(core + 1000.0, rel=1e-14)
    assert both == pytest.approx((core + 1000.0) * 1e6 / (core + 1000.0 + 1e6), rel=1e-14)
    open_ = SensorModel("tunneling,contact,leakage", p).resistance(np.array([0.0]))[0]
    assert open_ == pytest.approx(1e6)


def test_temperature_scales_polymer_only() -> None:
    p = SensorParams(temperature_coeff_per_k=-0.01, reference_temperature_c=25.0)
    m = SensorModel("tunneling,contact,temperature", p)
    hot = m.breakdown(np.array([2.0]), temperature_c=35.0)
    ref = m.breakdown(np.array([2.0]), temperature_c=25.0)
    assert hot.polymer_ohm[0] == pytest.approx(ref.polymer_ohm[0] * math.exp(-0.1), rel=1e-14)
    assert hot.contact_ohm[0] == ref.contact_ohm[0]


def test_creep2_adds_a_slower_element() -> None:
    p = SensorParams()
    one = SensorModel("tunneling,creep", p).held_step(np.array([2.0]), 600.0)
    two = SensorModel("tunneling,creep,creep2", p).held_step(np.array([2.0]), 600.0)
    extra = 2.0 / (p.area_m2 * p.e2_pa) * (1 - math.exp(-p.e2_pa * 600.0 / p.mu2_pa_s))
    assert two.strain[0] - one.strain[0] == pytest.approx(extra, rel=1e-12)


def test_hysteresis_loading_reads_higher_than_unloading() -> None:
    m = SensorModel("tunneling,contact,hysteresis", SensorParams(hysteresis_strain=5e-4))
    up = np.linspace(0.2, 4.0, 40)
    path = np.concatenate([up, up[::-1]])
    out, _ = m.simulate(path[:, None], np.arange(path.size, dtype=float))
    r = out.total_ohm[:, 0]
    loading, unloading = r[:40], r[40:][::-1]
    # same force, two branches: loading has the lower strain and so the higher resistance
    assert np.all(loading[5:-5] > unloading[5:-5])


def test_the_effect_table_has_both_forms_of_every_contract_effect() -> None:
    from gateway.model import EFFECTS
    from gateway.model.submodels import Submodel

    assert tuple(EFFECTS) == EFFECT_NAMES
    for name, (on, off) in EFFECTS.items():
        assert issubclass(on, Submodel) and on.effect == name and on.active
        if name == "tunneling":
            assert off is None  # the baseline cannot be switched off
            continue
        assert off is not None and off.__bases__ == on.__bases__ and off.effect == name and not off.active


@pytest.mark.parametrize("effect", [e for e in EFFECT_NAMES if e != "tunneling"])
def test_each_effect_switched_off_is_the_model_without_it(effect: str) -> None:
    """Switching one effect on with neutral parameters leaves every output unchanged."""
    neutral = {
        "contact": {"rho1_ohm_m": 0.0, "rho2_ohm_m": 0.0},
        "creep": {"e1_slope_pa_per_n": 0.0, "mu1_pa_s": 1e30},
        "creep2": {"mu2_pa_s": 1e30},
        "hysteresis": {"hysteresis_strain": 0.0},
        "temperature": {"temperature_coeff_per_k": 0.0},
        "series_resistance": {"series_resistance_ohm": 0.0},
        "leakage": {"leakage_resistance_ohm": math.inf},
    }[effect]
    p = SensorParams(**neutral)
    t = np.arange(0.0, 50.0, 0.5)
    force = (2.0 + np.sin(t / 5.0))[:, None]
    without = SensorModel("tunneling", p).simulate(force, t, temperature_c=40.0)[0].total_ohm
    with_it = SensorModel(["tunneling", effect], p).simulate(force, t, temperature_c=40.0)[0].total_ohm
    np.testing.assert_allclose(with_it, without, rtol=1e-12)


def test_breakdown_lists_every_term_by_hand() -> None:
    """(T R_pol + 2 R_con + R_series) || R_leak with the strains of each effect, at 2 N and 40 degC
    after a 100 s hold, worked out from the closed forms."""
    p = SensorParams()
    f, t = 2.0, 100.0
    m = SensorModel(EFFECT_NAMES, p)
    b = m.held_step(np.array([f]), t, temperature_c=40.0)
    elastic = f / (p.area_m2 * (p.e0_pa + p.e0_slope_pa_per_n * f))
    e1, mu1 = p.e1_pa + p.e1_slope_pa_per_n * f, p.mu1_pa_s + p.mu1_slope_pa_s_per_n * f
    kv1 = f / (p.area_m2 * e1) * (1 - math.exp(-e1 * t / mu1))
    kv2 = f / (p.area_m2 * p.e2_pa) * (1 - math.exp(-p.e2_pa * t / p.mu2_pa_s))
    travel = f - 0.1 * p.hysteresis_force_n  # the play's dead band is a tenth of F_h
    hyst = -p.hysteresis_strain * (1 - math.exp(-travel / p.hysteresis_force_n))
    factor = math.exp(p.temperature_coeff_per_k * (40.0 - p.reference_temperature_c))
    strain = elastic + kv1 + kv2 + hyst
    gs0 = float(m.gamma_s0()[0])
    polymer = factor * p.r0_ohm * (1 - strain) * math.exp(-gs0 * strain)
    contact = (p.rho1_ohm_m + p.rho2_ohm_m) / 2 * math.sqrt(math.pi * p.hardness_pa / f)
    core = polymer + contact + p.series_resistance_ohm
    total = core * p.leakage_resistance_ohm / (core + p.leakage_resistance_ohm)
    expected = {
        "elastic_strain": elastic,
        "kv1_strain": kv1,
        "kv2_strain": kv2,
        "hysteresis_strain": hyst,
        "strain": strain,
        "temperature_factor": factor,
        "polymer_ohm": polymer,
        "contact_ohm": contact,
        "series_ohm": p.series_resistance_ohm,
        "leakage_ohm": p.leakage_resistance_ohm,
        "total_ohm": total,
    }
    got = b.components()
    assert set(got) == set(expected)
    for name, value in expected.items():
        assert float(got[name][0]) == pytest.approx(value, rel=1e-12), name


def test_breakdown_of_an_effect_that_is_off_is_its_neutral_term() -> None:
    b = SensorModel(PAPER_EFFECTS, SensorParams()).held_step(np.array([1.0]), 10.0, temperature_c=80.0)
    assert b.series_ohm[0] == 0.0 and np.isinf(b.leakage_ohm[0]) and b.temperature_factor[0] == 1.0
    assert b.kv2_strain[0] == 0.0 and b.hysteresis_strain[0] == 0.0 and b.kv1_strain[0] > 0.0
