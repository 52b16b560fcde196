"""An independent emulator of a force-sensing resistor (FSR) on a bench, for tests.

Records from this module are *not* produced by the gateway's physical model (tunneling +
contact + creep, ``gateway/model``) nor by the simulated MIS array (``sim_device.sensor``):
the sensor here is a generic power-law FSR with Burgers-like creep, Preisach-style
hysteresis and run-to-run sensitivity changes, read by a 2-wire ohmmeter, with a load cell
as the force reference. It imports nothing of ``gateway`` (numpy and scipy only).

Symbols and units
-----------------
``F`` applied (true) force, N; ``t`` time since the start of the run, s; ``G`` conductance, S;
``R`` resistance, ohm. Parameter names carry their units (``FsrParams``).

1. Static curve (power law)
    ``G_static(F) = g_run k F^n_run`` for ``F > F_th``, and ``G = 0`` (open) for
    ``F <= F_th``. ``k`` (``k_s``) is the conductance at 1 N, S (i.e. S/N^n); ``n``
    (``exponent``) is dimensionless; ``F_th`` (``threshold_n``) is the contact threshold, N.
    A leakage resistance ``R_leak`` (``leakage_ohm``, default inf: none) is in parallel at
    all forces, so the sensor reads ``R = 1 / (G + 1/R_leak)`` (inf when both are 0).
    Defaults k = 5e-5 S, n = 0.8: R = 72.4 kohm at 0.2 N, 8.8 kohm at 5 N, 1.05 kohm at
    40 N on the static curve. (A power law through both 50 kohm at 0.2 N and 1-2 kohm at
    40 N would need n = 0.61-0.74; n = 0.8, the low end of the usual 0.8-1.1, is the
    compromise.)

2. Creep on an effective force (Burgers-like)
    The static curve is evaluated at an effective force
    ``F_eff = F + x1 + x2 + phi`` (N), where

    - two Kelvin elements relax towards a fraction of the applied force,
      ``dx_i/dt = (a_i F - x_i) / tau_i`` (``a_fast``, ``tau_fast_s``; ``a_slow``,
      ``tau_slow_s``); a held step F reaches ``x_i = a_i F (1 - exp(-t/tau_i))``;
    - a dashpot's accumulated flow ``phi`` (N) grows while the sensor is loaded (``F > F_th``)
      and recovers while it is unloaded (``F <= F_th``)::

          dphi/dt = F / eta            if F > F_th   (eta = ``eta_flow_s``, s)
          dphi/dt = -phi / tau_rec     if F <= F_th  (tau_rec = ``tau_recovery_s``, s)

      A true Burgers dashpot never recovers; here the flow relaxes slowly after unloading,
      so a low load after a high one reads high for a while (minutes).

    All states start at 0 (a rested sensor). Integration is exact: the emulator builds its
    own fine grid, every protocol knot and every crossing of ``F_th`` is a grid node and each
    protocol segment is cut into equal sub-steps of at most ``internal_step_s``, so the force
    is linear (slope ``s``, N/s) within each sub-step h, and each Kelvin element is advanced
    by the exact exponential update for a linear input::

        x(t+h) = c x(t) + a [F(t+h) - c F(t) + tau s expm1(-h/tau)],   c = exp(-h/tau)

    (a linear recurrence, evaluated per segment with ``scipy.signal.lfilter``); the flow by
    ``phi(t+h) = phi(t) + h (F(t) + F(t+h)) / (2 eta)`` (loaded) or ``phi(t) exp(-h/tau_rec)``
    (unloaded). A sample at time t between two nodes is propagated from the node before it
    by the same formulas with h = t - t_node. The states at the samples are therefore exact
    and do not depend on the sampling times (nor, beyond rounding, on ``internal_step_s``).

3. Rate-independent hysteresis (Preisach-style, play operators)
    Play (backlash) operators of half-widths ``r_j`` (``hysteresis_widths_n``, N) act on F:
    ``p_j <- max(F - r_j, min(F + r_j, p_j))``, ``p_j = 0`` at the start (virgin sensor).
    Their normalised states ``d_j = (F - p_j) / r_j`` lie in [-1, 1]: +1 after loading by at
    least ``2 r_j``, -1 after unloading. The conductance is multiplied by
    ``1 + H``, ``H = -A sum_j w_j d_j`` (``hysteresis_amplitude`` A, weights ``w_j`` summing
    to 1, equal by default): loading reads lower than unloading at the same force. On virgin
    loading ``H = -A sum_j w_j min(F / r_j, 1)``; unloading from ``F_max`` gives
    ``d_j = max(-1, 1 - (F_max - F) / r_j)``. Defaults A = 0.07, r = 0.5, 1, 2, 4, 8 N: -7 %
    on loading and +7 % on unloading at mid-range (once F has moved 2 x 8 = 16 N from the
    last reversal, or 8 N from a virgin start). The operators are evaluated exactly at every
    sample (the protocol is monotone between its knots, where it reverses), so the loop is
    the same at any loading rate.

4. Sensitivity changing between runs
    Each run r draws, from ``SeedSequence([seed, r])``: a gain ``g_run = exp(clip(sigma_g z1,
    -ln(M)/2, ln(M)/2))`` on k (``gain_sigma`` sigma_g, ``gain_max_ratio`` M: any two runs
    differ by at most M), an exponent ``n_run = n + sigma_n z2`` (``exponent_sigma``), a load
    cell zero offset ``sigma_0 z3`` (``load_cell_offset_sigma_n``) and a humidity phase
    ``U(0, 2 pi)``; z ~ N(0, 1). The draws are kept in ``RunConditions``.

5. Two-wire ohmmeter
    The reading is ``(R + R_lead) (1 + sigma_R z)`` (``lead_ohm``, ``ohmmeter_noise_rel``),
    quantised like a 4.5-digit auto-ranging meter (``ohmmeter_reading``): ranges of full
    scale ``R_min 10^j`` (``ohmmeter_min_range_ohm`` = 200 ohm, 2 k, 20 k, ... up to
    ``ohmmeter_max_range_ohm``), each read in ``ohmmeter_counts`` counts (20000: resolution
    full scale / 20000); the lowest range whose count is below 20000 is used; above the top
    range, and for an open circuit, the reading is inf. ``ohmmeter_counts = 0``: an ideal
    meter (no quantisation, no range limit).

6. Load cell reference
    ``force_n = F + offset_run + sigma_F z`` (``load_cell_noise_n``), rounded to
    ``load_cell_resolution_n``; the indicator shows no negative force (readings below 0 are
    0, as the record format requires force_n >= 0).

7. Timestamps
    ``t_0 = 0``, ``t_{i+1} = t_i + dt (1 + j u_i)``, u_i ~ U(-1, 1) (``jitter_fraction`` j < 1,
    dt = ``sample_interval_s``): strictly increasing, intervals within ``dt (1 +- j)``. The run
    is sampled until the protocol's end.

8. Out-of-catalogue effects (off by default; not in the gateway's effect catalogue)
    - ``wear_per_cycle`` w: during the m-th loading of the sensor (m = 1, 2, ..., counted at
      each unload-to-load crossing of ``F_th``, plus ``prior_cycles`` before the run) k is
      multiplied by ``(1 - w)^(m - 1)``;
    - ``rate_gain_s`` b (s): G is multiplied by ``max(0.1, 1 + b (dF/dt) / F_fs)`` with the
      protocol's slope dF/dt (N/s) and ``full_scale_n`` F_fs (a viscous rate dependence);
    - ``humidity`` h: G is multiplied by ``1 + h sin(2 pi t / P + phase_run)``
      (``humidity_period_s`` P), a slow drift unrelated to the load.

The sensor's conductance is therefore::

    G = g_run k (1 - w)^(m - 1) F_eff^n_run (1 + H) rate_factor humidity_factor  (F > F_th)

``EmulatedRecord.static_resistance_ohm`` is ``1 / (g_run k F^n_run + 1/R_leak)`` (the run's
static curve at the true force, no creep, hysteresis, wear, rate or humidity, no lead).

Protocols (``Protocol``) are piecewise-linear load histories starting at 0 N, built from
``Ramp`` (to a level at a rate) and ``Hold`` steps; builders ``hold_protocol``,
``staircase``, ``calibration_run``. ``write_record`` writes runs in the project's record
format (``docs/record-format.md``), time continuing across runs.

Example::

    emu = FsrEmulator(FsrParams(), seed=1)
    records = emu.run_many(calibration_run(), n_runs=3)
    write_record("fsr.csv", records)
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

FloatArray = NDArray[np.float64]

__all__ = [
    "DEFAULT_HOLD_LEVELS_N",
    "PROTOCOLS",
    "EmulatedRecord",
    "FsrEmulator",
    "FsrParams",
    "Hold",
    "Protocol",
    "Ramp",
    "RunConditions",
    "calibration_run",
    "hold_protocol",
    "ohmmeter_reading",
    "staircase",
    "write_record",
]

#: Levels of the ``holds`` protocol, N: non-monotone, so that low loads follow high ones.
DEFAULT_HOLD_LEVELS_N: tuple[float, ...] = (5.0, 20.0, 2.0, 40.0, 10.0, 1.0, 30.0, 0.5)
_MIN_RATE_FACTOR = 0.1


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(message)


def _finite(value: float, name: str, *, low: float | None = None, strict: bool = False) -> None:
    _check(math.isfinite(value), f"{name} must be finite, got {value!r}")
    if low is not None:
        bad = value <= low if strict else value < low
        _check(not bad, f"{name} must be {'>' if strict else '>='} {low:g}, got {value!r}")


# --------------------------------------------------------------------------------------------
# Parameters

_POSITIVE: tuple[str, ...] = (
    "k_s",
    "exponent",
    "tau_fast_s",
    "tau_slow_s",
    "internal_step_s",
    "full_scale_n",
)
_POSITIVE += ("humidity_period_s", "ohmmeter_min_range_ohm", "gain_max_ratio")
_NON_NEGATIVE: tuple[str, ...] = ("threshold_n", "a_fast", "a_slow", "hysteresis_amplitude", "gain_sigma")
_NON_NEGATIVE += ("exponent_sigma", "lead_ohm", "ohmmeter_noise_rel", "load_cell_noise_n")
_NON_NEGATIVE += ("load_cell_offset_sigma_n", "load_cell_resolution_n", "jitter_fraction")


@dataclass(frozen=True)
class FsrParams:
    """Every parameter of the emulated sensor and bench (see the module docstring)."""

    # 1. static curve
    k_s: float = 5e-5  # conductance at F_eff = 1 N, S (k in S/N^n)
    exponent: float = 0.8  # n, dimensionless
    threshold_n: float = 0.05  # at or below: open circuit
    leakage_ohm: float = math.inf  # in parallel, at every force
    # 2. creep (Burgers-like)
    a_fast: float = 0.06
    tau_fast_s: float = 5.0
    a_slow: float = 0.06
    tau_slow_s: float = 100.0
    eta_flow_s: float = 2.0e4  # flow grows at F / eta while loaded (inf: no flow)
    tau_recovery_s: float = 200.0  # flow recovery time constant while unloaded
    # 3. hysteresis
    hysteresis_amplitude: float = 0.07  # A: +-A at mid-range
    hysteresis_widths_n: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0)  # play half-widths
    hysteresis_weights: tuple[float, ...] | None = None  # None: equal; normalised to sum 1
    # 4. run-to-run sensitivity
    gain_sigma: float = 0.15  # sigma of ln(gain)
    gain_max_ratio: float = 2.0  # gains of any two runs differ by at most this factor
    exponent_sigma: float = 0.02
    # 5. ohmmeter
    lead_ohm: float = 1.0
    ohmmeter_noise_rel: float = 0.005
    ohmmeter_counts: int = 20000  # 0: ideal meter
    ohmmeter_min_range_ohm: float = 200.0
    ohmmeter_max_range_ohm: float = 20e6
    # 6. load cell
    load_cell_noise_n: float = 0.02
    load_cell_offset_sigma_n: float = 0.03
    load_cell_resolution_n: float = 0.001  # 0: unrounded
    # 7. sampling
    jitter_fraction: float = 0.2
    internal_step_s: float = 0.01
    # 8. out-of-catalogue effects (off by default)
    wear_per_cycle: float = 0.0
    rate_gain_s: float = 0.0
    full_scale_n: float = 50.0
    humidity: float = 0.0
    humidity_period_s: float = 300.0

    def __post_init__(self) -> None:
        for name in _POSITIVE:
            _finite(getattr(self, name), name, low=0.0, strict=True)
        for name in _NON_NEGATIVE:
            _finite(getattr(self, name), name, low=0.0)
        for name in ("wear_per_cycle", "rate_gain_s", "humidity"):
            _finite(getattr(self, name), name)
        for name in ("leakage_ohm", "eta_flow_s", "tau_recovery_s"):
            value = getattr(self, name)
            _check(value > 0 and not math.isnan(value), f"{name} must be > 0 (inf allowed), got {value!r}")
        _check(self.gain_max_ratio >= 1.0, f"gain_max_ratio must be >= 1, got {self.gain_max_ratio!r}")
        _check(self.hysteresis_amplitude < 1.0, "hysteresis_amplitude must be < 1")
        _check(self.jitter_fraction < 1.0, "jitter_fraction must be < 1 (time must increase)")
        _check(0.0 <= self.wear_per_cycle < 1.0, "wear_per_cycle must be in [0, 1)")
        _check(abs(self.humidity) < 1.0, "humidity must be in (-1, 1)")
        _check(self.ohmmeter_counts >= 0, "ohmmeter_counts must be >= 0 (0: ideal meter)")
        _check(
            self.ohmmeter_max_range_ohm >= self.ohmmeter_min_range_ohm,
            "ohmmeter_max_range_ohm must be >= ohmmeter_min_range_ohm",
        )
        _check(len(self.hysteresis_widths_n) > 0, "hysteresis_widths_n must not be empty")
        for r in self.hysteresis_widths_n:
            _finite(r, "hysteresis_widths_n", low=0.0, strict=True)
        if self.hysteresis_weights is not None:
            _check(
                len(self.hysteresis_weights) == len(self.hysteresis_widths_n),
                "hysteresis_weights must have one weight per width",
            )
            for w in self.hysteresis_weights:
                _finite(w, "hysteresis_weights", low=0.0)
            _check(sum(self.hysteresis_weights) > 0, "hysteresis_weights must not all be 0")

    def ideal_instruments(self) -> FsrParams:
        """The same sensor read without noise, quantisation, zero offset or time jitter."""
        return replace(
            self,
            ohmmeter_noise_rel=0.0,
            ohmmeter_counts=0,
            load_cell_noise_n=0.0,
            load_cell_offset_sigma_n=0.0,
            load_cell_resolution_n=0.0,
            jitter_fraction=0.0,
        )

    def static_only(self) -> FsrParams:
        """The same sensor without creep, flow and hysteresis (its static curve only)."""
        return replace(self, a_fast=0.0, a_slow=0.0, eta_flow_s=math.inf, hysteresis_amplitude=0.0)

    def out_of_catalogue(self) -> dict[str, float]:
        """The out-of-catalogue effects that are on, with their values."""
        values = {"wear_per_cycle": self.wear_per_cycle, "rate_gain_s": self.rate_gain_s}
        values["humidity"] = self.humidity
        return {k: v for k, v in values.items() if v != 0.0}

    def weights(self) -> FloatArray:
        """Hysteresis weights, normalised to sum 1."""
        w = np.asarray(self.hysteresis_weights or [1.0] * len(self.hysteresis_widths_n), dtype=np.float64)
        return np.asarray(w / w.sum())


# --------------------------------------------------------------------------------------------
# Protocols


@dataclass(frozen=True)
class Ramp:
    """Ramp the force linearly to ``target_n`` (N, >= 0) at ``rate_n_per_s`` (N/s, > 0)."""

    target_n: float
    rate_n_per_s: float

    def __post_init__(self) -> None:
        _finite(self.target_n, "target_n", low=0.0)
        _finite(self.rate_n_per_s, "rate_n_per_s", low=0.0, strict=True)


@dataclass(frozen=True)
class Hold:
    """Hold the current force for ``duration_s`` (s, >= 0)."""

    duration_s: float

    def __post_init__(self) -> None:
        _finite(self.duration_s, "duration_s", low=0.0)


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
    _check(cycles >= 1, f"cycles must be >= 1, got {cycles}")
    _finite(max_n, "max_n", low=0.0, strict=True)
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


#: The protocols the command line offers, by name (each built with its defaults).
PROTOCOLS: dict[str, Callable[[], Protocol]] = {
    "holds": hold_protocol,
    "calibration": calibration_run,
    "staircase": staircase,
}


# --------------------------------------------------------------------------------------------
# Instruments


def ohmmeter_reading(
    resistance_ohm: FloatArray | Sequence[float],
    counts: int = 20000,
    min_range_ohm: float = 200.0,
    max_range_ohm: float = 20e6,
) -> FloatArray:
    """What an auto-ranging ohmmeter of ``counts`` counts per range displays (noise-free).

    Ranges have full scales ``min_range_ohm * 10^j`` up to ``max_range_ohm``; a range shows
    ``round(R / (full_scale / counts))`` counts, valid below ``counts``; the lowest valid range
    is used. Beyond the top range, and for inf, the reading is inf. ``counts = 0``: no
    quantisation and no range limit.
    """
    r = np.asarray(resistance_ohm, dtype=np.float64)
    if counts == 0:
        return r.copy()
    out = np.full(r.shape, np.inf)
    finite = np.isfinite(r) & (r >= 0.0)
    x = r[finite]
    with np.errstate(divide="ignore"):
        j = np.floor(np.log10(np.maximum(x, 1e-300) / min_range_ohm)) + 1.0
    j = np.maximum(j, 0.0)
    n_ranges = math.floor(math.log10(max_range_ohm / min_range_ohm) + 1e-9) + 1
    value = np.full(x.shape, np.inf)
    pending = np.ones(x.shape, dtype=bool)
    for _ in range(2):  # the estimate j, or one range up when rounding reaches ``counts``
        full_scale = min_range_ohm * 10.0**j
        q = np.round(x / (full_scale / counts))
        ok = pending & (q < counts) & (j < n_ranges)
        shown = q * full_scale / counts  # 12345 * 2000 / 20000 = 1234.5, not 12345 * 0.1
        value = np.where(ok, shown, value)
        pending &= ~ok
        j = j + 1.0
    out[finite] = value
    return out


# --------------------------------------------------------------------------------------------
# The emulator


@dataclass(frozen=True)
class RunConditions:
    """What changes from one run to the next (drawn from the seed and the run index)."""

    gain: float  # on k
    exponent: float  # n of this run
    load_cell_offset_n: float
    humidity_phase_rad: float
    prior_cycles: int = 0  # loading cycles the sensor had seen before the run (wear)


@dataclass(frozen=True, eq=False)
class EmulatedRecord:
    """One emulated run; arrays are per sample, times from the run's start."""

    time_s: FloatArray
    force_n: FloatArray  # the load cell's reading
    true_force_n: FloatArray  # the applied force, noise-free
    resistance_ohm: FloatArray  # the ohmmeter's reading (inf: open / over range)
    sensor_resistance_ohm: FloatArray  # the sensor's true resistance, without lead and meter
    static_resistance_ohm: FloatArray  # the run's static curve at the true force
    effective_force_n: FloatArray  # F_eff = F + x1 + x2 + phi
    run: int
    conditions: RunConditions
    cycles: int  # loading cycles in this run
    protocol_name: str
    seed: int
    params: FsrParams
    sample_interval_s: float

    @property
    def n_samples(self) -> int:
        return int(self.time_s.size)


