"""One calibrated channel: a static curve, its sensitivity, its dynamics and its range.

``CurveChannel`` is the one calibration form every empirical calibration loads into, whatever
table it was written as (``from_table``):

* ``[line.<name>]``: the paper's conductance line, static (``slope_s_per_n``, ``intercept_s``,
  optional ``force_min_n``/``force_max_n``, else the channel's force range);
* ``[lookup.<name>]``: a monotone lookup, static (``resistance_ohm``, ``force_n``), calibrated
  over its knots' forces;
* ``[curve.<name>]``: any static curve (``kind``) with a sensitivity (``gain``, ``offset_n``:
  x = curve(R / gain) + offset_n), dynamics (``drift.Drift``) and a calibrated range.

The rules of reading a force (``tracker``) are the channel's, the same on every path:

* a force at or below ``ZERO_FORCE_N`` reads 0 N no contact; an open sensor carries no load;
* a curve whose zero-conductance reading is above 0 N (a line with c < 0, or a positive
  ``offset_n``) would read a phantom force on a nearly open sensor: its ``force_min_n`` must lie
  above that reading (``LINE_ZERO_MARGIN`` x it is what ``calibrate`` writes), and below
  ``force_min_n`` it reads no contact instead of extrapolating down;
* outside [force_min_n, force_max_n] a force is still read along the curve and flagged
  extrapolated.

``table()`` writes the ``[curve.<name>]`` body back (``from_table`` reads it to the same object).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .drift import DRIFT_KEYS, Drift
from .frontend_base import FrontEnd
from .static_curves import (
    CURVE_KEYS,
    CURVE_KINDS,
    CountsLookupCurve,
    CurveError,
    LineCurve,
    LookupCurve,
    StaticCurve,
    curve_body_from_table,
    finite_value,
    positive_value,
)

__all__ = [
    "CONVERSION_KINDS",
    "LINE_ZERO_MARGIN",
    "ZERO_FORCE_N",
    "CurveChannel",
    "channel_from_table",
    "curve_from_table",
]

FloatArray = NDArray[np.float64]

_NO_DRIFT = Drift()
#: The calibration-file tables that name a channel's conversion, by kind.
CONVERSION_KINDS = ("line", "lookup", "curve")
#: A force at or below this reads 0 N no contact: the unloaded-baseline correction puts a
#: channel at rest at 0 N only up to rounding (about 1e-17 N), never a nanonewton.
ZERO_FORCE_N = 1e-9
#: A curve that reads a force at zero conductance starts this factor above it.
LINE_ZERO_MARGIN = 1.1
_COMMON_KEYS = ("kind", "gain", "offset_n", "force_min_n", "force_max_n", "held_out_force_rms_n")
_LINE_KEYS = ("slope_s_per_n", "intercept_s", "force_min_n", "force_max_n", "held_out_force_rms_n")
_LOOKUP_KEYS = ("resistance_ohm", "counts", "force_n", "held_out_force_rms_n")


@dataclass(frozen=True)
class CurveChannel:
    """One channel read through a curve: static curve, sensitivity, dynamics, calibrated range
    [force_min_n, force_max_n] (N)."""

    curve: StaticCurve
    drift: Drift = _NO_DRIFT
    gain: float = 1.0
    offset_n: float = 0.0
    force_min_n: float = 0.0
    force_max_n: float = math.inf
    #: the table it was read from or is written as: ``curve`` (default), ``line`` or ``lookup``
    table_kind: str = "curve"

    def __post_init__(self) -> None:
        positive_value("gain", self.gain, "")
        finite_value("offset_n", self.offset_n, "N")
        low = self.force_min_n
        if isinstance(low, bool) or not isinstance(low, int | float) or math.isnan(low) or low < 0.0:
            raise CurveError("force_min_n", f"{low!r} is out of range; allowed: [0, inf) N")
        high = self.force_max_n
        if isinstance(high, bool) or not isinstance(high, int | float) or not high > low:
            raise CurveError(
                "force_max_n", f"{high!r} is out of range; allowed: (force_min_n = {low!r}, inf] N"
            )
        floor = self.zero_conductance_force_n
        if floor > 0.0 and not low > floor:
            raise CurveError(
                "force_min_n",
                f"{low!r} is out of range for this curve: it reaches zero conductance at {floor:.4g} N "
                f"(a nearly open sensor reads that), so below it a sensor at rest would read a force; "
                f"allowed: ({floor:.4g}, inf) N (calibrate writes {LINE_ZERO_MARGIN} x that)",
            )

    @property
    def zero_conductance_force_n(self) -> float:
        """What the channel reads as its conductance tends to 0 S (N; -inf for a lookup)."""
        return self.curve.force_at_zero_conductance_n + self.offset_n

    @property
    def no_contact_below_n(self) -> float:
        """Readings at or below this force (N) are no contact: ``force_min_n`` on a curve with
        a phantom force at zero conductance, else ``ZERO_FORCE_N``."""
        return self.force_min_n if self.zero_conductance_force_n > 0.0 else ZERO_FORCE_N

    @property
    def unloaded_resistance_ohm(self) -> float:
        """The resistance at which the channel reads 0 N (ohm; inf where it reads a force at
        any finite resistance): where an unloaded-baseline correction puts a channel at rest."""
        g = self._conductance_at_zero_s() / self.gain
        return 1.0 / g if g > 0.0 else math.inf

    def _conductance_at_zero_s(self) -> float:
        """The curve's conductance (S, before the gain) where it reads x = 0 N."""
        target = -self.offset_n
        curve = self.curve
        if isinstance(curve, LineCurve):
            return max(float(curve.conductance(target)), 0.0)
        if not isinstance(curve, LookupCurve | CountsLookupCurve):
            return 0.0 if target <= 0.0 else float(1.0 / curve.resistance(target))
        # along the table's own abscissa (ln R, or a counts table's signed code), increasing with R
        u = np.asarray(curve.knot_abscissa())
        f = np.asarray(curve.force_n if isinstance(curve, LookupCurve) else curve._knot_forces()) - target
        if f[0] <= 0.0:  # never above 0 N: every reading is no contact
            at = float(u[0])
        elif f[-1] > 0.0:  # on the last sloped segment extended along the abscissa
            k = int(np.flatnonzero(f > f[-1])[-1])
            at = float(u[-1] + f[-1] * (u[-1] - u[k]) / (f[k] - f[-1]))
        else:
            j = int(np.flatnonzero(f <= 0.0)[0])
            t = f[j - 1] / (f[j - 1] - f[j])
            at = float(u[j - 1] + t * (u[j] - u[j - 1]))
        if isinstance(curve, LookupCurve):
            return float(np.exp(-at))
        r = curve.resistance_at(at)
        return 1.0 / r if r > 0.0 else math.inf

    def static_force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """The apparent force x = curve(R / gain) + offset_n (N), before any drift correction;
        an open sensor (+inf) reads 0 N, a NaN, zero or negative R NaN."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            x = self.curve.force(r / self.gain) + self.offset_n
        return np.asarray(np.where(np.isposinf(r), 0.0, x))

    def with_sensitivity(self, gain: float, offset_n: float) -> CurveChannel:
        """The same curve read with another sensitivity (``calibrate --update``); a curve that
        now reads a phantom force at zero conductance starts above it (``with_range``)."""
        floor = self.curve.force_at_zero_conductance_n + offset_n
        low = max(self.force_min_n, LINE_ZERO_MARGIN * floor) if floor > 0.0 else self.force_min_n
        return replace(
            self, gain=gain, offset_n=offset_n, force_min_n=low, force_max_n=max(self.force_max_n, 2.0 * low)
        )

    def with_range(self, force_min_n: float, force_max_n: float) -> CurveChannel:
        """The channel calibrated over [force_min_n, force_max_n] (N); a curve that reads a
        phantom force at zero conductance starts at ``LINE_ZERO_MARGIN`` x it when the range
        reaches below that (the top at least twice the bottom)."""
        floor = self.zero_conductance_force_n
        low = max(force_min_n, 0.0)
        if floor > 0.0 and not low > LINE_ZERO_MARGIN * floor:
            low = LINE_ZERO_MARGIN * floor
        return replace(self, force_min_n=low, force_max_n=max(force_max_n, 2.0 * low))

    @property
    def n_parameters(self) -> int:
        return self.curve.n_parameters + self.drift.n_parameters + (self.gain != 1.0) + (self.offset_n != 0.0)

    def describe(self) -> str:
        """``lookup``, ``line`` for a static line or lookup table; ``kind + form`` for a curve."""
        if self.table_kind != "curve":
            return self.table_kind
        return f"{self.curve.kind} + {self.drift.form}"

    def table(self) -> dict[str, object]:
        """The body of the channel's calibration table (``table_kind``), read back by
        ``channel_from_table`` into an equal channel."""
        body: dict[str, object] = dict(self.curve.table())
        if self.table_kind == "lookup":
            return body
        if self.table_kind == "line":
            return {**body, "force_min_n": float(self.force_min_n), "force_max_n": float(self.force_max_n)}
        out: dict[str, object] = {"kind": self.curve.kind, **body}
        out.update(gain=float(self.gain), offset_n=float(self.offset_n))
        out.update(self.drift.table())
        out.update(force_min_n=float(self.force_min_n), force_max_n=float(self.force_max_n))
        return out


def _check_keys(data: Mapping[str, object], allowed: tuple[str, ...], what: str) -> None:
    for key in data:
        if key not in allowed:
            raise CurveError(key, f"unknown key{what}; allowed: {', '.join(allowed)}")
    if "held_out_force_rms_n" in data:
        finite_value("held_out_force_rms_n", data["held_out_force_rms_n"], "N")


def _number(data: Mapping[str, object], key: str, default: float, unit: str) -> float:
    value = data.get(key, default)
    if isinstance(value, float) and math.isinf(value) and value > 0:
        return value
    return finite_value(key, value, unit)


def curve_from_table(data: Mapping[str, object], front_end: FrontEnd | None = None) -> CurveChannel:
    """A channel from a ``[curve.<name>]`` table (a lookup in counts read through
    ``front_end``); ``CurveError`` names the key at fault."""
    kind = data.get("kind")
    if kind not in CURVE_KINDS:
        raise CurveError("kind", f"{kind!r} is not a curve kind; allowed: {', '.join(CURVE_KINDS)}")
    assert isinstance(kind, str)
    counts = ("counts",) if kind == "lookup" else ()
    _check_keys(data, _COMMON_KEYS + CURVE_KEYS[kind] + counts + DRIFT_KEYS, f" for a {kind} curve")
    drift_values = {k: finite_value(k, data[k], "") for k in DRIFT_KEYS if k in data}
    return CurveChannel(
        curve_body_from_table(kind, data, front_end),
        Drift(**drift_values),
        gain=_number(data, "gain", 1.0, ""),
        offset_n=_number(data, "offset_n", 0.0, "N"),
        force_min_n=_number(data, "force_min_n", 0.0, "N"),
        force_max_n=_number(data, "force_max_n", math.inf, "N"),
    )


def channel_from_table(
    kind: str,
    data: Mapping[str, object],
    force_min_n: float,
    force_max_n: float,
    front_end: FrontEnd | None = None,
) -> CurveChannel:
    """The channel of a calibration file's ``[line.<name>]``, ``[lookup.<name>]`` or
    ``[curve.<name>]`` table; a line without its own force range takes the channel's
    (``force_min_n``/``force_max_n``), a lookup is calibrated over its knots' forces (never
    below 0 N) and read in the domain it was given in: ``resistance_ohm`` in ln R (what
    ``calibrate`` writes), ``counts`` in the ADC code of ``front_end`` (the device's; None: a
    device without one, where a table in counts is refused). ``CurveError`` names the key."""
    if kind == "curve":
        return curve_from_table(data, front_end)
    if kind == "line":
        _check_keys(data, _LINE_KEYS, "")
        curve: StaticCurve = curve_body_from_table("line", data)
        low = _number(data, "force_min_n", force_min_n, "N")
        high = _number(data, "force_max_n", force_max_n, "N")
        if not low > 0.0:
            raise CurveError("force_min_n", f"{low!r} is out of range; allowed: (0, inf) N")
        return CurveChannel(curve, force_min_n=low, force_max_n=high, table_kind="line")
    if kind == "lookup":
        _check_keys(data, _LOOKUP_KEYS, "")
        lookup = curve_body_from_table("lookup", data, front_end)
        assert isinstance(lookup, LookupCurve | CountsLookupCurve)
        low_n, high_n = max(min(lookup.force_n), 0.0), max(lookup.force_n)
        return CurveChannel(lookup, force_min_n=low_n, force_max_n=high_n, table_kind="lookup")
    raise CurveError("kind", f"{kind!r} is not a calibration table; allowed: {', '.join(CONVERSION_KINDS)}")


def line_channel(line: LineCurve, force_min_n: float, force_max_n: float) -> CurveChannel:
    """A static ``[line]`` channel over [force_min_n, force_max_n] (``CurveChannel.with_range``)."""
    floor = line.force_at_zero_conductance_n
    start = LINE_ZERO_MARGIN * floor if floor > 0.0 else 0.0
    return CurveChannel(line, force_min_n=start, table_kind="line").with_range(force_min_n, force_max_n)
