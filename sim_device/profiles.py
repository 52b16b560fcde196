"""Piecewise signals of one quantity (force in N or temperature in degC) versus device time (s).

A ``Profile`` is built by a ``ProfileBuilder`` from holds, steps, ramps (at a rate or over a
duration) and sinusoids, evaluated vectorized over times; after its end it holds its final
value, or repeats. ``ScenarioError`` is the error of every scenario building block.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


class ScenarioError(ValueError):
    """A scenario that cannot be built: unknown name, bad file, or a value out of range."""


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