@dataclass
class _Kelvin:
    a: float
    tau_s: float
    x: float = 0.0


@dataclass(frozen=True)
class FsrEmulator:
    """Emulates runs of one FSR; deterministic for a given ``seed`` and run index."""

    params: FsrParams = field(default_factory=FsrParams)
    seed: int = 0

    def __post_init__(self) -> None:
        _check(int(self.seed) == self.seed and self.seed >= 0, f"seed must be an int >= 0, got {self.seed!r}")

    def _generators(self, run_index: int) -> tuple[np.random.Generator, np.random.Generator]:
        _check(int(run_index) == run_index and run_index >= 0, f"run_index must be >= 0, got {run_index!r}")
        a, b = np.random.SeedSequence([int(self.seed), int(run_index)]).spawn(2)
        return np.random.default_rng(a), np.random.default_rng(b)

    def conditions(self, run_index: int, prior_cycles: int = 0) -> RunConditions:
        """The run's sensitivity gain, exponent, load cell offset and humidity phase."""
        p = self.params
        rng, _ = self._generators(run_index)
        z = rng.standard_normal(3)
        phase = float(rng.uniform(0.0, 2.0 * math.pi))
        half = 0.5 * math.log(p.gain_max_ratio)
        return RunConditions(
            gain=math.exp(min(max(p.gain_sigma * float(z[0]), -half), half)),
            exponent=p.exponent + p.exponent_sigma * float(z[1]),
            load_cell_offset_n=p.load_cell_offset_sigma_n * float(z[2]),
            humidity_phase_rad=phase,
            prior_cycles=prior_cycles,
        )

    def run(
        self,
        protocol: Protocol,
        run_index: int = 0,
        sample_interval_s: float = 0.1,
        *,
        prior_cycles: int = 0,
    ) -> EmulatedRecord:
        """Play ``protocol`` on a rested sensor and record it every ``sample_interval_s`` (+ jitter)."""
        p = self.params
        _finite(sample_interval_s, "sample_interval_s", low=0.0, strict=True)
        _check(prior_cycles >= 0, "prior_cycles must be >= 0")
        cond = self.conditions(run_index, prior_cycles)
        _, rng = self._generators(run_index)

        # 7. timestamps
        duration = protocol.duration_s
        n_max = math.ceil(duration / (sample_interval_s * (1.0 - p.jitter_fraction))) + 2
        steps = sample_interval_s * (1.0 + p.jitter_fraction * rng.uniform(-1.0, 1.0, n_max))
        t = np.concatenate(([0.0], np.cumsum(steps)))
        t = t[t <= duration * (1.0 + 1e-12)]
        noise_r = rng.standard_normal(t.size)
        noise_f = rng.standard_normal(t.size)

        force, f_eff, hyst, slope, cycle_no, n_cycles = self._dynamics(protocol, t)

        # 1-4, 8: conductance
        loaded = force > p.threshold_n
        gain = cond.gain * p.k_s
        g_static = np.where(loaded, gain * np.power(np.maximum(force, 1e-300), cond.exponent), 0.0)
        wear = (1.0 - p.wear_per_cycle) ** (np.maximum(cycle_no - 1, 0) + prior_cycles)
        rate = np.maximum(_MIN_RATE_FACTOR, 1.0 + p.rate_gain_s * slope / p.full_scale_n)
        humid = 1.0 + p.humidity * np.sin(2.0 * math.pi * t / p.humidity_period_s + cond.humidity_phase_rad)
        g_dyn = gain * np.power(np.maximum(f_eff, 1e-300), cond.exponent) * (1.0 + hyst)
        g = np.where(loaded, g_dyn * wear * rate * humid, 0.0)
        r_sensor = _resistance(g, p.leakage_ohm)
        r_static = _resistance(g_static, p.leakage_ohm)

        # 5. ohmmeter
        noisy = (r_sensor + p.lead_ohm) * np.maximum(1.0 + p.ohmmeter_noise_rel * noise_r, 1e-6)
        reading = ohmmeter_reading(
            noisy, p.ohmmeter_counts, p.ohmmeter_min_range_ohm, p.ohmmeter_max_range_ohm
        )

        # 6. load cell
        cell = force + cond.load_cell_offset_n + p.load_cell_noise_n * noise_f
        if p.load_cell_resolution_n > 0.0:
            cell = np.round(cell / p.load_cell_resolution_n) * p.load_cell_resolution_n
        cell = np.maximum(cell, 0.0)

        return EmulatedRecord(
            time_s=t,
            force_n=cell,
            true_force_n=force,
            resistance_ohm=reading,
            sensor_resistance_ohm=r_sensor,
            static_resistance_ohm=r_static,
            effective_force_n=f_eff,
            run=int(run_index),
            conditions=cond,
            cycles=n_cycles,
            protocol_name=protocol.name,
            seed=int(self.seed),
            params=p,
            sample_interval_s=float(sample_interval_s),
        )

    def run_many(
        self, protocol: Protocol, n_runs: int, sample_interval_s: float = 0.1
    ) -> list[EmulatedRecord]:
        """Runs 0 .. n_runs-1 of ``protocol``; wear carries over from run to run."""
        _check(n_runs >= 1, f"n_runs must be >= 1, got {n_runs}")
        out: list[EmulatedRecord] = []
        prior = 0
        for i in range(n_runs):
            rec = self.run(protocol, i, sample_interval_s, prior_cycles=prior)
            prior += rec.cycles
            out.append(rec)
        return out

    def _dynamics(
        self, protocol: Protocol, t: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.int64], int]:
        """Force, effective force, hysteresis term H, slope dF/dt and loading-cycle number at
        the sample times ``t``, and the number of loading cycles of the protocol."""
        p = self.params
        knot_t, knot_f = _with_threshold_crossings(*protocol.knots(), p.threshold_n)
        n = t.size
        force = np.empty(n)
        creep = np.zeros(n)
        slope = np.zeros(n)
        cycle_no = np.zeros(n, dtype=np.int64)
        widths = np.asarray(p.hysteresis_widths_n, dtype=np.float64)
        play = np.zeros(widths.size)
        plays = np.zeros((n, widths.size))
        kelvins = [
            _Kelvin(a, tau) for a, tau in ((p.a_fast, p.tau_fast_s), (p.a_slow, p.tau_slow_s)) if a > 0
        ]
        flow = 0.0
        cycles = 0
        was_loaded = False
        bounds = np.searchsorted(t, knot_t, side="left")
        bounds[-1] = n
        if knot_t.size == 1:  # an empty protocol: 0 N throughout
            force[:] = 0.0
            plays[:] = play
        for j in range(knot_t.size - 1):
            t0, t1, f0, f1 = knot_t[j], knot_t[j + 1], knot_f[j], knot_f[j + 1]
            length = t1 - t0
            s = (f1 - f0) / length
            loaded = 0.5 * (f0 + f1) > p.threshold_n
            if loaded and not was_loaded:
                cycles += 1
            was_loaded = loaded
            n_sub = max(1, math.ceil(length / p.internal_step_s - 1e-9))
            h = length / n_sub
            f_nodes = f0 + s * h * np.arange(n_sub + 1)
            f_nodes[-1] = f1
            lo, hi = int(bounds[j]), int(bounds[j + 1])
            ts = t[lo:hi] - t0
            k = np.clip(np.floor(ts / h).astype(np.int64), 0, n_sub - 1)
            delta = ts - k * h
            fs = f0 + s * ts
            force[lo:hi] = fs
            slope[lo:hi] = s
            cycle_no[lo:hi] = cycles
            fk = f_nodes[k]
            # Kelvin elements: exact exponential updates on the nodes, then to the samples
            for kv in kelvins:
                c = math.exp(-h / kv.tau_s)
                u = kv.a * (f_nodes[1:] - c * f_nodes[:-1] + kv.tau_s * s * math.expm1(-h / kv.tau_s))
                x_nodes = np.empty(n_sub + 1)
                x_nodes[0] = kv.x
                x_nodes[1:] = lfilter([1.0], [1.0, -c], u, zi=[c * kv.x])[0]
                e = np.exp(-delta / kv.tau_s)
                creep[lo:hi] += e * x_nodes[k] + kv.a * (
                    fs - e * fk + kv.tau_s * s * np.expm1(-delta / kv.tau_s)
                )
                kv.x = float(x_nodes[-1])
            # the dashpot's flow: grows while loaded, recovers while unloaded
            if loaded:
                inc = h * (f_nodes[:-1] + f_nodes[1:]) / (2.0 * p.eta_flow_s)
                phi_nodes = flow + np.concatenate(([0.0], np.cumsum(inc)))
                creep[lo:hi] += phi_nodes[k] + delta * (fk + fs) / (2.0 * p.eta_flow_s)
            else:
                phi_nodes = flow * np.exp(-h * np.arange(n_sub + 1) / p.tau_recovery_s)
                creep[lo:hi] += phi_nodes[k] * np.exp(-delta / p.tau_recovery_s)
            flow = float(phi_nodes[-1])
            # play operators: exact on a monotone segment
            if s > 0:
                plays[lo:hi] = np.maximum(fs[:, None] - widths, play)
                play = np.maximum(f1 - widths, play)
            elif s < 0:
                plays[lo:hi] = np.minimum(fs[:, None] + widths, play)
                play = np.minimum(f1 + widths, play)
            else:
                plays[lo:hi] = play
        states = (force[:, None] - plays) / widths
        hyst = -p.hysteresis_amplitude * (states @ p.weights())
        return force, force + creep, hyst, slope, cycle_no, cycles


