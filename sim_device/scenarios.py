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
import math
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Forces a scenario may ask for (N) and temperatures (°C); beyond them is an error.
FORCE_RANGE_N = (0.0, 50.0)
TEMPERATURE_RANGE_C = (-40.0, 150.0)
DEFAULT_TEMPERATURE_C = 25.0


class ScenarioError(ValueError):
    """A scenario that cannot be built: unknown name, bad file, or a value out of range."""


# --------------------------------------------------------------------------- layout
@dataclass(frozen=True)
class ArrayLayout:
    """Geometry of the array: ``channels`` sensors on a grid of ``columns``, ``pitch_mm`` apart.

    Channel i sits at column ``i % columns`` and row ``i // columns``; its centre is at
    ``x = column * pitch_mm``, ``y = row * pitch_mm`` (millimetres).
    """

    channels: int = 16
    columns: int = 4
    pitch_mm: float = 2.5

    def __post_init__(self) -> None:
        if not (isinstance(self.channels, int) and 1 <= self.channels <= 256):
            raise ScenarioError(f"channels = {self.channels!r} must be an integer in 1..256")
        if not (isinstance(self.columns, int) and 1 <= self.columns <= self.channels):
            raise ScenarioError(f"columns = {self.columns!r} must be an integer in 1..channels")
        if not (math.isfinite(self.pitch_mm) and self.pitch_mm > 0.0):
            raise ScenarioError(f"pitch_mm = {self.pitch_mm!r} must be > 0")

    @property
    def rows(self) -> int:
        return -(-self.channels // self.columns)

    @property
    def positions_mm(self) -> FloatArray:
        """Channel centres, shape (N, 2): x along a row, y down the columns (mm)."""
        idx = np.arange(self.channels)
        return np.stack([(idx % self.columns) * self.pitch_mm, (idx // self.columns) * self.pitch_mm], axis=1)

    @property
    def centre_mm(self) -> tuple[float, float]:
        return ((self.columns - 1) * self.pitch_mm / 2.0, (self.rows - 1) * self.pitch_mm / 2.0)


# -------------------------------------------------------------------------- profiles
_LINEAR = 0
_SINE = 1


@dataclass(frozen=True)
class Profile:
    """A piecewise signal: contiguous pieces, each linear (v0 -> v1) or a sinusoid.

    A sine piece is ``v0 + v1 * sin(2 pi (t - start) / period)``. Before the first piece the
    signal is ``initial``; after the last it holds ``final`` (or repeats when ``repeat``).
    """

    starts_s: FloatArray
    durations_s: FloatArray
    kinds: NDArray[np.int8]
    v0: FloatArray
    v1: FloatArray
    periods_s: FloatArray
    initial: float
    final: float
    repeat: bool = False

    @property
    def duration_s(self) -> float:
        if self.starts_s.size == 0:
            return 0.0
        return float(self.starts_s[-1] + self.durations_s[-1])

    def __call__(self, time_s: ArrayLike) -> FloatArray:
        t = np.asarray(time_s, dtype=np.float64)
        total = self.duration_s
        if self.starts_s.size == 0 or total <= 0.0:
            return np.full(t.shape, self.final)
        if self.repeat:
            t = np.where(t >= 0.0, np.mod(t, total), t)
        idx = np.searchsorted(self.starts_s, t, side="right") - 1
        safe = np.clip(idx, 0, self.starts_s.size - 1)
        local = t - self.starts_s[safe]
        dur = self.durations_s[safe]
        frac = np.clip(local / dur, 0.0, 1.0)
        v0, v1 = self.v0[safe], self.v1[safe]
        linear = v0 + (v1 - v0) * frac
        sine = v0 + v1 * np.sin(2.0 * np.pi * local / self.periods_s[safe])
        out = np.where(self.kinds[safe] == _SINE, sine, linear)
        out = np.where(idx < 0, self.initial, out)
        return np.asarray(np.where(t >= total, self.final, out), dtype=np.float64)


class ProfileBuilder:
    """Build a ``Profile`` step by step; every method returns the builder.

    Values are in the profile's unit (N for loads, °C for temperatures); times in seconds.
    """

    def __init__(self, initial: float = 0.0) -> None:
        self._initial = float(initial)
        self._value = float(initial)
        self._t = 0.0
        self._pieces: list[tuple[float, float, int, float, float, float]] = []

    @property
    def value(self) -> float:
        """The value at the current end of the profile."""
        return self._value

    @property
    def time_s(self) -> float:
        return self._t

    def step(self, value: float) -> ProfileBuilder:
        """Jump to ``value`` (a discontinuity; takes no time)."""
        self._value = float(value)
        return self

    def hold(self, duration_s: float, value: float | None = None) -> ProfileBuilder:
        """Jump to ``value`` if given, then hold for ``duration_s``."""
        if value is not None:
            self.step(value)
        _check_duration(duration_s)
        if duration_s > 0.0:
            self._add(duration_s, _LINEAR, self._value, self._value, 1.0)
        return self

    def ramp(
        self, value: float, *, rate_per_s: float | None = None, duration_s: float | None = None
    ) -> ProfileBuilder:
        """Ramp linearly to ``value`` at ``rate_per_s`` (> 0) or over ``duration_s``."""
        if (rate_per_s is None) == (duration_s is None):
            raise ScenarioError("a ramp needs exactly one of a rate or a duration")
        if rate_per_s is not None:
            if not (math.isfinite(rate_per_s) and rate_per_s > 0.0):
                raise ScenarioError(f"ramp rate must be > 0, got {rate_per_s!r}")
            duration_s = abs(float(value) - self._value) / rate_per_s
        assert duration_s is not None
        _check_duration(duration_s)
        if duration_s > 0.0:
            self._add(duration_s, _LINEAR, self._value, float(value), 1.0)
        self._value = float(value)
        return self

    def sine(
        self,
        amplitude: float,
        period_s: float,
        *,
        cycles: float | None = None,
        duration_s: float | None = None,
    ) -> ProfileBuilder:
        """A sinusoid of ``amplitude`` around the current value, for ``cycles`` or ``duration_s``.

        Starts at the current value going up; after whole cycles it ends where it started.
        """
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ScenarioError(f"sine period must be > 0, got {period_s!r}")
        if (cycles is None) == (duration_s is None):
            raise ScenarioError("a sine needs exactly one of cycles or a duration")
        length = float(cycles) * period_s if cycles is not None else float(duration_s or 0.0)
        _check_duration(length)
        if length > 0.0:
            self._add(length, _SINE, self._value, float(amplitude), float(period_s))
            self._value = self._value + float(amplitude) * math.sin(2.0 * math.pi * length / period_s)
        return self

    def _add(self, duration_s: float, kind: int, v0: float, v1: float, period_s: float) -> None:
        self._pieces.append((self._t, float(duration_s), kind, v0, v1, period_s))
        self._t += float(duration_s)

    def values_range(self) -> tuple[float, float]:
        """Lowest and highest value the profile reaches."""
        lo = hi = self._initial
        for _start, _dur, kind, v0, v1, _p in self._pieces:
            if kind == _SINE:
                lo, hi = min(lo, v0 - abs(v1)), max(hi, v0 + abs(v1))
            else:
                lo, hi = min(lo, v0, v1), max(hi, v0, v1)
        return min(lo, self._value), max(hi, self._value)

    def build(self, repeat: bool = False) -> Profile:
        cols = list(zip(*self._pieces, strict=True)) if self._pieces else [()] * 6
        return Profile(
            starts_s=np.asarray(cols[0], dtype=np.float64),
            durations_s=np.asarray(cols[1], dtype=np.float64),
            kinds=np.asarray(cols[2], dtype=np.int8),
            v0=np.asarray(cols[3], dtype=np.float64),
            v1=np.asarray(cols[4], dtype=np.float64),
            periods_s=np.asarray(cols[5], dtype=np.float64),
            initial=self._initial,
            final=self._value,
            repeat=repeat,
        )


def _check_duration(duration_s: float | None) -> None:
    if duration_s is None or not (math.isfinite(duration_s) and duration_s >= 0.0):
        raise ScenarioError(f"duration must be a finite number >= 0 s, got {duration_s!r}")


# ---------------------------------------------------------------------- force sources
class ForceSource(Protocol):
    """Anything that adds force (N) to channels: ``force_n(t, positions_mm) -> (T, N)``."""

    @property
    def duration_s(self) -> float: ...

    def force_n(self, time_s: FloatArray, positions_mm: FloatArray) -> FloatArray: ...


@dataclass(frozen=True)
class UniformLoad:
    """The same force profile (N) on a set of channels (``None``: all), times ``gain``."""

    profile: Profile
    channels: tuple[int, ...] | None = None
    gain: float = 1.0

    @property
    def duration_s(self) -> float:
        return self.profile.duration_s

    def force_n(self, time_s: FloatArray, positions_mm: FloatArray) -> FloatArray:
        n = positions_mm.shape[0]
        values = self.gain * self.profile(time_s)
        out = np.zeros((time_s.shape[0], n))
        if self.channels is None:
            out[:] = values[:, None]
        else:
            out[:, list(self.channels)] = values[:, None]
        return out


@dataclass(frozen=True)
class Indentation:
    """A probe pressing into soft tissue with a hard inclusion, sliding across the array.

    Timeline: press in over ``press_s`` at ``start_mm`` (force ramps 0 -> ``peak_force_n``), slide
    to ``end_mm`` at ``speed_mm_s``, lift over ``press_s``, rest ``rest_s`` unloaded. Pressure
    is Gaussian around the probe centre (``sigma_mm``), raised by ``1 + inclusion_gain *
    exp(-d_inc^2 / (2 inclusion_sigma_mm^2))`` over the inclusion; a channel carries the
    pressure at its centre times ``cell_area_mm2`` (default pitch^2, set by the scenario).
    """

    peak_force_n: float = 3.0
    start_mm: tuple[float, float] = (-2.5, 3.75)
    end_mm: tuple[float, float] = (10.0, 3.75)
    speed_mm_s: float = 1.0
    sigma_mm: float = 2.0
    inclusion_mm: tuple[float, float] = (3.75, 3.75)
    inclusion_sigma_mm: float = 1.5
    inclusion_gain: float = 1.0
    press_s: float = 2.0
    rest_s: float = 2.0
    cell_area_mm2: float = 6.25
    repeat: bool = False

    def __post_init__(self) -> None:
        for name in ("speed_mm_s", "sigma_mm", "inclusion_sigma_mm", "cell_area_mm2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ScenarioError(f"{name} must be > 0, got {value!r}")
        for name in ("press_s", "rest_s", "inclusion_gain"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ScenarioError(f"{name} must be >= 0, got {value!r}")
        _check_range("peak_force_n", self.peak_force_n, FORCE_RANGE_N)

    @property
    def travel_s(self) -> float:
        dx = np.subtract(self.end_mm, self.start_mm)
        return float(np.hypot(dx[0], dx[1]) / self.speed_mm_s)

    @property
    def duration_s(self) -> float:
        return 2.0 * self.press_s + self.travel_s + self.rest_s

    def probe_force_n(self, time_s: FloatArray) -> FloatArray:
        """Total probe force (N) versus time."""
        t = self._local(time_s)
        up = np.clip(t / self.press_s, 0.0, 1.0) if self.press_s > 0 else (t >= 0).astype(float)
        lift_start = self.press_s + self.travel_s
        down = 1.0 - (np.clip((t - lift_start) / self.press_s, 0.0, 1.0) if self.press_s > 0 else 0.0)
        down = np.where(t >= lift_start + self.press_s, 0.0, down)
        return np.asarray(self.peak_force_n * up * down, dtype=np.float64)

    def centre_mm(self, time_s: FloatArray) -> FloatArray:
        """Probe centre (T, 2) in mm."""
        t = self._local(time_s)
        travel = self.travel_s
        frac = np.clip((t - self.press_s) / travel, 0.0, 1.0) if travel > 0 else np.zeros_like(t)
        start, end = np.asarray(self.start_mm), np.asarray(self.end_mm)
        return np.asarray(start[None, :] + frac[:, None] * (end - start)[None, :])

    def force_n(self, time_s: FloatArray, positions_mm: FloatArray) -> FloatArray:
        """Force on every channel (T, N) in N: pressure at the channel centre times its cell area."""
        c = self.centre_mm(time_s)  # (T, 2)
        d2 = np.sum((positions_mm[None, :, :] - c[:, None, :]) ** 2, axis=2)  # (T, N)
        s2 = self.sigma_mm**2
        pressure = np.exp(-d2 / (2.0 * s2)) / (2.0 * np.pi * s2)  # per newton of probe force, 1/mm^2
        d_inc2 = np.sum((positions_mm - np.asarray(self.inclusion_mm)[None, :]) ** 2, axis=1)
        bump = 1.0 + self.inclusion_gain * np.exp(-d_inc2 / (2.0 * self.inclusion_sigma_mm**2))
        return np.asarray(self.probe_force_n(time_s)[:, None] * pressure * bump[None, :] * self.cell_area_mm2)

    def _local(self, time_s: FloatArray) -> FloatArray:
        t = np.asarray(time_s, dtype=np.float64)
        if self.repeat and self.duration_s > 0:
            t = np.where(t >= 0.0, np.mod(t, self.duration_s), t)
        return t


@dataclass(frozen=True)
class TemperatureProgram:
    """A temperature profile (°C) on a set of channels (``None``: all)."""

    profile: Profile
    channels: tuple[int, ...] | None = None


@dataclass(frozen=True)
class FaultEvent:
    """A scheduled device fault: at device time ``at_s`` set ``changes`` (until ``until_s``).

    ``changes`` holds ``FaultInjector`` fields (delay_s, no_response, exception_code, garble,
    drop_connection) and/or ``channel_mode`` with ``channel``.
    """

    at_s: float
    changes: Mapping[str, Any]
    until_s: float | None = None
    channel: int | None = None


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
    ) -> None:
        self.name = name
        self.layout = layout or ArrayLayout()
        self.description = description
        self.loads = tuple(loads)
        self.temperatures = tuple(temperatures)
        self.repeat = repeat
        self.base_temperature_c = float(base_temperature_c)
        self.faults = tuple(faults)
        _check_range("base_temperature_c", self.base_temperature_c, TEMPERATURE_RANGE_C)
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
    def builtin(cls, name: str, layout: ArrayLayout | None = None) -> Scenario:
        """A built-in scenario by name (see ``builtin_scenarios()``)."""
        if name not in _BUILTINS:
            close = difflib.get_close_matches(name, list(_BUILTINS), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ScenarioError(f"unknown scenario {name!r}{hint} (built-ins: {', '.join(_BUILTINS)})")
        description, factory = _BUILTINS[name]
        return factory(layout or ArrayLayout(), name, description)

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
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ScenarioError(f"{source}: invalid TOML: {exc}") from exc
        return _parse_scenario(data, layout or ArrayLayout(), source, default_name)

    @classmethod
    def load(cls, spec: str | Path, layout: ArrayLayout | None = None) -> Scenario:
        """A built-in name, or the path of a TOML file (anything ending in .toml or existing)."""
        text = str(spec)
        if isinstance(spec, Path) or text.endswith(".toml") or Path(text).is_file():
            return cls.from_file(text, layout)
        return cls.builtin(text, layout)

    @classmethod
    def constant(
        cls, force_n: float, layout: ArrayLayout | None = None, temperature_c: float = 25.0
    ) -> Scenario:
        """Every channel held at ``force_n`` from t = 0 (handy for tests)."""
        _check_range("force_n", force_n, FORCE_RANGE_N)
        profile = ProfileBuilder(force_n).build()
        return cls(
            f"constant-{force_n:g}N",
            layout,
            loads=[UniformLoad(profile)],
            description=f"all channels held at {force_n:g} N",
            base_temperature_c=temperature_c,
        )

    def __repr__(self) -> str:
        return f"Scenario({self.name!r}, channels={self.n_channels}, duration_s={self.duration_s:g})"


def builtin_scenarios() -> dict[str, str]:
    """Built-in scenario names with a one-line description each."""
    return {name: desc for name, (desc, _factory) in _BUILTINS.items()}


# --------------------------------------------------------------------------- builtins
_Factory = Callable[[ArrayLayout, str, str], Scenario]


def _uniform(builder: ProfileBuilder, repeat: bool = False) -> UniformLoad:
    return UniformLoad(builder.build(repeat=repeat))


def _idle(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    return Scenario(name, layout, description=desc)


def _holds(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    b = ProfileBuilder(0.0).hold(10.0)
    for level in (0.5, 2.0, 5.0):
        b.hold(120.0, level)
    b.hold(60.0, 0.0)
    return Scenario(name, layout, loads=[_uniform(b)], description=desc)


def _staircase(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    b = ProfileBuilder(0.0).hold(10.0)
    levels = [0.5 * k for k in range(1, 11)]
    for level in levels:
        b.hold(30.0, level)
    for level in reversed(levels[:-1]):
        b.hold(30.0, level)
    b.hold(30.0, 0.0)
    return Scenario(name, layout, loads=[_uniform(b)], description=desc)


def _creep_test(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    b = ProfileBuilder(0.0).hold(10.0)
    for level in (2.0, 4.0, 6.0, 8.0):
        b.hold(600.0, level).hold(600.0, 0.0)
    return Scenario(name, layout, loads=[_uniform(b)], description=desc)


def _ramps(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    b = ProfileBuilder(0.0).hold(5.0)
    for rate in (0.1, 0.5, 2.0):
        b.ramp(5.0, rate_per_s=rate).ramp(0.0, rate_per_s=rate).hold(20.0)
    return Scenario(name, layout, loads=[_uniform(b)], description=desc)


def _sine(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    b = ProfileBuilder(0.0).ramp(2.0, duration_s=2.0).sine(1.5, 10.0, cycles=30).ramp(0.0, duration_s=2.0)
    return Scenario(name, layout, loads=[_uniform(b)], description=desc, repeat=True)


def _cycles(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    b = ProfileBuilder(0.0)
    for _ in range(10):
        b.ramp(4.0, rate_per_s=1.0).hold(5.0).ramp(0.0, rate_per_s=1.0).hold(5.0)
    return Scenario(name, layout, loads=[_uniform(b)], description=desc, repeat=True)


def _indentation(layout: ArrayLayout, name: str, desc: str) -> Scenario:
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
    return Scenario(name, layout, loads=[probe], description=desc, repeat=True)


def _temperature_step(layout: ArrayLayout, name: str, desc: str) -> Scenario:
    load = ProfileBuilder(0.0).hold(5.0).hold(1500.0, 2.0).hold(60.0, 0.0)
    temp = ProfileBuilder(25.0).hold(605.0).ramp(35.0, rate_per_s=0.5).hold(400.0).ramp(25.0, rate_per_s=0.5)
    temp.hold(120.0)
    return Scenario(
        name,
        layout,
        loads=[_uniform(load)],
        temperatures=[TemperatureProgram(temp.build())],
        description=desc,
    )


def _discrepancy(layout: ArrayLayout, name: str, desc: str) -> Scenario:
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
    return Scenario(
        name,
        layout,
        loads=[_uniform(b)],
        temperatures=[TemperatureProgram(temp.build())],
        description=desc,
    )


_BUILTINS: dict[str, tuple[str, _Factory]] = {
    "idle": ("no load on any channel, 25 °C", _idle),
    "holds": (
        "all channels: 0 N for 10 s, holds at 0.5, 2 and 5 N (120 s each, steps between), then unload",
        _holds,
    ),
    "staircase": ("0.5 N steps up to 5 N and back down, 30 s per step", _staircase),
    "creep-test": (
        "the paper's creep tests: 2, 4, 6, 8 N each held 600 s, 600 s unloaded between",
        _creep_test,
    ),
    "ramps": ("triangular ramps 0-5-0 N at 0.1, 0.5 and 2 N/s", _ramps),
    "sine": ("2 N +- 1.5 N sinusoid, 10 s period, repeating", _sine),
    "cycles": ("load cycles 0-4 N at 1 N/s with 5 s holds, repeating", _cycles),
    "indentation": (
        "a 3 N probe with a hard inclusion slides across the array along the middle row, repeating",
        _indentation,
    ),
    "temperature-step": ("2 N held while the temperature steps 25 -> 35 -> 25 °C", _temperature_step),
    "discrepancy": (
        "log-spaced loads 0.2-8 N with unload holds, a long hold, two ramp rates, cycles and a "
        "temperature step",
        _discrepancy,
    ),
}


# ---------------------------------------------------------------------- TOML parsing
_TOP_KEYS = (
    "name",
    "description",
    "repeat",
    "base_temperature_c",
    "load",
    "indentation",
    "temperature",
    "fault",
)
_FAULT_FIELDS = ("delay_s", "no_response", "exception_code", "garble", "drop_connection")
_CHANNEL_MODES = ("normal", "open", "short")


@dataclass
class _Ctx:
    source: str
    path: list[str] = field(default_factory=list)

    def key(self, *parts: str) -> str:
        return ".".join([*self.path, *parts]).replace(".[", "[")

    def error(self, key: str, message: str) -> ScenarioError:
        where = f"{self.source}: {key}: " if key else f"{self.source}: "
        return ScenarioError(where + message)


def _unknown_keys(table: Mapping[str, Any], allowed: Sequence[str], ctx: _Ctx, prefix: str) -> None:
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, list(allowed), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ctx.error(
                f"{prefix}{'.' if prefix else ''}{key}", f"unknown key{hint}; allowed: {', '.join(allowed)}"
            )


def _number(
    table: Mapping[str, Any], key: str, ctx: _Ctx, prefix: str, default: float | None = None
) -> float:
    where = f"{prefix}.{key}" if prefix else key
    if key not in table:
        if default is None:
            raise ctx.error(where, "missing required key")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ctx.error(where, f"must be a finite number, got {value!r}")
    return float(value)


def _positive(
    table: Mapping[str, Any], key: str, ctx: _Ctx, prefix: str, default: float | None = None
) -> float:
    value = _number(table, key, ctx, prefix, default)
    if value <= 0.0:
        raise ctx.error(f"{prefix}.{key}" if prefix else key, f"must be > 0, got {value:g}")
    return value


def _pair(
    table: Mapping[str, Any], key: str, ctx: _Ctx, prefix: str, default: tuple[float, float]
) -> tuple[float, float]:
    if key not in table:
        return default
    value = table[key]
    ok = isinstance(value, list) and len(value) == 2
    ok = ok and all(
        not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v) for v in value
    )
    if not ok:
        raise ctx.error(f"{prefix}.{key}", f"must be a list of two numbers [x, y] in mm, got {value!r}")
    return (float(value[0]), float(value[1]))


def _channels(table: Mapping[str, Any], ctx: _Ctx, prefix: str, n: int) -> tuple[int, ...] | None:
    value = table.get("channels", "all")
    if value == "all":
        return None
    if not isinstance(value, list) or not value:
        raise ctx.error(
            f"{prefix}.channels", f'must be "all" or a non-empty list of channel indices, got {value!r}'
        )
    for c in value:
        if isinstance(c, bool) or not isinstance(c, int) or not 0 <= c < n:
            raise ctx.error(f"{prefix}.channels", f"channel {c!r} is not an integer in 0..{n - 1}")
    return tuple(value)


def _check_range(name: str, value: float, allowed: tuple[float, float]) -> None:
    if not (math.isfinite(value) and allowed[0] <= value <= allowed[1]):
        raise ScenarioError(f"{name} = {value!r} is outside {allowed[0]:g}..{allowed[1]:g}")


def _parse_steps(
    table: Mapping[str, Any], ctx: _Ctx, prefix: str, unit: str, initial: float, allowed: tuple[float, float]
) -> ProfileBuilder:
    value_key = "force_n" if unit == "n" else "temperature_c"
    step_key, ramp_key, rate_key, amp_key = (
        f"step_{unit}",
        f"ramp_{unit}",
        f"rate_{unit}_per_s",
        f"sine_amplitude_{unit}",
    )
    builder = ProfileBuilder(initial)
    steps = table.get("steps", [])
    if not isinstance(steps, list):
        raise ctx.error(f"{prefix}.steps", "must be a list of inline tables")
    for k, step in enumerate(steps):
        where = f"{prefix}.steps[{k}]"
        if not isinstance(step, dict):
            raise ctx.error(where, f"must be an inline table such as {{ hold_s = 10 }}, got {step!r}")
        actions = [a for a in ("hold_s", step_key, ramp_key, amp_key) if a in step]
        if len(actions) != 1:
            raise ctx.error(
                where, f"needs exactly one of hold_s, {step_key}, {ramp_key}, {amp_key}; got {sorted(step)}"
            )
        action = actions[0]
        try:
            if action == "hold_s":
                _unknown_keys(step, ("hold_s", value_key), ctx, where)
                duration = _number(step, "hold_s", ctx, where)
                if duration < 0:
                    raise ctx.error(f"{where}.hold_s", f"must be >= 0, got {duration:g}")
                target = _number(step, value_key, ctx, where) if value_key in step else None
                builder.hold(duration, target)
            elif action == step_key:
                _unknown_keys(step, (step_key,), ctx, where)
                builder.step(_number(step, step_key, ctx, where))
            elif action == ramp_key:
                _unknown_keys(step, (ramp_key, rate_key, "duration_s"), ctx, where)
                target = _number(step, ramp_key, ctx, where)
                if (rate_key in step) == ("duration_s" in step):
                    raise ctx.error(where, f"a ramp needs exactly one of {rate_key} or duration_s")
                if rate_key in step:
                    builder.ramp(target, rate_per_s=_positive(step, rate_key, ctx, where))
                else:
                    builder.ramp(target, duration_s=_number(step, "duration_s", ctx, where))
            else:
                _unknown_keys(step, (amp_key, "period_s", "cycles", "duration_s"), ctx, where)
                amplitude = _number(step, amp_key, ctx, where)
                period = _positive(step, "period_s", ctx, where)
                if ("cycles" in step) == ("duration_s" in step):
                    raise ctx.error(where, "a sine needs exactly one of cycles or duration_s")
                if "cycles" in step:
                    builder.sine(amplitude, period, cycles=_positive(step, "cycles", ctx, where))
                else:
                    builder.sine(amplitude, period, duration_s=_positive(step, "duration_s", ctx, where))
        except ScenarioError as exc:
            if str(exc).startswith(ctx.source):
                raise
            raise ctx.error(where, str(exc)) from exc
        lo, hi = builder.values_range()
        if lo < allowed[0] or hi > allowed[1]:
            raise ctx.error(
                where, f"reaches {lo:g}..{hi:g}, outside the allowed {allowed[0]:g}..{allowed[1]:g}"
            )
    return builder


def _parse_scenario(data: Mapping[str, Any], layout: ArrayLayout, source: str, default_name: str) -> Scenario:
    ctx = _Ctx(source)
    _unknown_keys(data, _TOP_KEYS, ctx, "")
    name = data.get("name", default_name)
    description = data.get("description", "")
    if not isinstance(name, str) or not name:
        raise ctx.error("name", f"must be a non-empty string, got {name!r}")
    if not isinstance(description, str):
        raise ctx.error("description", f"must be a string, got {description!r}")
    repeat = data.get("repeat", False)
    if not isinstance(repeat, bool):
        raise ctx.error("repeat", f"must be true or false, got {repeat!r}")
    base_temp = _number(data, "base_temperature_c", ctx, "", DEFAULT_TEMPERATURE_C)
    if not TEMPERATURE_RANGE_C[0] <= base_temp <= TEMPERATURE_RANGE_C[1]:
        raise ctx.error("base_temperature_c", f"{base_temp:g} is outside {TEMPERATURE_RANGE_C}")
    n = layout.channels
    loads: list[ForceSource] = []
    for k, table in enumerate(_table_list(data, "load", ctx)):
        where = f"load[{k}]"
        _unknown_keys(table, ("channels", "gain", "initial_n", "steps"), ctx, where)
        chans = _channels(table, ctx, where, n)
        gain = _number(table, "gain", ctx, where, 1.0)
        if gain < 0:
            raise ctx.error(f"{where}.gain", f"must be >= 0, got {gain:g}")
        initial = _number(table, "initial_n", ctx, where, 0.0)
        if not FORCE_RANGE_N[0] <= initial <= FORCE_RANGE_N[1]:
            raise ctx.error(f"{where}.initial_n", f"{initial:g} N is outside {FORCE_RANGE_N}")
        builder = _parse_steps(table, ctx, where, "n", initial, FORCE_RANGE_N)
        loads.append(UniformLoad(builder.build(), chans, gain))
    for k, table in enumerate(_table_list(data, "indentation", ctx)):
        where = f"indentation[{k}]"
        allowed = (
            "force_n", "start_mm", "end_mm", "speed_mm_s", "sigma_mm", "inclusion_mm",
            "inclusion_sigma_mm", "inclusion_gain", "press_s", "rest_s", "repeat",
        )  # fmt: skip
        _unknown_keys(table, allowed, ctx, where)
        defaults = _indentation(layout, "x", "").loads[0]
        assert isinstance(defaults, Indentation)
        force = _number(table, "force_n", ctx, where, defaults.peak_force_n)
        if not FORCE_RANGE_N[0] <= force <= FORCE_RANGE_N[1]:
            raise ctx.error(f"{where}.force_n", f"{force:g} N is outside {FORCE_RANGE_N}")
        rep = table.get("repeat", False)
        if not isinstance(rep, bool):
            raise ctx.error(f"{where}.repeat", f"must be true or false, got {rep!r}")
        try:
            loads.append(
                Indentation(
                    peak_force_n=force,
                    start_mm=_pair(table, "start_mm", ctx, where, defaults.start_mm),
                    end_mm=_pair(table, "end_mm", ctx, where, defaults.end_mm),
                    speed_mm_s=_positive(table, "speed_mm_s", ctx, where, defaults.speed_mm_s),
                    sigma_mm=_positive(table, "sigma_mm", ctx, where, defaults.sigma_mm),
                    inclusion_mm=_pair(table, "inclusion_mm", ctx, where, defaults.inclusion_mm),
                    inclusion_sigma_mm=_positive(
                        table, "inclusion_sigma_mm", ctx, where, defaults.inclusion_sigma_mm
                    ),
                    inclusion_gain=_number(table, "inclusion_gain", ctx, where, defaults.inclusion_gain),
                    press_s=_number(table, "press_s", ctx, where, defaults.press_s),
                    rest_s=_number(table, "rest_s", ctx, where, defaults.rest_s),
                    cell_area_mm2=layout.pitch_mm**2,
                    repeat=rep,
                )
            )
        except ScenarioError as exc:
            if str(exc).startswith(ctx.source):
                raise
            raise ctx.error(where, str(exc)) from exc
    temps: list[TemperatureProgram] = []
    for k, table in enumerate(_table_list(data, "temperature", ctx)):
        where = f"temperature[{k}]"
        _unknown_keys(table, ("channels", "initial_c", "steps"), ctx, where)
        chans = _channels(table, ctx, where, n)
        initial = _number(table, "initial_c", ctx, where, base_temp)
        builder = _parse_steps(table, ctx, where, "c", initial, TEMPERATURE_RANGE_C)
        temps.append(TemperatureProgram(builder.build(), chans))
    faults = [_parse_fault(t, ctx, f"fault[{k}]", n) for k, t in enumerate(_table_list(data, "fault", ctx))]
    return Scenario(
        name,
        layout,
        loads=loads,
        temperatures=temps,
        description=description,
        repeat=repeat,
        base_temperature_c=base_temp,
        faults=faults,
    )


def _table_list(data: Mapping[str, Any], key: str, ctx: _Ctx) -> list[dict[str, Any]]:
    value = data.get(key, [])
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ctx.error(key, f"must be an array of tables ([[{key}]])")
    return value


def _parse_fault(table: Mapping[str, Any], ctx: _Ctx, where: str, n: int) -> FaultEvent:
    _unknown_keys(table, ("at_s", "until_s", "channel", "channel_mode", *_FAULT_FIELDS), ctx, where)
    at_s = _number(table, "at_s", ctx, where)
    until = _number(table, "until_s", ctx, where) if "until_s" in table else None
    if until is not None and until <= at_s:
        raise ctx.error(f"{where}.until_s", f"must be after at_s ({at_s:g}), got {until:g}")
    changes: dict[str, Any] = {}
    channel = None
    if "channel_mode" in table:
        mode = table["channel_mode"]
        if mode not in _CHANNEL_MODES:
            raise ctx.error(
                f"{where}.channel_mode", f"must be one of {', '.join(_CHANNEL_MODES)}, got {mode!r}"
            )
        ch = table.get("channel")
        if isinstance(ch, bool) or not isinstance(ch, int) or not 0 <= ch < n:
            raise ctx.error(f"{where}.channel", f"channel_mode needs a channel in 0..{n - 1}, got {ch!r}")
        changes["channel_mode"] = mode
        channel = ch
    elif "channel" in table:
        raise ctx.error(f"{where}.channel", "channel is only used with channel_mode")
    if "delay_s" in table:
        delay = _number(table, "delay_s", ctx, where)
        if delay < 0:
            raise ctx.error(f"{where}.delay_s", f"must be >= 0, got {delay:g}")
        changes["delay_s"] = delay
    for key in ("no_response", "garble", "drop_connection"):
        if key in table:
            if not isinstance(table[key], bool):
                raise ctx.error(f"{where}.{key}", f"must be true or false, got {table[key]!r}")
            changes[key] = table[key]
    if "exception_code" in table:
        code = table["exception_code"]
        if isinstance(code, bool) or not isinstance(code, int) or code not in VALID_EXCEPTION_CODES:
            raise ctx.error(
                f"{where}.exception_code",
                f"must be a Modbus exception code {VALID_EXCEPTION_CODES}, got {code!r}",
            )
        changes["exception_code"] = code
    if not changes:
        raise ctx.error(where, "sets no fault; give channel_mode or one of " + ", ".join(_FAULT_FIELDS))
    return FaultEvent(at_s=at_s, changes=changes, until_s=until, channel=channel)


#: Modbus exception codes a device may answer with.
VALID_EXCEPTION_CODES: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8, 10, 11)
