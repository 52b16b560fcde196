"""Sensor parameters: the default Linqstat set of ``shared/spec/linqstat-parameters.md``.

Every value is in SI units and named with its unit. ``SensorParams`` describes one sensor;
``ChannelParams`` stacks several sensors into arrays so the physics is vectorized over
channels. Validation happens at construction and states the allowed range.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


class ParameterError(ValueError):
    """A sensor parameter is missing, unknown, or outside its allowed range."""


@dataclass(frozen=True)
class Interval:
    """An allowed range of a number, with the notation used in error messages."""

    low: float
    high: float
    low_inclusive: bool = False
    high_inclusive: bool = True

    def contains(self, value: float) -> bool:
        if math.isnan(value):
            return False
        above = value >= self.low if self.low_inclusive else value > self.low
        below = value <= self.high if self.high_inclusive else value < self.high
        return above and below

    def describe(self) -> str:
        left = "[" if self.low_inclusive else "("
        right = "]" if self.high_inclusive else ")"
        return f"{left}{self.low:g}, {self.high:g}{right}"


_POSITIVE = Interval(0.0, math.inf, high_inclusive=False)
_NON_NEGATIVE = Interval(0.0, math.inf, low_inclusive=True, high_inclusive=False)

#: Allowed range of every parameter, used by validation and by error messages.
PARAMETER_RANGES: dict[str, Interval] = {
    "barrier_height_ev": Interval(0.0, 10.0),
    "particle_diameter_m": Interval(0.0, 1e-3),
    "volume_fraction": Interval(0.0, math.pi / 6, high_inclusive=False),
    "area_m2": Interval(0.0, 1.0),
    "r0_ohm": _POSITIVE,
    "rho1_ohm_m": _NON_NEGATIVE,
    "rho2_ohm_m": _NON_NEGATIVE,
    "hardness_pa": _POSITIVE,
    "e0_pa": _POSITIVE,
    "e0_slope_pa_per_n": _NON_NEGATIVE,
    "e1_pa": _POSITIVE,
    "e1_slope_pa_per_n": _NON_NEGATIVE,
    "mu1_pa_s": _POSITIVE,
    "mu1_slope_pa_s_per_n": _NON_NEGATIVE,
    "e2_pa": _POSITIVE,
    "mu2_pa_s": _POSITIVE,
    "hysteresis_strain": Interval(0.0, 0.1, low_inclusive=True),
    "hysteresis_force_n": _POSITIVE,
    "temperature_coeff_per_k": Interval(-0.2, 0.2, low_inclusive=True),
    "reference_temperature_c": Interval(-273.15, 1000.0),
    "series_resistance_ohm": _NON_NEGATIVE,
    "leakage_resistance_ohm": Interval(0.0, math.inf, high_inclusive=True),
    "force_min_n": _POSITIVE,
    "force_max_n": _POSITIVE,
}


@dataclass(frozen=True)
class SensorParams:
    """Physical parameters of one piezoresistive sensor (SI units).

    The defaults are the project's Linqstat set: barrier height, particle diameter and
    volume fraction are printed in the paper; the rest are assumed (see the spec) and are
    meant to be replaced by calibration. E0, E1 and mu1 are linear in the applied force
    (paper eq. 19 form): ``E0(F) = e0_pa + e0_slope_pa_per_n * F``.
    """

    barrier_height_ev: float = 0.05
    particle_diameter_m: float = 500e-9
    volume_fraction: float = 0.2873
    area_m2: float = 1.9635e-5
    r0_ohm: float = 200e3
    rho1_ohm_m: float = 1.68e-8
    rho2_ohm_m: float = 1.0
    hardness_pa: float = 30e6
    e0_pa: float = 15e6
    e0_slope_pa_per_n: float = 1.0e6
    e1_pa: float = 150e6
    e1_slope_pa_per_n: float = 10e6
    mu1_pa_s: float = 1.5e10
    mu1_slope_pa_s_per_n: float = 1.0e9
    # Effects beyond the paper; each has an "off" form chosen by the effect list, and
    # these values only matter when the effect is switched on.
    e2_pa: float = 300e6
    mu2_pa_s: float = 3.0e11
    hysteresis_strain: float = 2e-4
    hysteresis_force_n: float = 0.5
    temperature_coeff_per_k: float = -0.005
    reference_temperature_c: float = 25.0
    series_resistance_ohm: float = 500.0
    leakage_resistance_ohm: float = 2e6
    # Force range of the inversion: below force_min_n reads as "no contact", above
    # force_max_n as "saturated".
    force_min_n: float = 0.05
    force_max_n: float = 10.0

    def __post_init__(self) -> None:
        for name, allowed in _CHECKS:
            value = getattr(self, name)
            number = _checked(name, value, allowed)
            if number is not value:
                object.__setattr__(self, name, number)
        _check_force_range(self.force_min_n, self.force_max_n)

    def replaced(self, values: Mapping[str, float]) -> SensorParams:
        """``dataclasses.replace(self, **values)``, with the same checks and errors, without its
        overhead (a fit builds thousands): only the new values are checked, the others were
        when ``self`` was built."""
        fields_ = dict(self.__dict__)
        for name, value in values.items():
            allowed = PARAMETER_RANGES.get(name)
            if allowed is None:
                raise TypeError(f"SensorParams has no parameter {name!r}")
            fields_[name] = _checked(name, value, allowed)
        _check_force_range(fields_["force_min_n"], fields_["force_max_n"])
        out = object.__new__(SensorParams)
        out.__dict__.update(fields_)
        return out

    def with_overrides(self, overrides: Mapping[str, Any]) -> SensorParams:
        """Return a copy with the named values replaced (unknown names are an error)."""
        _check_names(overrides)
        return replace(self, **dict(overrides))

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any]) -> SensorParams:
        """Build from a mapping such as a TOML table; missing keys keep their defaults."""
        _check_names(table)
        return cls(**dict(table))

    @classmethod
    def from_toml(cls, text: str, table: str | None = None) -> SensorParams:
        """Parse TOML text; ``table`` names a sub-table (dotted) holding the parameters."""
        try:
            data: Any = tomllib.loads(text.removeprefix("\ufeff"))
        except RecursionError:
            raise ParameterError("invalid TOML: arrays or inline tables nested too deeply") from None
        except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
            raise ParameterError(f"invalid TOML: {str(exc).split(';')[0]}") from None
        if table:
            for key in table.split("."):
                if not isinstance(data, dict) or key not in data:
                    raise ParameterError(f"TOML has no table [{table}]")
                data = data[key]
        if not isinstance(data, dict):
            raise ParameterError(f"[{table}] is not a table")
        return cls.from_mapping(data)

    def to_toml(self, table: str | None = None) -> str:
        """Dump as a TOML table that ``from_toml`` reads back exactly."""
        lines = [f"[{table}]"] if table else []
        for f in fields(self):
            value = getattr(self, f.name)
            text = "inf" if math.isinf(value) else repr(value)
            lines.append(f"{f.name} = {text}")
        return "\n".join(lines) + "\n"


def _checked(name: str, value: object, allowed: Interval) -> float:
    """``value`` as a float, or a ``ParameterError`` saying why it is not a valid ``name``."""
    if type(value) is float:  # kept as it is (a fit builds thousands)
        number = value
    elif isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(f"parameter {name} must be a number, got {type(value).__name__} {value!r}")
    else:
        number = float(value)
    if not allowed.contains(number):
        raise ParameterError(
            f"parameter {name} = {value!r} is outside its allowed range {allowed.describe()}"
        )
    return number


def _check_force_range(force_min_n: float, force_max_n: float) -> None:
    if force_min_n >= force_max_n:
        raise ParameterError(f"force_min_n ({force_min_n:g} N) must be below force_max_n ({force_max_n:g} N)")


#: every parameter's name and allowed range, in declaration order
_CHECKS: tuple[tuple[str, Interval], ...] = tuple(
    (f.name, PARAMETER_RANGES[f.name]) for f in fields(SensorParams)
)


_NAMES: tuple[str, ...] = tuple(name for name, _ in _CHECKS)


def parameter_names() -> list[str]:
    """Names of all sensor parameters, in declaration order."""
    return list(_NAMES)


def _check_names(table: Mapping[str, Any]) -> None:
    import difflib

    known = parameter_names()
    for name in table:
        if name not in known:
            close = difflib.get_close_matches(name, known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ParameterError(f"unknown sensor parameter {name!r}{hint}")


@dataclass(frozen=True)
class ChannelParams:
    """Parameters of N channels as arrays of shape (N,), for vectorized physics."""

    barrier_height_ev: FloatArray
    particle_diameter_m: FloatArray
    volume_fraction: FloatArray
    area_m2: FloatArray
    r0_ohm: FloatArray
    rho1_ohm_m: FloatArray
    rho2_ohm_m: FloatArray
    hardness_pa: FloatArray
    e0_pa: FloatArray
    e0_slope_pa_per_n: FloatArray
    e1_pa: FloatArray
    e1_slope_pa_per_n: FloatArray
    mu1_pa_s: FloatArray
    mu1_slope_pa_s_per_n: FloatArray
    e2_pa: FloatArray
    mu2_pa_s: FloatArray
    hysteresis_strain: FloatArray
    hysteresis_force_n: FloatArray
    temperature_coeff_per_k: FloatArray
    reference_temperature_c: FloatArray
    series_resistance_ohm: FloatArray
    leakage_resistance_ohm: FloatArray
    force_min_n: FloatArray
    force_max_n: FloatArray

    @classmethod
    def stack(cls, sensors: SensorParams | Sequence[SensorParams]) -> ChannelParams:
        """Stack one or more sensors' parameters into per-channel arrays."""
        items = [sensors] if isinstance(sensors, SensorParams) else list(sensors)
        if not items:
            raise ParameterError("at least one channel is required")
        names = _NAMES
        if len(items) == 1:  # a fit's model, built thousands of times: one row per parameter
            table = np.array([getattr(items[0], name) for name in names], dtype=np.float64).reshape(-1, 1)
        else:
            table = np.array([[getattr(s, name) for s in items] for name in names], dtype=np.float64)
        return cls(**dict(zip(names, table, strict=True)))

    @property
    def n_channels(self) -> int:
        return int(self.r0_ohm.shape[0])

    def channel(self, index: int) -> SensorParams:
        """The parameters of one channel as a ``SensorParams``."""
        return SensorParams(**{n: float(getattr(self, n)[index]) for n in parameter_names()})
