"""Effects are named, switchable terms with an exact off form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway.model import EFFECT_NAMES, SensorModel, SensorParams, UnknownEffectError, parse_effects


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
