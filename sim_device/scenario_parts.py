"""The parts a ``Scenario`` is made of (``sim_device.scenarios``): the array layout, the force
sources (uniform loads and the indentation probe), temperature programs, fault events, the
allowed ranges, and ``ScenarioSpec``, a scenario not yet bound to a layout's ``Scenario``.

The built-in scenarios (``builtin_scenarios``) and the file format (``scenario_file``) build
``ScenarioSpec``s from these parts; ``scenarios`` sits above all three and turns a spec into a
``Scenario`` (``Scenario.builtin``, ``Scenario.from_toml``), so the imports point one way.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from .profiles import Profile, ScenarioError

FloatArray = NDArray[np.float64]

#: Forces a scenario may ask for (N) and temperatures (°C); beyond them is an error.
FORCE_RANGE_N = (0.0, 50.0)
TEMPERATURE_RANGE_C = (-40.0, 150.0)
DEFAULT_TEMPERATURE_C = 25.0


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
        check_range("peak_force_n", self.peak_force_n, FORCE_RANGE_N)

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


@dataclass(frozen=True)
class ScenarioSpec:
    """What a built-in or a scenario file describes; ``Scenario.from_spec`` binds it to a layout."""

    name: str
    loads: Sequence[ForceSource] = ()
    temperatures: Sequence[TemperatureProgram] = ()
    description: str = ""
    repeat: bool = False
    base_temperature_c: float = DEFAULT_TEMPERATURE_C
    faults: Sequence[FaultEvent] = ()
    #: the sensors have carried their t = 0 load long before the start: their creep has settled
    settled: bool = False


def check_range(name: str, value: float, allowed: tuple[float, float]) -> None:
    if not (math.isfinite(value) and allowed[0] <= value <= allowed[1]):
        raise ScenarioError(f"{name} = {value!r} is outside {allowed[0]:g}..{allowed[1]:g}")


#: Modbus exception codes a fault event may answer with.
VALID_EXCEPTION_CODES: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8, 10, 11)
