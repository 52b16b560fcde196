"""Per-channel conversions that replace the physical model: the paper's line and a lookup.

``tactile-gateway calibrate --model line|lookup|auto`` writes, for a channel whose physical
model loses on held-out force, a ``[line.<name>]`` or ``[lookup.<name>]`` table
(``docs/calibration.md``). A channel with one reads force without the physical model:

* ``LineConversion``: the conductance line C = m F + n, so F = (1/R - n) / m, calibrated over
  [force_min_n, force_max_n];
* ``LookupConversion``: F by linear interpolation in ln R between knots (resistance strictly
  increasing, force non-increasing), calibrated over the knots' forces.

Both are stateless (no creep state: the static estimate equals the force). Beyond the
calibrated range a channel still reads a force, extrapolated along its calibration (the line
along itself; the lookup along its end segments in ln R) and flagged ``EXTRAPOLATED``: a
calibration is not a blindfold. A force at or below 0 N, and an open sensor, read 0 N
``NO_CONTACT``; so does a line with n < 0 below its ``force_min_n`` (below its zero-conductance
force -n/m a sensor at rest would read a phantom force; see ``LineConversion``). A NaN, zero
or negative resistance is ``INVALID``; the smallest resistance the runtime passes for a short
rail read as a reading (a device with fault bitmaps, ``_SHORT_RAIL_OHM``) is ``SATURATED``
with the calibrated upper bound, as no extrapolation means anything there.
``ConversionSet`` evaluates every converted channel of a device at once, each kind
vectorised over its channels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .curves import CurveChannel, CurveError, KnotTable, curve_from_table
from .curves import finite_value as _finite
from .inversion import ForceStatus

__all__ = [
    "CONVERSION_KINDS",
    "Conversion",
    "ConversionError",
    "ConversionSet",
    "LineConversion",
    "LookupConversion",
    "conversion_from_table",
]

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]
BoolArray = NDArray[np.bool_]

#: The calibration-file tables that name a conversion, by kind (``curve``: a static curve with
#: drift correction on top, ``gateway.model.curves``; tracked, not stateless).
CONVERSION_KINDS = ("line", "lookup", "curve")
_LINE_KEYS = ("slope_s_per_n", "intercept_s", "force_min_n", "force_max_n", "held_out_force_rms_n")
_LOOKUP_KEYS = ("resistance_ohm", "force_n", "held_out_force_rms_n")

_OK, _NO_CONTACT, _SATURATED, _INVALID, _EXTRAPOLATED = (
    int(ForceStatus.OK),
    int(ForceStatus.NO_CONTACT),
    int(ForceStatus.SATURATED),
    int(ForceStatus.INVALID),
    int(ForceStatus.EXTRAPOLATED),
)
#: A force at or below this reads 0 N no contact: the unloaded-baseline correction puts a
#: channel at rest at 0 N only up to rounding (about 1e-17 N), never a nanonewton.
ZERO_FORCE_N = 1e-9
#: The runtime's reading of a short rail when the device's fault bitmaps say the channel is
#: not shorted (``runtime.status_tables._TINY_OHM``): less resistance than the converter
#: resolves, so saturated, not a force extrapolated to 1e300 N.
_SHORT_RAIL_OHM = float(np.finfo(np.float64).tiny)


#: A conversion's value outside its allowed range (``key`` names the field): the curves'
#: error, one type for every calibration table.
ConversionError = CurveError


@dataclass(frozen=True)
class LineConversion:
    """F = (1/R - n) / m, calibrated over [force_min_n, force_max_n] (m in S/N, n in S,
    forces in N); beyond the range the line reads along itself, flagged extrapolated.

    With n < 0 the line's conductance is zero at F = -n/m: an open sensor (0 S) or a nearly
    open one would read about -n/m newtons, a phantom force at rest. So ``force_min_n`` must
    lie above -n/m, and below ``force_min_n`` such a line reads 0 N ``NO_CONTACT`` instead of
    extrapolating down (with n >= 0 the line extrapolates down to 0 N, where a sensor at rest
    lies: conductance n or less)."""

    slope_s_per_n: float
    intercept_s: float
    force_min_n: float
    force_max_n: float

    def __post_init__(self) -> None:
        m = _finite("slope_s_per_n", self.slope_s_per_n, "S/N")
        if not m > 0.0:
            raise ConversionError(
                "slope_s_per_n", f"{m!r} is out of range; allowed: (0, inf) S/N (conductance rises with F)"
            )
        _finite("intercept_s", self.intercept_s, "S")
        low = _finite("force_min_n", self.force_min_n, "N")
        high = _finite("force_max_n", self.force_max_n, "N")
        if not low > 0.0:
            raise ConversionError("force_min_n", f"{low!r} is out of range; allowed: (0, inf) N")
        if not high > low:
            raise ConversionError(
                "force_max_n", f"{high!r} is out of range; allowed: (force_min_n = {low!r}, inf) N"
            )
        zero_n = -self.intercept_s / m
        if not m * low + self.intercept_s > 0.0:
            # below -n/m the line's conductance is <= 0: a sensor at rest (open, or a tiny
            # conductance) would read about -n/m newtons instead of no contact
            raise ConversionError(
                "force_min_n",
                f"{low!r} is out of range for this line (intercept_s = {self.intercept_s:.6g} S < 0): "
                f"the line reaches zero conductance at {zero_n:.4g} N, so below it a sensor at rest "
                f"would read a force; allowed: ({zero_n:.4g}, inf) N (calibrate writes 1.1 x that)",
            )

    @property
    def unloaded_conductance_s(self) -> float:
        """The line's conductance at 0 N, n (S; 0 when n <= 0: open there)."""
        return max(0.0, self.intercept_s)


