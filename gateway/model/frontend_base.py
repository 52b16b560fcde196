"""The part every read-out front end shares: the ideal ADC, the inverse with its statuses, the
description and the validation (``FrontEnd``), and the helpers the topologies use (numpy only).

The topologies live in ``frontend_dividers`` (``Divider``, ``LowSideDivider``) and
``frontend_transimpedance`` (``Transimpedance``); ``frontend`` describes them all, builds
them by kind and re-exports everything here.
"""

from __future__ import annotations

import abc
import contextlib
import enum
import math
import numbers
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]

_MAX_OHM = float(np.finfo(np.float64).max)


class DividerStatus(enum.IntEnum):
    """What a front end's reading says about the sensor."""

    OK = 0
    OPEN = 1  # at or beyond the code of an open sensor (no current through it): r = +inf
    SHORT = 2  # at or beyond the code of a shorted sensor: r = 0
    INVALID = 3  # counts outside the converter's range, or not a number
    SATURATED = 4  # an ADC rail that is not the open/short level: r beyond the measurable range


_OK = np.int8(int(DividerStatus.OK))
_OPEN = np.int8(int(DividerStatus.OPEN))
_SHORT = np.int8(int(DividerStatus.SHORT))
_INVALID = np.int8(int(DividerStatus.INVALID))
_SATURATED = np.int8(int(DividerStatus.SATURATED))

_PREFIXES = ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"), (1e-6, "u"))


def _fmt(value: float, unit: str) -> str:
    """``10000, "ohm"`` -> ``"10 kohm"``: engineering prefix, four significant digits."""
    if not math.isfinite(value) or value == 0.0:
        return f"{value:g} {unit}"
    for scale, prefix in _PREFIXES:
        if abs(value) >= scale:
            return f"{value / scale:.4g} {prefix}{unit}"
    return f"{value:.4g} {unit}"


def _real(value: object) -> float | None:
    """A finite real number (not a bool) as float, else None."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        number = float(value)
        if math.isfinite(number):
            return number
    return None


def _check_positive(name: str, value: object, unit: str) -> None:
    number = _real(value)
    if number is None or number <= 0.0:
        raise ValueError(f"{name} = {value!r} must be in (0, inf) {unit}")


def _check_finite(name: str, value: object, unit: str) -> None:
    if _real(value) is None:
        raise ValueError(f"{name} = {value!r} must be a finite number ({unit}), in (-inf, inf)")


def _object_codes(raw: NDArray[Any]) -> FloatArray:
    """Element by element: real numbers as float, anything else NaN."""
    out = np.full(raw.shape, np.nan)
    for i, item in enumerate(raw.flat):
        if isinstance(item, numbers.Real):
            with contextlib.suppress(OverflowError, TypeError, ValueError):
                out.flat[i] = float(item)
    return out


def _as_codes(raw: NDArray[Any], fs: int) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Any array as float64 codes (1-d, a view where possible) and the mask of invalid ones:
    not a real number, not finite, below 0 or above ``fs``. Never raises or warns."""
    with np.errstate(all="ignore"):
        kind = raw.dtype.kind
        if kind in "biuf":
            c = raw.astype(np.float64, copy=False).reshape(-1)
        elif kind == "c":
            c = np.where(raw.imag == 0, raw.real, np.nan).astype(np.float64).reshape(-1)
        elif kind == "O":
            c = _object_codes(raw).reshape(-1)
        else:  # strings, dates, records: no code at all
            c = np.full(raw.size, np.nan)
        invalid = ~np.isfinite(c) | (c < 0.0) | (c > fs)
    return c, invalid


