"""The built-in scenarios (``tactile-sim --scenario NAME``; listed in ``docs/scenarios.md``).

Each is a factory of a ``ScenarioSpec`` for a layout (``Scenario.builtin`` binds it): holds,
staircases, the paper's creep tests (2, 4, 6, 8 N), ramps, sines, load cycles, a probe
indenting tissue with a hard inclusion, a temperature step, and the discrepancy protocol.
Forces in N, times in s, temperatures in degC.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .profiles import ProfileBuilder
from .scenario_parts import ArrayLayout, Indentation, ScenarioSpec, TemperatureProgram, UniformLoad

_Factory = Callable[[ArrayLayout, str, str], ScenarioSpec]


def _uniform(builder: ProfileBuilder, repeat: bool = False) -> UniformLoad:
    return UniformLoad(builder.build(repeat=repeat))


def _idle(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    return ScenarioSpec(name, description=desc)


def _holds(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    b = ProfileBuilder(0.0).hold(10.0)
    for level in (0.5, 2.0, 5.0):
        b.hold(120.0, level)
    b.hold(60.0, 0.0)
    return ScenarioSpec(name, loads=[_uniform(b)], description=desc)


def _staircase(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    b = ProfileBuilder(0.0).hold(10.0)
    levels = [0.5 * k for k in range(1, 11)]
    for level in levels:
        b.hold(30.0, level)
    for level in reversed(levels[:-1]):
        b.hold(30.0, level)
    b.hold(30.0, 0.0)
    return ScenarioSpec(name, loads=[_uniform(b)], description=desc)


def _creep_test(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    # 600 s unloaded before the first hold too: a logger started after the device still sees
    # the unloaded sensor before the first step, so every step's onset lies between two samples
    b = ProfileBuilder(0.0).hold(600.0)
    for level in (2.0, 4.0, 6.0, 8.0):
        b.hold(600.0, level).hold(600.0, 0.0)
    return ScenarioSpec(name, loads=[_uniform(b)], description=desc)


def _ramps(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    b = ProfileBuilder(0.0).hold(5.0)
    for rate in (0.1, 0.5, 2.0):
        b.ramp(5.0, rate_per_s=rate).ramp(0.0, rate_per_s=rate).hold(20.0)
    return ScenarioSpec(name, loads=[_uniform(b)], description=desc)


def _sine(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    b = ProfileBuilder(0.0).ramp(2.0, duration_s=2.0).sine(1.5, 10.0, cycles=30).ramp(0.0, duration_s=2.0)
    return ScenarioSpec(name, loads=[_uniform(b)], description=desc, repeat=True)


def _cycles(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    b = ProfileBuilder(0.0)
    for _ in range(10):
        b.ramp(4.0, rate_per_s=1.0).hold(5.0).ramp(0.0, rate_per_s=1.0).hold(5.0)
    return ScenarioSpec(name, loads=[_uniform(b)], description=desc, repeat=True)


def builtin_indentation(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    cx, cy = layout.centre_mm
    p = layout.pitch_mm
    width = (layout.columns - 1) * p
    probe = Indentation(
        peak_force_n=3.0,
        start_mm=(-p, cy),
        end_mm=(width + p, cy),
        speed_mm_s=1.0,
        sigma_mm=max(0.8 * p, 0.5),
        inclusion_mm=(cx + 0.25 * p, cy),
        inclusion_sigma_mm=0.6 * p,
        inclusion_gain=1.0,
        press_s=2.0,
        rest_s=2.0,
        cell_area_mm2=p * p,
    )
    return ScenarioSpec(name, loads=[probe], description=desc, repeat=True)


def _temperature_step(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    load = ProfileBuilder(0.0).hold(5.0).hold(1500.0, 2.0).hold(60.0, 0.0)
    temp = ProfileBuilder(25.0).hold(605.0).ramp(35.0, rate_per_s=0.5).hold(400.0).ramp(25.0, rate_per_s=0.5)
    temp.hold(120.0)
    return ScenarioSpec(
        name,
        loads=[_uniform(load)],
        temperatures=[TemperatureProgram(temp.build())],
        description=desc,
    )


def _discrepancy(layout: ArrayLayout, name: str, desc: str) -> ScenarioSpec:
    b = ProfileBuilder(0.0).hold(10.0)
    # log-spaced static levels, each held then unloaded and held at zero (creep and recovery)
    for level in np.geomspace(0.2, 8.0, 7):
        b.hold(90.0, float(level)).hold(60.0, 0.0)
    # one long hold separates a slow second creep element from the first
    b.hold(1200.0, 4.0).hold(600.0, 0.0)
    # ramps at two rates (rate dependence, hysteresis)
    for rate in (0.05, 1.0):
        b.ramp(6.0, rate_per_s=rate).hold(10.0).ramp(0.0, rate_per_s=rate).hold(30.0)
    # repeated loading cycles (hysteresis loops)
    for _ in range(5):
        b.ramp(5.0, rate_per_s=0.5).hold(10.0).ramp(0.5, rate_per_s=0.5).hold(10.0)
    b.hold(60.0, 0.0)
    # a load held through a temperature step
    t_step = b.time_s + 300.0
    b.hold(1200.0, 2.0).hold(60.0, 0.0)
    temp = ProfileBuilder(25.0).hold(t_step).ramp(35.0, rate_per_s=0.5).hold(500.0).ramp(25.0, rate_per_s=0.5)
    temp.hold(max(0.0, b.time_s - temp.time_s))
    return ScenarioSpec(
        name,
        loads=[_uniform(b)],
        temperatures=[TemperatureProgram(temp.build())],
        description=desc,
    )


BUILTINS: dict[str, tuple[str, _Factory]] = {
    "idle": ("no load on any channel, 25 °C", _idle),
    "holds": (
        "all channels: 0 N for 10 s, holds at 0.5, 2 and 5 N (120 s each, steps between), then unload",
        _holds,
    ),
    "staircase": ("0.5 N steps up to 5 N and back down, 30 s per step", _staircase),
    "creep-test": (
        "the paper's creep tests: 2, 4, 6, 8 N each held 600 s, 600 s unloaded before each",
        _creep_test,
    ),
    "ramps": ("triangular ramps 0-5-0 N at 0.1, 0.5 and 2 N/s", _ramps),
    "sine": ("2 N +- 1.5 N sinusoid, 10 s period, repeating", _sine),
    "cycles": ("load cycles 0-4 N at 1 N/s with 5 s holds, repeating", _cycles),
    "indentation": (
        "a 3 N probe with a hard inclusion slides across the array along the middle row, repeating",
        builtin_indentation,
    ),
    "temperature-step": ("2 N held while the temperature steps 25 -> 35 -> 25 °C", _temperature_step),
    "discrepancy": (
        "log-spaced loads 0.2-8 N with unload holds, a long hold, two ramp rates, cycles and a "
        "temperature step",
        _discrepancy,
    ),
}
