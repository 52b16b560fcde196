"""Parameters of the emulated FSR and its bench (``sim_device.fsr_emulator``), with their checks.

Every parameter and its physics is described in the docstring of ``sim_device.fsr_emulator``;
names carry their units (``k_s`` S, ``tau_fast_s`` s, ``threshold_n`` N).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def require(ok: bool, message: str) -> None:
    """Raise ``ValueError(message)`` unless ``ok``: bad input gets a sentence, not a traceback."""
    if not ok:
        raise ValueError(message)


def require_finite(value: float, name: str, *, low: float | None = None, strict: bool = False) -> None:
    """``value`` must be finite and at or above ``low`` (above it when ``strict``)."""
    require(math.isfinite(value), f"{name} must be finite, got {value!r}")
    if low is not None:
        bad = value <= low if strict else value < low
        require(not bad, f"{name} must be {'>' if strict else '>='} {low:g}, got {value!r}")


@dataclass(frozen=True)
class CreepElement:
    """One element of the creep chain (section 2b): a Kelvin element whose state ``x`` (N)
    relaxes towards ``amplitude * F`` with ``tau_load_s`` (s) while it charges (``|x|``
    grows towards ``|amplitude| F``) and with ``tau_recovery_s`` (s) while it discharges.

    ``amplitude`` is dimensionless, in (-1, 1): positive, creep (the sensor reads more and
    more under a held load); negative, a set (the sensor reads less after a higher load).
    """

    amplitude: float
    tau_load_s: float
    tau_recovery_s: float

    def __post_init__(self) -> None:
        require_finite(self.amplitude, "creep element amplitude")
        require(
            -1.0 < self.amplitude < 1.0, f"creep element amplitude must be in (-1, 1), got {self.amplitude!r}"
        )
        require_finite(self.tau_load_s, "creep element tau_load_s", low=0.0, strict=True)
        require_finite(self.tau_recovery_s, "creep element tau_recovery_s", low=0.0, strict=True)


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
_NON_NEGATIVE += ("load_cell_lag_s", "burst_gap_s", "ohmmeter_noise_ohm")


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
    # 2b. creep chain: Kelvin elements that load and recover with different time constants
    creep_chain: tuple[CreepElement, ...] = ()
    # 3. hysteresis
    hysteresis_amplitude: float = 0.07  # A: +-A at mid-range
    hysteresis_widths_n: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0)  # play half-widths
    hysteresis_weights: tuple[float, ...] | None = None  # None: equal; normalised to sum 1
    # 4. run-to-run sensitivity
    gain_sigma: float = 0.15  # sigma of ln(gain)
    gain_max_ratio: float = 2.0  # gains of any two runs differ by at most this factor
    exponent_sigma: float = 0.02
    run_gains: tuple[float, ...] = ()  # if given: run r's gain is run_gains[r % len], not drawn
    # 5. ohmmeter
    lead_ohm: float = 1.0
    ohmmeter_noise_rel: float = 0.005
    ohmmeter_noise_ohm: float = 0.0  # added in quadrature to the relative noise, ohm rms
    ohmmeter_counts: int = 20000  # 0: ideal meter
    ohmmeter_min_range_ohm: float = 200.0
    ohmmeter_max_range_ohm: float = 20e6
    # 6. load cell
    load_cell_noise_n: float = 0.02
    load_cell_offset_sigma_n: float = 0.03
    load_cell_resolution_n: float = 0.001  # 0: unrounded
    load_cell_lag_s: float = 0.0  # the reference reads the force applied this long before
    # 7. sampling
    jitter_fraction: float = 0.2
    internal_step_s: float = 0.01
    burst_size: int = 0  # samples per burst (0: no bursts); a burst_gap_s interval after each
    burst_gap_s: float = 0.0
    # 8. out-of-catalogue effects (off by default)
    wear_per_cycle: float = 0.0
    rate_gain_s: float = 0.0
    full_scale_n: float = 50.0
    humidity: float = 0.0
    humidity_period_s: float = 300.0

    def __post_init__(self) -> None:
        for name in _POSITIVE:
            require_finite(getattr(self, name), name, low=0.0, strict=True)
        for name in _NON_NEGATIVE:
            require_finite(getattr(self, name), name, low=0.0)
        for name in ("wear_per_cycle", "rate_gain_s", "humidity"):
            require_finite(getattr(self, name), name)
        for name in ("leakage_ohm", "eta_flow_s", "tau_recovery_s"):
            value = getattr(self, name)
            require(value > 0 and not math.isnan(value), f"{name} must be > 0 (inf allowed), got {value!r}")
        require(self.gain_max_ratio >= 1.0, f"gain_max_ratio must be >= 1, got {self.gain_max_ratio!r}")
        require(self.hysteresis_amplitude < 1.0, "hysteresis_amplitude must be < 1")
        require(self.jitter_fraction < 1.0, "jitter_fraction must be < 1 (time must increase)")
        require(0.0 <= self.wear_per_cycle < 1.0, "wear_per_cycle must be in [0, 1)")
        require(abs(self.humidity) < 1.0, "humidity must be in (-1, 1)")
        require(self.ohmmeter_counts >= 0, "ohmmeter_counts must be >= 0 (0: ideal meter)")
        require(
            self.ohmmeter_max_range_ohm >= self.ohmmeter_min_range_ohm,
            "ohmmeter_max_range_ohm must be >= ohmmeter_min_range_ohm",
        )
        require(self.burst_size >= 0, f"burst_size must be >= 0 (0: no bursts), got {self.burst_size!r}")
        require(
            self.burst_size == 0 or self.burst_gap_s > 0.0,
            f"burst_gap_s must be > 0 when burst_size is given, got {self.burst_gap_s!r}",
        )
        for g in self.run_gains:
            require_finite(g, "run_gains", low=0.0, strict=True)
        amplitudes = [self.a_fast, self.a_slow, *(e.amplitude for e in self.creep_chain)]
        require(
            1.0 + sum(amplitudes) > 0.0,
            "the creep amplitudes (a_fast, a_slow and the chain's) must sum to more than -1, "
            f"got {sum(amplitudes)!r}",
        )
        require(len(self.hysteresis_widths_n) > 0, "hysteresis_widths_n must not be empty")
        for r in self.hysteresis_widths_n:
            require_finite(r, "hysteresis_widths_n", low=0.0, strict=True)
        if self.hysteresis_weights is not None:
            require(
                len(self.hysteresis_weights) == len(self.hysteresis_widths_n),
                "hysteresis_weights must have one weight per width",
            )
            for w in self.hysteresis_weights:
                require_finite(w, "hysteresis_weights", low=0.0)
            require(sum(self.hysteresis_weights) > 0, "hysteresis_weights must not all be 0")

    def ideal_instruments(self) -> FsrParams:
        """The same sensor read without noise, quantisation, zero offset, lag or time jitter."""
        return replace(
            self,
            ohmmeter_noise_rel=0.0,
            ohmmeter_noise_ohm=0.0,
            ohmmeter_counts=0,
            load_cell_noise_n=0.0,
            load_cell_offset_sigma_n=0.0,
            load_cell_resolution_n=0.0,
            jitter_fraction=0.0,
            load_cell_lag_s=0.0,
        )

    def static_only(self) -> FsrParams:
        """The same sensor without creep, flow, creep chain and hysteresis (its static curve only)."""
        return replace(
            self, a_fast=0.0, a_slow=0.0, eta_flow_s=math.inf, hysteresis_amplitude=0.0, creep_chain=()
        )

    def out_of_catalogue(self) -> dict[str, float]:
        """The out-of-catalogue effects that are on, with their values."""
        values = {"wear_per_cycle": self.wear_per_cycle, "rate_gain_s": self.rate_gain_s}
        values["humidity"] = self.humidity
        return {k: v for k, v in values.items() if v != 0.0}

    def weights(self) -> FloatArray:
        """Hysteresis weights, normalised to sum 1."""
        w = np.asarray(self.hysteresis_weights or [1.0] * len(self.hysteresis_widths_n), dtype=np.float64)
        return np.asarray(w / w.sum())


@dataclass(frozen=True)
class RunConditions:
    """What changes from one run to the next (drawn from the seed and the run index)."""

    gain: float  # on k
    exponent: float  # n of this run
    load_cell_offset_n: float
    humidity_phase_rad: float
    prior_cycles: int = 0  # loading cycles the sensor had seen before the run (wear)