class FrontEnd(abc.ABC):
    """A read-out circuit and its ADC: resistance -> voltage -> counts, and back.

    Concrete front ends are frozen dataclasses; they validate themselves on construction
    (``ValueError`` naming the field, its value and the allowed range).

    Attributes common to all (units in the names):

    * ``kind``: the name used in configuration files (``FRONT_END_KINDS``);
    * ``adc_bits``: converter resolution, 8..24 bit; ``full_scale = 2^bits - 1``;
    * ``adc_reference_v``: the converter's reference (V); a divider may leave it ``None``,
      which means its supply (a ratiometric converter);
    * ``adc_offset_counts``: a constant code the converter/amplifier adds (may be negative,
      ``|offset| < full_scale / 2``).
    """

    kind: ClassVar[str]
    adc_bits: int
    adc_reference_v: float | None
    adc_offset_counts: float

    def __post_init__(self) -> None:
        self.validate()

    # ---- what each topology supplies -------------------------------------------------------

    @property
    @abc.abstractmethod
    def reference_v(self) -> float:
        """The ADC reference in volts (a ratiometric divider's is its supply)."""

    @abc.abstractmethod
    def output_voltage(self, resistance_ohm: ArrayLike) -> FloatArray:
        """The circuit's output voltage (V) for a sensor resistance (ohm), vectorised:
        +inf is an open sensor, 0 a shorted one; NaN or negative resistances give NaN."""

    @abc.abstractmethod
    def _code_edges(self) -> tuple[float, float]:
        """The exact (unrounded, unclipped) codes of an open and of a shorted sensor; may be
        infinite (a transimpedance's short)."""

    @abc.abstractmethod
    def _inverse(self, y: FloatArray) -> FloatArray:
        """Resistance (ohm) for ``y = code - adc_offset_counts``; only used strictly between
        the open and short codes, where it is finite and positive."""

    @abc.abstractmethod
    def _validate_parameters(self) -> None:
        """Check the topology's own fields (``ValueError`` naming field, value, range)."""

    @abc.abstractmethod
    def _equation(self) -> str:
        """The forward equation and the values, for ``describe``."""

    def _unmeasurable_hint(self) -> str:
        return "check the supply, adc_reference_v and adc_offset_counts"

    # ---- the converter ---------------------------------------------------------------------

    def idle_floor_codes(self, share: float = 0.06) -> tuple[float, float]:
        """The codes within ``share`` of full scale of an open sensor's code (inclusive, in
        the converter's range): where a channel with nothing on it reads when its board
        leaks a little or its converter has an offset, so a reading there without a zero
        may be no load at all."""
        x_open, _ = self._code_edges()
        fs = float(self.full_scale)
        open_code = min(max(x_open, 0.0), fs)
        return max(open_code - share * fs, 0.0), min(open_code + share * fs, fs)

    @property
    def full_scale(self) -> int:
        """The largest code, ``2^bits - 1``."""
        return int(2**self.adc_bits - 1)

    def counts(self, voltage_v: ArrayLike) -> NDArray[np.int64]:
        """Ideal converter: ``offset + V / V_ref * FS``, rounded half to even, clipped to
        ``[0, FS]``."""
        v = np.asarray(voltage_v, dtype=np.float64)
        with np.errstate(over="ignore"):  # a huge voltage is beyond full scale anyway
            x = v / self.reference_v * self.full_scale
        if self.adc_offset_counts:
            x = x + self.adc_offset_counts
        return np.clip(np.rint(x), 0, self.full_scale).astype(np.int64)

    def voltage(self, counts: ArrayLike) -> FloatArray:
        """The voltage (V) a code stands for: ``(code - offset) / FS * V_ref`` (no clipping)."""
        c = np.asarray(counts, dtype=np.float64)
        if self.adc_offset_counts:
            c = c - self.adc_offset_counts
        return np.asarray(c / self.full_scale * self.reference_v)

    def counts_for(self, resistance_ohm: ArrayLike) -> NDArray[np.int64]:
        """The code the ideal converter gives for a sensor resistance (ohm; +inf = open).

        ``ValueError`` for NaN or negative resistances: they have no code."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            bad = np.isnan(r) | (r < 0.0)
        if bad.any():
            raise ValueError(
                f"resistance_ohm must be in [0, inf] ohm (inf = open); got {r[bad].ravel()[:5].tolist()}"
            )
        return self.counts(self.output_voltage(r))

    # ---- the inverse -----------------------------------------------------------------------

    def _edges(self) -> tuple[bool, float, float]:
        """(open at low codes?, open edge, short edge): a code at or beyond an edge reads
        OPEN/SHORT. An edge is the rounded code of the open/short sensor, moved to its exact
        code where that lies further in, so every code between the edges has a finite,
        positive inverse."""
        x_open, x_short = self._code_edges()
        k_open, k_short = float(np.rint(x_open)), float(np.rint(x_short))
        if x_open < x_short:
            return True, max(k_open, x_open), min(k_short, x_short)
        return False, min(k_open, x_open), max(k_short, x_short)

    def _finite_code_span(self) -> tuple[int, int]:
        """The lowest and highest integer codes in ``[0, FS]`` that read neither OPEN nor
        SHORT (OK, or SATURATED at a rail); ``lo > hi`` if there are none."""
        fs = self.full_scale
        open_low, open_edge, short_edge = self._edges()
        low_edge, high_edge = (open_edge, short_edge) if open_low else (short_edge, open_edge)
        low_edge = min(max(low_edge, -1.0), fs + 1.0)
        high_edge = min(max(high_edge, -1.0), fs + 1.0)
        return max(0, math.floor(low_edge) + 1), min(fs, math.ceil(high_edge) - 1)

    def resistance(self, counts: ArrayLike) -> tuple[FloatArray, StatusArray]:
        """Sensor resistance (ohm) and a ``DividerStatus`` (int8) per code, same shape as the
        input. Never raises or warns: invalid codes read NaN/INVALID, the open code and
        beyond +inf/OPEN, the short code and beyond 0/SHORT, a rail that is neither the
        bound of the measurable range/SATURATED."""
        raw = np.asarray(counts)
        fs = self.full_scale
        c, invalid = _as_codes(raw, fs)
        open_low, open_edge, short_edge = self._edges()
        with np.errstate(all="ignore"):
            if open_low:
                open_ = ~invalid & (c <= open_edge)
                short = ~invalid & (c >= short_edge)
            else:
                open_ = ~invalid & (c >= open_edge)
                short = ~invalid & (c <= short_edge)
            saturated = ((c == 0.0) | (c == fs)) & ~(open_ | short)
            y = c - self.adc_offset_counts if self.adc_offset_counts else c
            r = np.clip(self._inverse(y), 0.0, _MAX_OHM)
        r = np.where(open_, np.inf, np.where(short, 0.0, np.where(invalid, np.nan, r)))
        status = np.zeros(c.shape, dtype=np.int8)
        status[open_] = _OPEN
        status[short] = _SHORT
        status[saturated] = _SATURATED
        status[invalid] = _INVALID
        return np.asarray(r, dtype=np.float64).reshape(raw.shape), status.reshape(raw.shape)

    def measurable_range_ohm(self) -> tuple[float, float]:
        """``(r_min, r_max)`` in ohm: the finite resistances the converter can report, those of
        the extreme codes just short of the open and short codes, or at a rail that is not
        one (the SATURATED bound). A smaller resistance reads ``r_min`` (SATURATED) or 0
        (SHORT), a larger one ``r_max`` (SATURATED) or +inf (OPEN)."""
        lo, hi = self._finite_code_span()
        r, _ = self.resistance(np.array([lo, hi], dtype=np.int64))
        return float(min(r[0], r[1])), float(max(r[0], r[1]))

    def describe(self) -> str:
        """One line for ``check-config``: equation, values, converter, open/short codes and
        the measurable range."""
        fs = self.full_scale
        x_open, x_short = self._code_edges()
        r_min, r_max = self.measurable_range_ohm()
        return (
            f"{self.kind}: {self._equation()}; ADC {self.adc_bits} bit, FS = {fs}, "
            f"{self._reference_text()}, offset {self.adc_offset_counts:g} counts; "
            f"open -> {self._level_text(x_open, 'OPEN')}, short -> {self._level_text(x_short, 'SHORT')}; "
            f"{self._range_text(r_min, r_max)}"
        )

    def _range_text(self, r_min: float, r_max: float) -> str:
        """The measurable range as ``describe`` ends with it."""
        return f"reads {_fmt(r_min, 'ohm')} .. {_fmt(r_max, 'ohm')}"

    def _reference_text(self) -> str:
        return f"Vref = {_fmt(self.reference_v, 'V')}"

    def _level_text(self, x: float, name: str) -> str:
        k = float(np.rint(x))
        if 0 <= k <= self.full_scale:
            return f"code {int(k)} ({name})"
        rail = 0 if k < 0 else self.full_scale
        return f"beyond the rail (code {rail} reads SATURATED)"

    # ---- validation ------------------------------------------------------------------------

    def validate(self) -> None:
        """Every parameter finite and in range, and at least one code with a finite inverse;
        ``ValueError`` naming the field, its value and the allowed range otherwise."""
        bits = self.adc_bits
        if not (isinstance(bits, int) and not isinstance(bits, bool) and 8 <= bits <= 24):
            raise ValueError(f"adc_bits = {bits!r} must be an integer in [8, 24]")
        self._validate_parameters()
        half = self.full_scale / 2
        offset = self.adc_offset_counts
        number = _real(offset)
        if number is None or not abs(number) < half:
            raise ValueError(
                f"adc_offset_counts = {offset!r} must be in ({-half:g}, {half:g}) counts "
                f"(|offset| < full scale / 2 at {bits} bit)"
            )
        lo, hi = self._finite_code_span()
        if max(lo, 1) > min(hi, self.full_scale - 1):
            x_open, x_short = self._code_edges()
            raise ValueError(
                f"{self.kind}: nothing is measurable: an open sensor gives code {x_open:.6g} and a "
                f"shorted one {x_short:.6g} (with adc_offset_counts = {offset!r}), so no code strictly "
                f"inside [0, {self.full_scale}] lies between them; {self._unmeasurable_hint()}"
            )
