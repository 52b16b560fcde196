"""Load scenarios: the true force on every channel, and its temperature, versus device time.

A ``Scenario`` is bound to an array layout (channel count, grid columns, pitch) and is
evaluated vectorized: ``force_n(t)`` and ``temperature_c(t)`` take device times in seconds,
shape (T,), and return arrays of shape (T, N) in newtons and degrees Celsius. Forces are
never negative (a sensor cannot be pulled) and are finite everywhere.

Building blocks
---------------
- ``Profile``: a piecewise signal of one quantity (force in N, or temperature in °C) built
  from holds, steps, ramps at a rate or over a duration, and sinusoids
  (``ProfileBuilder``). After its end a profile holds its final value, or repeats.
- ``UniformLoad``: a profile applied to a set of channels (all by default), times a gain.
  Loads are summed per channel.
- ``Indentation``: a probe pressing into soft tissue with a hard inclusion and sliding across
  the array. The contact pressure is a Gaussian of width ``sigma_mm`` around the probe
  centre, carrying the probe force F(t): ``p(x) = F / (2 pi sigma^2) exp(-|x - c(t)|^2 / (2
  sigma^2))``; above the inclusion the tissue is stiffer and the pressure rises by the factor
  ``1 + gain exp(-|x - x_inc|^2 / (2 s_inc^2))``. Each channel carries the pressure at its
  centre times its cell area (pitch^2), so the channel forces add up to about F.
- Temperature profiles apply to all channels or to a selection (a later one overrides an
  earlier one on its channels); the base temperature is 25 °C.
- Fault events (``[[fault]]``) are carried along for the device's ``FaultInjector``.

TOML format (see ``docs/scenarios.md``)
---------------------------------------
::

    name = "my-protocol"          # optional; defaults to the file name
    description = "one line"
    repeat = false                # loop the whole scenario after its duration
    base_temperature_c = 25.0

    [[load]]                      # summed per channel
    channels = "all"              # or a list of channel indices, e.g. [0, 1, 5]
    gain = 1.0
    initial_n = 0.0
    steps = [
      { hold_s = 10 },                          # hold the current force for 10 s
      { step_n = 0.5 },                         # jump to 0.5 N
      { hold_s = 120, force_n = 2.0 },          # jump to 2 N and hold 120 s
      { ramp_n = 5.0, rate_n_per_s = 0.5 },     # ramp at a rate ...
      { ramp_n = 0.0, duration_s = 4 },         # ... or over a duration
      { sine_amplitude_n = 1.0, period_s = 10, cycles = 3 },   # around the current force
    ]

    [[indentation]]
    force_n = 3.0                 # probe force
    start_mm = [-2.5, 3.75]       # probe path on the array (x along a row, y down columns)
    end_mm = [10.0, 3.75]
    speed_mm_s = 1.0
    sigma_mm = 2.0
    inclusion_mm = [3.75, 3.75]
    inclusion_sigma_mm = 1.5
    inclusion_gain = 1.0
    press_s = 2.0                 # time to press in at the start and to lift at the end
    rest_s = 2.0                  # unloaded time after lifting

    [[temperature]]
    channels = "all"
    initial_c = 25.0
    steps = [ { hold_s = 300 }, { ramp_c = 35.0, rate_c_per_s = 0.1 }, { hold_s = 600 } ]

    [[fault]]                     # device faults over device time
    at_s = 100.0
    until_s = 130.0               # optional: switch back off at this time
    channel = 3
    channel_mode = "open"         # "normal" | "open" | "short"
    # or any of: delay_s = 0.2, no_response = true, exception_code = 6, garble = true,
    # drop_connection = true

Errors name the file and the offending key, e.g. ``p.toml: load[0].steps[2].rate_n_per_s:
must be > 0, got -1``.
"""

from __future__ import annotations