def _resistance(conductance_s: FloatArray, leakage_ohm: float) -> FloatArray:
    g = conductance_s + (0.0 if math.isinf(leakage_ohm) else 1.0 / leakage_ohm)
    with np.errstate(divide="ignore"):
        return np.asarray(np.where(g > 0.0, 1.0 / np.where(g > 0.0, g, 1.0), np.inf))


def _with_threshold_crossings(
    knot_t: FloatArray, knot_f: FloatArray, threshold_n: float
) -> tuple[FloatArray, FloatArray]:
    """The knots with a knot added wherever a ramp crosses ``threshold_n``."""
    fa, fb = knot_f[:-1], knot_f[1:]
    cross = (np.minimum(fa, fb) < threshold_n) & (np.maximum(fa, fb) > threshold_n)
    if not cross.any():
        return knot_t, knot_f
    ta, tb = knot_t[:-1][cross], knot_t[1:][cross]
    tc = ta + (threshold_n - fa[cross]) / (fb[cross] - fa[cross]) * (tb - ta)
    times = np.concatenate((knot_t, tc))
    forces = np.concatenate((knot_f, np.full(tc.size, threshold_n)))
    order = np.argsort(times, kind="stable")
    return times[order], forces[order]


# --------------------------------------------------------------------------------------------
# Records