@dataclass(frozen=True)
class LookupConversion:
    """F against ln R through the knots ``(resistance_ohm[i], force_n[i])``; beyond the ends
    along the end segments (``ConversionSet``), flagged extrapolated."""

    resistance_ohm: tuple[float, ...]
    force_n: tuple[float, ...]

    def __post_init__(self) -> None:
        for key, values in (("resistance_ohm", self.resistance_ohm), ("force_n", self.force_n)):
            if not isinstance(values, tuple) or len(values) < 2:
                raise ConversionError(key, f"expected at least 2 points, got {values!r}")
        if len(self.resistance_ohm) != len(self.force_n):
            raise ConversionError(
                "force_n",
                f"{len(self.force_n)} forces for {len(self.resistance_ohm)} resistances; one per resistance",
            )
        r = [_finite(f"resistance_ohm[{i}]", v, "ohm") for i, v in enumerate(self.resistance_ohm)]
        f = [_finite(f"force_n[{i}]", v, "N") for i, v in enumerate(self.force_n)]
        for i in range(len(r)):
            if not r[i] > 0.0:
                raise ConversionError(
                    f"resistance_ohm[{i}]", f"{r[i]!r} is out of range; allowed: (0, inf) ohm"
                )
            if i and not r[i] > r[i - 1]:
                raise ConversionError(
                    f"resistance_ohm[{i}]",
                    f"{r[i]!r} after {r[i - 1]!r}: resistances must be strictly increasing",
                )
            if i and f[i] > f[i - 1]:
                raise ConversionError(
                    f"force_n[{i}]",
                    f"{f[i]!r} after {f[i - 1]!r}: forces must not increase with resistance (non-increasing)",
                )
        if not f[0] > f[-1]:
            raise ConversionError("force_n", f"all forces are {f[0]!r}: the lookup needs a force range")

    @property
    def unloaded_conductance_s(self) -> float:
        """The conductance where the lookup reaches 0 N (S): inside the table where its forces
        go that low, else on its last sloped segment extended in ln R."""
        log_r = np.log(np.asarray(self.resistance_ohm))
        f = np.asarray(self.force_n)
        if f[0] <= 0.0:  # never above 0 N: every reading is no contact
            return float(np.exp(-log_r[0]))
        if f[-1] > 0.0:
            k = int(np.flatnonzero(f > f[-1])[-1])  # the last knot above the lowest force
            return float(np.exp(-(log_r[-1] + f[-1] * (log_r[-1] - log_r[k]) / (f[k] - f[-1]))))
        j = int(np.flatnonzero(f <= 0.0)[0])  # the first knot at or below 0 N (j >= 1)
        t = f[j - 1] / (f[j - 1] - f[j])
        return float(np.exp(-(log_r[j - 1] + t * (log_r[j] - log_r[j - 1]))))


Conversion = LineConversion | LookupConversion | CurveChannel


def conversion_from_table(
    kind: str, data: Mapping[str, object], force_min_n: float, force_max_n: float
) -> Conversion:
    """A conversion from a calibration file's ``[line.<name>]`` / ``[lookup.<name>]`` table;
    a line without its own force range takes the channel's (``force_min_n``/``force_max_n``).
    ``ConversionError`` names the key."""
    if kind == "curve":
        return curve_from_table(data)
    allowed = _LINE_KEYS if kind == "line" else _LOOKUP_KEYS
    # the model imports nothing of ours, so not ``gateway.keys.check_keys``: the error names the key
    for key in data:
        if key not in allowed:
            raise ConversionError(key, f"unknown key; allowed: {', '.join(allowed)}")
    if "held_out_force_rms_n" in data:
        _finite("held_out_force_rms_n", data["held_out_force_rms_n"], "N")
    required = allowed[:2]
    for key in required:
        if key not in data:
            need = " and ".join(required)
            raise ConversionError(key, f"required key is missing ({kind} tables need {need})")
    if kind == "line":
        return LineConversion(
            slope_s_per_n=data["slope_s_per_n"],  # type: ignore[arg-type]  # checked by the dataclass
            intercept_s=data["intercept_s"],  # type: ignore[arg-type]
            force_min_n=data.get("force_min_n", force_min_n),  # type: ignore[arg-type]
            force_max_n=data.get("force_max_n", force_max_n),  # type: ignore[arg-type]
        )
    points: list[tuple[float, ...]] = []
    for key in required:
        values = data[key]
        if not isinstance(values, list):
            raise ConversionError(key, f"expected an array of numbers, got {values!r}")
        points.append(tuple(values))
    return LookupConversion(points[0], points[1])