import difflib
import tomllib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from .builtin_scenarios import BUILTINS
from .profiles import Profile, ProfileBuilder, ScenarioError
from .scenario_file import parse_scenario
from .scenario_parts import (
    DEFAULT_TEMPERATURE_C,
    FORCE_RANGE_N,
    TEMPERATURE_RANGE_C,
    VALID_EXCEPTION_CODES,
    ArrayLayout,
    FaultEvent,
    FloatArray,
    ForceSource,
    Indentation,
    ScenarioSpec,
    TemperatureProgram,
    UniformLoad,
    check_range,
)


# ------------------------------------------------------------------------- scenario
class Scenario:
    """True force (N) and temperature (°C) of every channel of one array versus device time."""

    def __init__(
        self,
        name: str,
        layout: ArrayLayout | None = None,
        *,
        loads: Sequence[ForceSource] = (),
        temperatures: Sequence[TemperatureProgram] = (),
        description: str = "",
        repeat: bool = False,
        base_temperature_c: float = DEFAULT_TEMPERATURE_C,
        faults: Sequence[FaultEvent] = (),
        duration_s: float | None = None,
        settled: bool = False,
    ) -> None:
        self.name = name
        #: the sensors have carried their t = 0 load long before the start (their creep has
        #: settled there), as on a rig that was loaded before the device was switched on
        self.settled = bool(settled)
        self.layout = layout or ArrayLayout()
        self.description = description
        self.loads = tuple(loads)
        self.temperatures = tuple(temperatures)
        self.repeat = repeat
        self.base_temperature_c = float(base_temperature_c)
        self.faults = tuple(faults)
        check_range("base_temperature_c", self.base_temperature_c, TEMPERATURE_RANGE_C)
        n = self.layout.channels
        for prog in (*self.loads, *self.temperatures):
            chans = getattr(prog, "channels", None)
            if chans is not None and any(not 0 <= c < n for c in chans):
                raise ScenarioError(f"scenario {name!r} names a channel outside 0..{n - 1}: {list(chans)}")
        natural = max(
            [0.0, *(p.duration_s for p in self.loads), *(p.profile.duration_s for p in self.temperatures)]
        )
        self.duration_s = float(duration_s) if duration_s is not None else natural
        self._positions = self.layout.positions_mm

    @property
    def n_channels(self) -> int:
        return self.layout.channels

    def _time(self, time_s: ArrayLike) -> FloatArray:
        t = np.atleast_1d(np.asarray(time_s, dtype=np.float64)).reshape(-1)
        if self.repeat and self.duration_s > 0.0:
            t = np.where(t >= 0.0, np.mod(t, self.duration_s), t)
        return t

    def force_n(self, time_s: ArrayLike) -> FloatArray:
        """True force of every channel at the given device times: shape (T, N), N >= 0."""
        t = self._time(time_s)
        out = np.zeros((t.shape[0], self.n_channels))
        for load in self.loads:
            out += load.force_n(t, self._positions)
        return np.maximum(out, 0.0)

    def temperature_c(self, time_s: ArrayLike) -> FloatArray:
        """Sensor temperature of every channel at the given device times: shape (T, N), °C."""
        t = self._time(time_s)
        out = np.full((t.shape[0], self.n_channels), self.base_temperature_c)
        for prog in self.temperatures:
            values = prog.profile(t)
            if prog.channels is None:
                out[:] = values[:, None]
            else:
                out[:, list(prog.channels)] = values[:, None]
        return out

    def with_layout(self, layout: ArrayLayout) -> Scenario:
        """The same scenario for another layout (only if it names no channel outside it)."""
        return Scenario(
            self.name,
            layout,
            loads=self.loads,
            temperatures=self.temperatures,
            description=self.description,
            repeat=self.repeat,
            base_temperature_c=self.base_temperature_c,
            faults=self.faults,
            duration_s=self.duration_s,
        )

    # ---------------------------------------------------------------- constructors
    @classmethod
    def from_spec(cls, spec: ScenarioSpec, layout: ArrayLayout | None = None) -> Scenario:
        """The scenario ``spec`` describes, on ``layout``."""
        return cls(
            spec.name,
            layout,
            loads=spec.loads,
            temperatures=spec.temperatures,
            description=spec.description,
            repeat=spec.repeat,
            base_temperature_c=spec.base_temperature_c,
            faults=spec.faults,
            settled=spec.settled,
        )

    @classmethod
    def builtin(cls, name: str, layout: ArrayLayout | None = None) -> Scenario:
        """A built-in scenario by name (see ``builtin_scenarios()``)."""
        if name not in BUILTINS:
            close = difflib.get_close_matches(name, list(BUILTINS), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ScenarioError(f"unknown scenario {name!r}{hint} (built-ins: {', '.join(BUILTINS)})")
        description, factory = BUILTINS[name]
        layout = layout or ArrayLayout()
        return cls.from_spec(factory(layout, name, description), layout)

    @classmethod
    def from_file(cls, path: str | Path, layout: ArrayLayout | None = None) -> Scenario:
        """Load a TOML scenario file (format in the module docstring)."""
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise ScenarioError(f"{p}: cannot read scenario file: {exc.strerror or exc}") from exc
        return cls.from_toml(text, layout, source=str(p), default_name=p.stem)

    @classmethod
    def from_toml(
        cls,
        text: str,
        layout: ArrayLayout | None = None,
        *,
        source: str = "<toml>",
        default_name: str = "custom",
    ) -> Scenario:
        """Parse scenario TOML text; ``source`` names it in error messages."""
        try:
            data = tomllib.loads(text.removeprefix("\ufeff"))
        except RecursionError:
            raise ScenarioError(
                f"{source}: invalid TOML: arrays or inline tables nested too deeply"
            ) from None
        except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
            raise ScenarioError(f"{source}: invalid TOML: {str(exc).split(';')[0]}") from None
        layout = layout or ArrayLayout()
        return cls.from_spec(parse_scenario(data, layout, source, default_name), layout)

    @classmethod
    def load(cls, spec: str | Path, layout: ArrayLayout | None = None) -> Scenario:
        """A built-in name, or the path of a TOML file (anything ending in .toml or existing)."""
        text = str(spec)
        if isinstance(spec, Path) or text.endswith(".toml") or Path(text).is_file():
            return cls.from_file(text, layout)
        return cls.builtin(text, layout)

    @classmethod
    def constant(
        cls,
        force_n: float,
        layout: ArrayLayout | None = None,
        temperature_c: float = 25.0,
        settled: bool = False,
    ) -> Scenario:
        """Every channel held at ``force_n`` from t = 0 (handy for tests); ``settled``: held
        long before t = 0 already."""
        check_range("force_n", force_n, FORCE_RANGE_N)
        profile = ProfileBuilder(force_n).build()
        return cls(
            f"constant-{force_n:g}N",
            layout,
            loads=[UniformLoad(profile)],
            description=f"all channels held at {force_n:g} N",
            base_temperature_c=temperature_c,
            settled=settled,
        )

    def __repr__(self) -> str:
        return f"Scenario({self.name!r}, channels={self.n_channels}, duration_s={self.duration_s:g})"


def builtin_scenarios() -> dict[str, str]:
    """Built-in scenario names with a one-line description each."""
    return {name: desc for name, (desc, _factory) in BUILTINS.items()}


__all__ = [
    "DEFAULT_TEMPERATURE_C",
    "FORCE_RANGE_N",
    "TEMPERATURE_RANGE_C",
    "VALID_EXCEPTION_CODES",
    "ArrayLayout",
    "FaultEvent",
    "FloatArray",
    "ForceSource",
    "Indentation",
    "Profile",
    "ProfileBuilder",
    "Scenario",
    "ScenarioError",
    "ScenarioSpec",
    "TemperatureProgram",
    "UniformLoad",
    "builtin_scenarios",
    "check_range",
]
