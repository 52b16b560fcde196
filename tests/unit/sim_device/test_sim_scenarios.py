"""Scenarios: built-ins, profiles, indentation geometry, TOML loading and its errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim_device import ArrayLayout, ProfileBuilder, Scenario, ScenarioError, builtin_scenarios
from sim_device.scenarios import FORCE_RANGE_N, TEMPERATURE_RANGE_C, Indentation

LAYOUT = ArrayLayout(channels=16, columns=4, pitch_mm=2.5)


@pytest.mark.parametrize("name", list(builtin_scenarios()))
def test_builtin_is_finite_and_in_range(name: str) -> None:
    scenario = Scenario.builtin(name, LAYOUT)
    end = max(scenario.duration_s, 10.0) * 1.2
    t = np.linspace(-1.0, end, 20001)
    force = scenario.force_n(t)
    temp = scenario.temperature_c(t)
    assert force.shape == (t.size, 16) and temp.shape == (t.size, 16)
    assert np.isfinite(force).all() and np.isfinite(temp).all()
    assert force.min() >= FORCE_RANGE_N[0] and force.max() <= FORCE_RANGE_N[1]
    assert temp.min() >= TEMPERATURE_RANGE_C[0] and temp.max() <= TEMPERATURE_RANGE_C[1]
    assert builtin_scenarios()[name] == scenario.description and "\n" not in scenario.description
    if name != "idle":
        assert force.max() > 0.5, "a loading scenario must load the array"


def test_builtin_list_has_the_required_names() -> None:
    required = {"idle", "holds", "staircase", "creep-test", "ramps", "sine", "cycles", "indentation",
                "temperature-step", "discrepancy"}  # fmt: skip
    assert required <= set(builtin_scenarios())


def test_holds_schedule() -> None:
    s = Scenario.builtin("holds", LAYOUT)
    t = np.array([0.0, 9.9, 10.0, 60.0, 129.9, 130.0, 249.9, 250.0, 369.9, 370.0, 400.0, 1e5])
    f = s.force_n(t)[:, 0]
    np.testing.assert_allclose(f, [0, 0, 0.5, 0.5, 0.5, 2, 2, 5, 5, 0, 0, 0])
    assert np.ptp(s.force_n(t), axis=1).max() == 0.0, "all channels carry the same load"


def test_creep_test_holds_the_paper_forces() -> None:
    s = Scenario.builtin("creep-test", LAYOUT)
    levels = s.force_n(600.0 + 1200.0 * np.arange(4) + 300.0)[:, 0]
    np.testing.assert_allclose(levels, [2.0, 4.0, 6.0, 8.0])
    # unloaded for 600 s before each hold, the first included
    np.testing.assert_allclose(s.force_n(np.array([0.0, 599.9, 1200.1, 1799.9, 5399.9]))[:, 0], 0.0)
    assert s.duration_s == pytest.approx(600.0 + 4 * 1200.0)


def test_discrepancy_is_rich() -> None:
    s = Scenario.builtin("discrepancy", LAYOUT)
    t = np.arange(0.0, s.duration_s, 0.5)
    f = s.force_n(t)[:, 0]
    temp = s.temperature_c(t)[:, 0]
    levels, counts = np.unique(f, return_counts=True)
    held = levels[(counts >= 100) & (levels > 0)]
    assert held.min() == pytest.approx(0.2) and held.max() == pytest.approx(8.0)
    assert len(held) >= 7, "log-spaced static levels"
    rates = np.abs(np.diff(f)) / 0.5
    assert ((rates > 0.03) & (rates < 0.08)).sum() > 50 and ((rates > 0.8) & (rates < 1.2)).sum() > 5
    assert temp.max() == pytest.approx(35.0) and temp.min() == pytest.approx(25.0)


def test_profile_builder_pieces() -> None:
    p = (
        ProfileBuilder(1.0)
        .hold(2.0)
        .step(3.0)
        .ramp(5.0, rate_per_s=1.0)
        .ramp(1.0, duration_s=2.0)
        .sine(2.0, 4.0, cycles=1)
        .build()
    )
    t = np.array([-1.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 100.0])
    np.testing.assert_allclose(p(t), [1, 1, 3, 4, 5, 3, 1, 3, 1, -1, 1], atol=1e-12)
    assert p.duration_s == pytest.approx(10.0)
    rep = ProfileBuilder(0.0).ramp(1.0, duration_s=1.0).build(repeat=True)
    np.testing.assert_allclose(rep(np.array([0.5, 1.5, 2.25])), [0.5, 0.5, 0.25])


def test_profile_builder_rejects_bad_ramps() -> None:
    with pytest.raises(ScenarioError, match="rate"):
        ProfileBuilder().ramp(1.0, rate_per_s=0.0)
    with pytest.raises(ScenarioError, match="exactly one"):
        ProfileBuilder().ramp(1.0)
    with pytest.raises(ScenarioError, match="duration"):
        ProfileBuilder().hold(-1.0)


def test_indentation_carries_the_probe_force_and_the_inclusion_bump() -> None:
    layout = ArrayLayout(channels=256, columns=16, pitch_mm=0.5)
    probe = {"peak_force_n": 2.0, "start_mm": (3.75, 3.75), "end_mm": (3.76, 3.75), "sigma_mm": 1.0,
             "cell_area_mm2": 0.25, "press_s": 1.0}  # fmt: skip
    flat = Indentation(inclusion_gain=0.0, **probe)  # type: ignore[arg-type]
    f = flat.force_n(np.array([1.0]), layout.positions_mm)
    assert f.sum() == pytest.approx(2.0, rel=0.01)
    bumpy = Indentation(inclusion_mm=(3.75, 3.75), inclusion_gain=1.0, **probe)  # type: ignore[arg-type]
    g = bumpy.force_n(np.array([1.0]), layout.positions_mm)
    centre = int(np.argmax(g[0]))
    assert g[0, centre] == pytest.approx(2.0 * f[0, centre], rel=0.05)


def test_indentation_slides_across_the_row() -> None:
    s = Scenario.builtin("indentation", LAYOUT)
    probe = s.loads[0]
    assert isinstance(probe, Indentation)
    times = np.linspace(probe.press_s, probe.press_s + probe.travel_s, 50)
    peak_channel = np.argmax(s.force_n(times), axis=1)
    columns = peak_channel % LAYOUT.columns
    assert columns[0] == 0 and columns[-1] == LAYOUT.columns - 1
    assert np.all(np.diff(columns) >= 0), "the peak moves along the row"


GOOD_TOML = """
name = "mine"
description = "a custom protocol"
base_temperature_c = 22.0

