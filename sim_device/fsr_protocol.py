"""Load protocols of the FSR emulator: piecewise-linear force histories (N versus s) from 0 N.

``Protocol`` is built from ``Ramp`` (to a level at a rate) and ``Hold`` steps; the builders
make the named protocols the command line offers (``PROTOCOLS``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from .fsr_params import FloatArray, require, require_finite

#: Levels of the ``holds`` protocol, N: non-monotone, so that low loads follow high ones.
DEFAULT_HOLD_LEVELS_N: tuple[float, ...] = (5.0, 20.0, 2.0, 40.0, 10.0, 1.0, 30.0, 0.5)


@dataclass(frozen=True)
class Ramp:
    """Ramp the force linearly to ``target_n`` (N, >= 0) at ``rate_n_per_s`` (N/s, > 0)."""

    target_n: float
    rate_n_per_s: float

    def __post_init__(self) -> None:
        require_finite(self.target_n, "target_n", low=0.0)
        require_finite(self.rate_n_per_s, "rate_n_per_s", low=0.0, strict=True)


@dataclass(frozen=True)
class Hold:
    """Hold the current force for ``duration_s`` (s, >= 0)."""

    duration_s: float

    def __post_init__(self) -> None:
        require_finite(self.duration_s, "duration_s", low=0.0)


Step = Ramp | Hold


@dataclass(frozen=True)
class Protocol:
    """A load history in N versus time in s, starting at 0 N at t = 0, piecewise linear."""

    steps: tuple[Step, ...] = ()
    name: str = "custom"

    def then(self, *steps: Step) -> Protocol:
        return replace(self, steps=self.steps + tuple(steps))

    def ramp(self, target_n: float, rate_n_per_s: float) -> Protocol:
        return self.then(Ramp(target_n, rate_n_per_s))

    def hold(self, duration_s: float) -> Protocol:
        return self.then(Hold(duration_s))

    def unload(self, rate_n_per_s: float) -> Protocol:
        return self.then(Ramp(0.0, rate_n_per_s))

    def rest(self, duration_s: float) -> Protocol:
        return self.then(Hold(duration_s))

    def knots(self) -> tuple[FloatArray, FloatArray]:
        """Times (s, strictly increasing, from 0) and forces (N) of the corners."""
        t, f = [0.0], [0.0]
        for step in self.steps:
            if isinstance(step, Ramp):
                dt = abs(step.target_n - f[-1]) / step.rate_n_per_s
                if dt > 0.0:
                    t.append(t[-1] + dt)
                    f.append(step.target_n)
            elif step.duration_s > 0.0:
                t.append(t[-1] + step.duration_s)
                f.append(f[-1])
        return np.asarray(t, dtype=np.float64), np.asarray(f, dtype=np.float64)

    @property
    def duration_s(self) -> float:
        return float(self.knots()[0][-1])

    def force_at(self, time_s: FloatArray | float) -> FloatArray:
        """The force at ``time_s`` (N); 0 before the start, the last force after the end."""
        t, f = self.knots()
        return np.asarray(np.interp(np.asarray(time_s, dtype=np.float64), t, f, left=0.0))

    def rate_at(self, time_s: FloatArray | float) -> FloatArray:
        """dF/dt (N/s) at ``time_s``, taken from the segment that starts at or before it."""
        t, f = self.knots()
        ts = np.asarray(time_s, dtype=np.float64)
        if t.size < 2:
            return np.zeros_like(ts)
        slopes = np.diff(f) / np.diff(t)
        seg = np.searchsorted(t, ts, side="right") - 1
        inside = (seg >= 0) & (seg < slopes.size)
        return np.asarray(np.where(inside, slopes[np.clip(seg, 0, slopes.size - 1)], 0.0))

    def loading_cycles(self, threshold_n: float) -> int:
        """How many times the force rises from at or below ``threshold_n`` to above it."""
        _, f = self.knots()
        above = f > threshold_n
        return int(np.count_nonzero(above[1:] & ~above[:-1]))


def hold_protocol(
    levels_n: Sequence[float] = DEFAULT_HOLD_LEVELS_N,
    hold_s: float = 30.0,
    rest_s: float = 30.0,
    rate_n_per_s: float = 1.0,
    *,
    lead_s: float = 5.0,
) -> Protocol:
    """Rest ``lead_s``; then for each level: ramp to it, hold ``hold_s``, unload, rest ``rest_s``."""
    p = Protocol(name="holds").rest(lead_s)
    for level in levels_n:
        p = p.ramp(level, rate_n_per_s).hold(hold_s).unload(rate_n_per_s).rest(rest_s)
    return p


def staircase(
    levels_n: Sequence[float] = (5.0, 10.0, 20.0, 30.0, 40.0, 49.0),
    step_s: float = 20.0,
    rate_n_per_s: float = 1.0,
    rest_s: float = 30.0,
    *,
    descending: bool = True,
    lead_s: float = 5.0,
) -> Protocol:
    """Up through ``levels_n`` holding ``step_s`` at each, then (``descending``) down through
    them again without unloading in between, then unload and rest ``rest_s``."""
    p = Protocol(name="staircase").rest(lead_s)
    levels = list(levels_n)
    for level in levels:
        p = p.ramp(level, rate_n_per_s).hold(step_s)
    if descending:
        for level in reversed(levels[:-1]):
            p = p.ramp(level, rate_n_per_s).hold(step_s)
    return p.unload(rate_n_per_s).rest(rest_s)


def calibration_run(
    max_n: float = 49.0,
    cycles: int = 3,
    hold_s: float = 15.0,
    rest_s: float = 20.0,
    slow_rate_n_per_s: float = 1.0,
    fast_rate_n_per_s: float = 20.0,
    *,
    lead_s: float = 5.0,
) -> Protocol:
    """A calibration session of ``cycles`` loading/unloading cycles up to ``max_n``.

    Levels are ``max_n`` x (2, 5, 10, 20, 35, 49) / 49. Cycle 1: an ascending then descending
    staircase at the slow rate, then unload. Cycle 2: separate holds (unload and rest between)
    in the non-monotone order 20, 2, 49, 5, 35, 10 at the slow rate. Cycle 3: holds in the
    order 35, 5, 49, 10, 2, 20 at the fast rate. Further cycles repeat the pattern.
    """
    require(cycles >= 1, f"cycles must be >= 1, got {cycles}")
    require_finite(max_n, "max_n", low=0.0, strict=True)
    scale = max_n / 49.0
    levels = [v * scale for v in (2.0, 5.0, 10.0, 20.0, 35.0, 49.0)]
    orders = ([3, 0, 5, 1, 4, 2], [4, 1, 5, 2, 0, 3])
    p = Protocol(name="calibration").rest(lead_s)
    for cycle in range(cycles):
        kind = cycle % 3
        if kind == 0:
            for level in levels:
                p = p.ramp(level, slow_rate_n_per_s).hold(hold_s)
            for level in reversed(levels[:-1]):
                p = p.ramp(level, slow_rate_n_per_s).hold(hold_s)
            p = p.unload(slow_rate_n_per_s).rest(rest_s)
        else:
            rate = slow_rate_n_per_s if kind == 1 else fast_rate_n_per_s
            for i in orders[kind - 1]:
                p = p.ramp(levels[i], rate).hold(hold_s).unload(rate).rest(rest_s)
    return p


def alternating_holds(
    high_n: float = 25.5,
    low_n: float = 3.3,
    high_s: float = 20.0,
    low_s: float = 10.0,
    cycles: int = 12,
    rate_n_per_s: float = 40.0,
    *,
    lead_s: float = 13.0,
) -> Protocol:
    """A slow-loading run: the sensor preloaded at ``low_n``, then ``cycles`` times a hold of
    ``high_s`` at ``high_n`` followed by a hold of ``low_s`` at ``low_n``, never unloaded.

    Ramp to ``low_n`` and hold ``lead_s``; each cycle ramps up to ``high_n`` and down to
    ``low_n`` at ``rate_n_per_s`` (N/s). The run ends on the last low hold. Every low hold but
    the lead follows a high one: what a sensor reads at a low load after a high load.
    """
    require(cycles >= 1, f"cycles must be >= 1, got {cycles}")
    require(0.0 < low_n < high_n, f"need 0 < low_n < high_n, got low_n={low_n!r}, high_n={high_n!r}")
    p = Protocol(name="slow-loading").ramp(low_n, rate_n_per_s).hold(lead_s)
    for _ in range(cycles):
        p = p.ramp(high_n, rate_n_per_s).hold(high_s).ramp(low_n, rate_n_per_s).hold(low_s)
    return p


def calibration_ramp(
    max_n: float = 49.0,
    rate_n_per_s: float = 0.125,
    hold_s: float = 24.0,
    unload_rate_n_per_s: float = 50.0,
    *,
    lead_s: float = 5.0,
    rest_s: float = 2.0,
) -> Protocol:
    """A calibration by one slow ramp: rest ``lead_s``, ramp to ``max_n`` at ``rate_n_per_s``
    (0.125 N/s: 392 s to 49 N), hold ``hold_s``, unload at ``unload_rate_n_per_s``, rest
    ``rest_s``. The creep elements faster than the ramp stay near their equilibrium on it."""
    require_finite(max_n, "max_n", low=0.0, strict=True)
    p = Protocol(name="calibration-ramp").rest(lead_s).ramp(max_n, rate_n_per_s).hold(hold_s)
    return p.unload(unload_rate_n_per_s).rest(rest_s)


#: The protocols the command line offers, by name (each built with its defaults).
PROTOCOLS: dict[str, Callable[[], Protocol]] = {
    "holds": hold_protocol,
    "calibration": calibration_run,
    "staircase": staircase,
    "slow-loading": alternating_holds,
    "calibration-ramp": calibration_ramp,
}