def _describe(p: FsrParams, sample_interval_s: float) -> dict[str, str]:
    effects = p.out_of_catalogue()
    parts = [f"{k}={v:g}" for k, v in effects.items()]
    if "humidity" in effects:
        parts[-1] += f" (period {p.humidity_period_s:g} s)"
    counts = f"{p.ohmmeter_counts} counts per range" if p.ohmmeter_counts else "ideal (no quantisation)"
    return {
        "force_reference": (
            f"emulated load cell, noise {p.load_cell_noise_n:g} N rms, zero offset per run "
            f"(sigma {p.load_cell_offset_sigma_n:g} N), resolution {p.load_cell_resolution_n:g} N, "
            "no negative readings"
        ),
        "ohmmeter": (
            f"2-wire, leads {p.lead_ohm:g} ohm included, {100 * p.ohmmeter_noise_rel:g} % rms noise, "
            f"{counts}, auto-ranging {p.ohmmeter_min_range_ohm:g} .. {p.ohmmeter_max_range_ohm:g} ohm, "
            "open and over range as inf"
        ),
        "sample_interval_s": f"{sample_interval_s:g} (jitter +-{100 * p.jitter_fraction:g} %)",
        "out_of_catalogue": ", ".join(parts) if parts else "none",
    }


def _joined(values: Sequence[object]) -> str:
    distinct = list(dict.fromkeys(str(v) for v in values))
    return distinct[0] if len(distinct) == 1 else ", ".join(str(v) for v in values)