[[load]]
channels = [0, 1]
steps = [
  { hold_s = 5 },
  { hold_s = 10, force_n = 2.0 },
  { ramp_n = 4.0, rate_n_per_s = 1.0 },
  { sine_amplitude_n = 1.0, period_s = 4, cycles = 2 },
  { step_n = 0.0 },
]

[[load]]
gain = 0.5
initial_n = 1.0

[[indentation]]
force_n = 1.0

[[temperature]]
channels = "all"
steps = [ { hold_s = 10 }, { ramp_c = 30, duration_s = 5 } ]

[[fault]]
at_s = 3
until_s = 4
channel = 2
channel_mode = "short"

[[fault]]
at_s = 5
exception_code = 6
"""


def test_toml_scenario_loads(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text(GOOD_TOML)
    s = Scenario.load(str(path), LAYOUT)
    assert s.name == "mine" and s.description == "a custom protocol"
    f = s.force_n(np.array([1.0, 6.0, 16.0, 17.0]))
    assert f[1, 0] == pytest.approx(2.5, abs=0.05)  # 2 N load plus 0.5 x 1 N
    assert f[1, 15] == pytest.approx(0.5, abs=0.01)  # far from the probe path
    assert f[2, 0] > f[1, 0]
    temp = s.temperature_c(np.array([0.0, 12.5, 100.0]))
    np.testing.assert_allclose(temp[:, 0], [22.0, 26.0, 30.0])
    assert len(s.faults) == 2 and s.faults[0].channel == 2 and s.faults[1].changes == {"exception_code": 6}


@pytest.mark.parametrize(
    ("text", "key", "message"),
    [
        ("[[load]]\nsteps = [{ ramp_n = 3, rate_n_per_s = -1 }]\n", "load[0].steps[0].rate_n_per_s", "> 0"),
        ("[[load]]\nsteps = [{ hold_s = 3, forse_n = 1 }]\n", "load[0].steps[0].forse_n", "force_n"),
        ("[[load]]\nchannels = [99]\n", "load[0].channels", "0..15"),
        ("[[load]]\nsteps = [{ hold_s = 1, force_n = 500 }]\n", "load[0].steps[0]", "outside"),
        ("[[load]]\nsteps = [{ hold_s = 1, step_n = 1 }]\n", "load[0].steps[0]", "exactly one"),
        ("[[temperature]]\nsteps = [{ ramp_c = 30 }]\n", "temperature[0].steps[0]", "rate_c_per_s"),
        ("[[fault]]\nat_s = 1\nexception_code = 99\n", "fault[0].exception_code", "exception code"),
        ("[[fault]]\nat_s = 1\nchannel_mode = 'open'\n", "fault[0].channel", "channel"),
        ("[[indentation]]\nsigma_mm = 0\n", "indentation[0].sigma_mm", "> 0"),
        ("lod = 1\n", "lod", "load"),
        ("repeat = 'yes'\n", "repeat", "true or false"),
    ],
)
def test_toml_errors_name_file_and_key(tmp_path: Path, text: str, key: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        Scenario.from_file(path, LAYOUT)
    text_of_error = str(info.value)
    assert text_of_error.startswith(f"{path}: {key}")
    assert message in text_of_error


def test_toml_syntax_error_and_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("[[load]\n")
    with pytest.raises(ScenarioError, match=r"broken\.toml: invalid TOML"):
        Scenario.from_file(path, LAYOUT)
    with pytest.raises(ScenarioError, match=r"missing\.toml: cannot read"):
        Scenario.load(str(tmp_path / "missing.toml"), LAYOUT)


def test_unknown_builtin_suggests() -> None:
    with pytest.raises(ScenarioError, match="did you mean 'holds'"):
        Scenario.builtin("hold", LAYOUT)


def test_constant_and_repeat() -> None:
    s = Scenario.constant(1.5, LAYOUT)
    assert np.all(s.force_n(np.array([0.0, 1e6])) == 1.5)
    sine = Scenario.builtin("sine", LAYOUT)
    t = np.array([5.0, 7.3])
    np.testing.assert_allclose(sine.force_n(t), sine.force_n(t + sine.duration_s))