class ConversionSet:
    """Every converted channel of a device: positions and parameters, per kind, as arrays."""

    def __init__(self, conversions: Sequence[Conversion | None]) -> None:
        lines = [(k, c) for k, c in enumerate(conversions) if isinstance(c, LineConversion)]
        lookups = [(k, c) for k, c in enumerate(conversions) if isinstance(c, LookupConversion)]
        self.line_pos = np.array([k for k, _ in lines], dtype=np.intp)
        self.slope = np.array([c.slope_s_per_n for _, c in lines], dtype=np.float64)
        self.intercept = np.array([c.intercept_s for _, c in lines], dtype=np.float64)
        self.line_low = np.array([c.force_min_n for _, c in lines], dtype=np.float64)
        self.line_high = np.array([c.force_max_n for _, c in lines], dtype=np.float64)
        # the resistances at the bounds: a resistance is compared with them, as the inversion
        # compares R with R(force_min/max), so that a force at a bound is inside the range
        # (LineConversion checks that m force_min_n + n > 0)
        self.line_r_low = 1.0 / (self.slope * self.line_low + self.intercept)
        self.line_r_high = 1.0 / (self.slope * self.line_high + self.intercept)
        #: lines with n < 0 read no contact below their lower bound (no phantom force at rest)
        self.line_floor = self.intercept < 0.0
        self.lookup_pos = np.array([k for k, _ in lookups], dtype=np.intp)
        self.knots = KnotTable([(c.resistance_ohm, c.force_n) for _, c in lookups])
        self.lookup_high = self.knots.high_n
        self.lookup_low = np.maximum(self.knots.low_n, 0.0)
        self.positions = np.concatenate([self.line_pos, self.lookup_pos])
        self.unloaded_ohm = np.array(
            [1.0 / g if g > 0.0 else np.inf for g in (c.unloaded_conductance_s for _, c in lines + lookups)],
            dtype=np.float64,
        )

    def apply(self, resistance_ohm: FloatArray, force_n: FloatArray, status: StatusArray) -> None:
        """Write force (N) and ``ForceStatus`` of the converted channels into the device's arrays."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if self.line_pos.size:
                r = resistance_ohm[self.line_pos]
                f = (np.where(np.isinf(r), 0.0, 1.0 / r) - self.intercept) / self.slope
                force_n[self.line_pos], status[self.line_pos] = self._classify(
                    f,
                    r,
                    (f <= ZERO_FORCE_N) | (self.line_floor & (r >= self.line_r_low)),
                    (r > self.line_r_low) | (r < self.line_r_high),
                    self.line_high,
                )
            if self.lookup_pos.size:
                r = resistance_ohm[self.lookup_pos]
                f = self.knots.force(np.log(r))
                force_n[self.lookup_pos], status[self.lookup_pos] = self._classify(
                    f, r, f <= ZERO_FORCE_N, (f < self.lookup_low) | (f > self.lookup_high), self.lookup_high
                )

    @staticmethod
    def _classify(
        f: FloatArray, r: FloatArray, no_contact: BoolArray, outside: BoolArray, high: FloatArray
    ) -> tuple[FloatArray, StatusArray]:
        """Force (N) and status: NaN ``INVALID`` where the resistance is not > 0, the upper
        bound ``SATURATED`` at the short rail, 0 N ``NO_CONTACT`` where ``no_contact``, else
        the force, ``EXTRAPOLATED`` where it lies ``outside`` the calibrated range."""
        invalid = ~(r > 0.0)
        short = ~invalid & (r <= _SHORT_RAIL_OHM)
        code = np.where(no_contact, _NO_CONTACT, np.where(outside, _EXTRAPOLATED, _OK))
        status = np.where(invalid, _INVALID, np.where(short, _SATURATED, code)).astype(np.int8)
        out = np.where(invalid, np.nan, np.where(short, high, np.where(no_contact, 0.0, f)))
        return out, status