def _fmt(values: FloatArray, spec: str) -> list[str]:
    return [spec % v if math.isfinite(v) else "inf" for v in values.tolist()]


def write_record(
    path: str | os.PathLike[str],
    records: Sequence[EmulatedRecord],
    channel: str = "0",
    *,
    gap_s: float = 60.0,
    metadata: Mapping[str, object] | None = None,
) -> Path:
    """Write ``records`` as one record file (``docs/record-format.md``), atomically.

    Columns ``time_s,channel,resistance_ohm,force_n`` (the ohmmeter's and the load cell's
    readings). Time continues across runs: each run starts ``gap_s`` after the previous
    run's last sample; ``# runs:`` lists the start times (s, comma separated). ``metadata``
    adds or overrides ``# key: value`` lines. Returns the path written.
    """
    _check(len(records) > 0, "write_record needs at least one record")
    _finite(gap_s, "gap_s", low=0.0, strict=True)
    _check(
        bool(channel.strip()) and "," not in channel and "\n" not in channel, f"bad channel name {channel!r}"
    )
    first = records[0]
    _check(
        all(r.params == first.params for r in records),
        "records written together must come from the same FsrParams",
    )
    starts: list[float] = []
    start = 0.0
    for rec in records:
        starts.append(start)
        last = float(rec.time_s[-1]) if rec.n_samples else 0.0
        start = start + last + gap_s
    meta: dict[str, object] = {
        "source": "sim_device.fsr_emulator",
        "sensor": "emulated FSR (sim_device.fsr_emulator)",
        "time": "real",
        "runs": ", ".join(f"{s:.6f}" for s in starts),
        "seed": _joined([r.seed for r in records]),
        "protocol": _joined([r.protocol_name for r in records]),
        **_describe(first.params, first.sample_interval_s),
    }
    meta.update(metadata or {})
    lines = [f"# {k}: {str(v).replace(chr(10), ' ')}\n" for k, v in meta.items()]
    lines.append("time_s,channel,resistance_ohm,force_n\n")
    for rec, s0 in zip(records, starts, strict=True):
        cols = (
            _fmt(rec.time_s + s0, "%.6f"),
            _fmt(rec.resistance_ohm, "%.10g"),
            _fmt(rec.force_n, "%.10g"),
        )
        lines.extend(f"{a},{channel},{b},{c}\n" for a, b, c in zip(*cols, strict=True))
    target = Path(path)
    if not target.parent.is_dir():
        raise FileNotFoundError(f"cannot write {target}: no directory {target.parent}")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.writelines(lines)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return target
