"""The read-out of the paper's Fig. 4b: a voltage divider and an ADC (eq. 18).

The sensor r sits between the supply V+ and the output node; the fixed resistor R_ref
goes from the output node to ground::

    V_o = R_ref / (R_ref + r) * V+      =>      r = R_ref (V+ / V_o - 1)

The ADC is ratiometric (its reference is V+), so counts = V_o / V+ * (2^bits - 1). The rails
are meaningful: 0 counts is an open sensor (r = inf), full scale a shorted one (r = 0).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


class DividerStatus(enum.IntEnum):
    """What a divider reading says about the sensor."""

    OK = 0
    OPEN = 1  # output at ground: no current through the sensor
    SHORT = 2  # output at the supply: the sensor has no resistance
    INVALID = 3  # counts outside the converter's range, or not a number


@dataclass(frozen=True)
class Divider:
    """Divider and converter constants (eq. 18)."""

    supply_v: float = 5.0
    reference_ohm: float = 10e3
    adc_bits: int = 16

    def __post_init__(self) -> None:
        if not (np.isfinite(self.supply_v) and self.supply_v > 0.0):
            raise ValueError(f"supply_v = {self.supply_v!r} must be in (0, inf) V")
        if not (np.isfinite(self.reference_ohm) and self.reference_ohm > 0.0):
            raise ValueError(f"reference_ohm = {self.reference_ohm!r} must be in (0, inf) ohm")
        if not (isinstance(self.adc_bits, int) and 8 <= self.adc_bits <= 24):
            raise ValueError(f"adc_bits = {self.adc_bits!r} must be an integer in [8, 24]")

    @property
    def full_scale(self) -> int:
        return int(2**self.adc_bits - 1)

    # resistance -> voltage -> counts
    def output_voltage(self, resistance_ohm: ArrayLike) -> FloatArray:
        """V_o for a sensor resistance; inf gives 0 V (open), 0 gives V+ (short)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            v = self.supply_v * self.reference_ohm / (self.reference_ohm + r)
        return np.asarray(np.where(np.isinf(r), 0.0, v))

    def counts(self, voltage_v: ArrayLike) -> NDArray[np.int64]:
        """Ideal converter: rounded and clipped to [0, full scale]."""
        v = np.asarray(voltage_v, dtype=np.float64)
        code = np.rint(v / self.supply_v * self.full_scale)
        return np.clip(code, 0, self.full_scale).astype(np.int64)

    # counts -> voltage -> resistance
    def voltage(self, counts: ArrayLike) -> FloatArray:
        """Output voltage for converter counts."""
        return np.asarray(np.asarray(counts, dtype=np.float64) / self.full_scale * self.supply_v)

    def resistance(self, counts: ArrayLike) -> tuple[FloatArray, NDArray[np.int8]]:
        """Sensor resistance (ohm) and a ``DividerStatus`` per reading.

        Open reads +inf, short reads 0; out-of-range or NaN counts read NaN. Never divides
        by zero.
        """
        fs = self.full_scale
        raw = np.asarray(counts)
        if raw.dtype.kind in "iu":  # integer counts (the polling path): no NaN to look for
            open_ = raw == 0
            short = raw == fs
            invalid = (raw > fs) | (raw < 0) if raw.dtype.kind == "i" else raw > fs
            with np.errstate(divide="ignore"):
                r = (fs / raw - 1.0) * self.reference_ohm  # 0 counts: +inf; full scale: 0
        else:
            c = raw.astype(np.float64)
            with np.errstate(invalid="ignore"):
                invalid = ~np.isfinite(c) | (c < 0.0) | (c > fs)
                open_ = ~invalid & (c == 0.0)
                short = ~invalid & (c == fs)
            ok = ~(invalid | open_ | short)
            r = self.reference_ohm * (fs / np.where(ok, c, 1.0) - 1.0)
            r[open_] = np.inf
            r[short] = 0.0
        status = open_.view(np.int8) + short.view(np.int8) * np.int8(int(DividerStatus.SHORT))
        if invalid.any():
            r = np.where(invalid, np.nan, r)
            status[invalid] = int(DividerStatus.INVALID)
        return np.asarray(r, dtype=np.float64), status


@dataclass(frozen=True)
class ConductanceLine:
    """The paper's calibration line C = m F + n (conductance C = 1/r in siemens)."""

    slope_s_per_n: float
    intercept_s: float

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """F = (1/r - n) / m; an open sensor (inf) gives F at C = 0."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.where(np.isinf(r), 0.0, 1.0 / r)
        return np.asarray((c - self.intercept_s) / self.slope_s_per_n)

    def conductance(self, force_n: ArrayLike) -> FloatArray:
        return np.asarray(self.slope_s_per_n * np.asarray(force_n, dtype=np.float64) + self.intercept_s)

    @classmethod
    def fit(cls, force_n: ArrayLike, resistance_ohm: ArrayLike) -> ConductanceLine:
        """Least-squares line through (F, 1/r) over finite, positive resistances."""
        f = np.asarray(force_n, dtype=np.float64).ravel()
        r = np.asarray(resistance_ohm, dtype=np.float64).ravel()
        use = np.isfinite(f) & np.isfinite(r) & (r > 0.0)
        if np.count_nonzero(use) < 2 or np.ptp(f[use]) == 0.0:
            raise ValueError("a conductance line needs at least two distinct forces")
        slope, intercept = np.polyfit(f[use], 1.0 / r[use], 1)
        return cls(float(slope), float(intercept))
