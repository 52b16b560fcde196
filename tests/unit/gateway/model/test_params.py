"""Parameter validation and TOML round trip."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import pytest

from gateway.model import ChannelParams, ParameterError, SensorParams, parameter_names


def test_defaults_are_the_spec_values() -> None:
    p = SensorParams()
    assert (p.barrier_height_ev, p.particle_diameter_m, p.volume_fraction) == (0.05, 500e-9, 0.2873)
    assert (p.area_m2, p.r0_ohm, p.rho1_ohm_m, p.rho2_ohm_m, p.hardness_pa) == (
        1.9635e-5,
        200e3,
        1.68e-8,
        1.0,
        30e6,
    )
    assert (p.e0_pa, p.e0_slope_pa_per_n, p.e1_pa, p.e1_slope_pa_per_n) == (15e6, 1e6, 150e6, 10e6)
    assert (p.mu1_pa_s, p.mu1_slope_pa_s_per_n) == (1.5e10, 1e9)
    assert p.mu1_pa_s / p.e1_pa == pytest.approx(100.0)


@pytest.mark.parametrize(
    ("name", "value", "fragment"),
    [
        ("r0_ohm", -1.0, "r0_ohm = -1.0 is outside its allowed range (0, inf)"),
        ("r0_ohm", 0.0, "(0, inf)"),
        ("volume_fraction", 0.6, "volume_fraction = 0.6 is outside its allowed range (0, 0.523599)"),
        ("area_m2", math.nan, "area_m2 = nan is outside"),
        ("rho1_ohm_m", -0.1, "[0, inf)"),
        ("hysteresis_strain", 0.5, "[0, 0.1]"),
        ("temperature_coeff_per_k", 1.0, "[-0.2, 0.2]"),
        ("force_min_n", 0.0, "force_min_n = 0.0"),
    ],
)
def test_out_of_range_values_name_the_range(name: str, value: float, fragment: str) -> None:
    with pytest.raises(ParameterError) as info:
        SensorParams(**{name: value})
    assert fragment in str(info.value)


def test_non_numbers_are_refused() -> None:
    with pytest.raises(ParameterError, match="must be a number, got str"):
        SensorParams(r0_ohm="big")  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="must be a number, got bool"):
        SensorParams(r0_ohm=True)


def test_force_range_must_be_ordered() -> None:
    with pytest.raises(ParameterError, match=r"force_min_n \(6 N\) must be below force_max_n \(5 N\)"):
        SensorParams(force_min_n=6.0, force_max_n=5.0)


def test_unknown_name_suggests_the_closest() -> None:
    with pytest.raises(ParameterError, match="unknown sensor parameter 'r0_ohms'; did you mean 'r0_ohm'"):
        SensorParams().with_overrides({"r0_ohms": 1.0})


def test_toml_round_trip_is_exact() -> None:
    p = SensorParams(r0_ohm=123456.789, leakage_resistance_ohm=math.inf, e1_pa=1.234e8)
    text = p.to_toml("sensor.tip")
    assert text.startswith("[sensor.tip]\n")
    assert SensorParams.from_toml(text, "sensor.tip") == p


def test_toml_errors_are_clear() -> None:
    with pytest.raises(ParameterError, match="invalid TOML"):
        SensorParams.from_toml("r0_ohm = = 3")
    with pytest.raises(ParameterError, match=r"TOML has no table \[a.b\]"):
        SensorParams.from_toml("r0_ohm = 3.0", "a.b")
    with pytest.raises(ParameterError, match="outside its allowed range"):
        SensorParams.from_toml("r0_ohm = -3.0")


def test_channel_params_stack_and_unstack() -> None:
    ps = [SensorParams(r0_ohm=1e5), SensorParams(r0_ohm=2e5)]
    stacked = ChannelParams.stack(ps)
    assert stacked.n_channels == 2
    assert stacked.channel(1) == ps[1]
    assert set(parameter_names()) == set(stacked.__dataclass_fields__)
    with pytest.raises(ParameterError, match="at least one channel"):
        ChannelParams.stack([])


def test_replaced_is_dataclasses_replace_with_the_same_checks() -> None:
    base = SensorParams()
    new = base.replaced({"r0_ohm": 1e5, "e0_pa": 2e7, "series_resistance_ohm": 0})
    assert new == replace(base, r0_ohm=1e5, e0_pa=2e7, series_resistance_ohm=0)
    assert type(new.series_resistance_ohm) is float and base.r0_ohm == 200e3  # base untouched
    bads: list[dict[str, Any]] = [
        {"r0_ohm": -1.0},
        {"volume_fraction": math.pi / 6},
        {"e0_pa": "1"},
        {"e0_pa": True},
    ]
    for bad in bads:
        with pytest.raises(ParameterError) as want:
            replace(base, **bad)
        with pytest.raises(ParameterError) as got:
            base.replaced(bad)
        assert str(got.value) == str(want.value)
    with pytest.raises(ParameterError, match=r"force_min_n \(20 N\) must be below force_max_n \(10 N\)"):
        base.replaced({"force_min_n": 20.0})
    with pytest.raises(TypeError, match="r0"):
        base.replaced({"r0": 1.0})
