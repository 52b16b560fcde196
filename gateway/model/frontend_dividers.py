"""The two resistive dividers (numpy only): ``Divider``, the paper's high-side divider of eq. 18
(Fig. 4b), and ``LowSideDivider``, the sensor below a pull-up. ``frontend`` describes both.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from .frontend_base import (
    _INVALID,
    _MAX_OHM,
    _SHORT,
    FloatArray,
    FrontEnd,
    StatusArray,
    _as_codes,
    _check_positive,
    _fmt,
)


def _check_reference(value: float | None) -> None:
    if value is not None:
        _check_positive("adc_reference_v", value, "V")


class _SupplyDivider(FrontEnd):
    """What the two dividers share: a supply rail, a reference resistor, and an ADC whose
    reference is the supply unless it is given (a ratiometric converter)."""

    supply_v: float
    reference_ohm: float
    adc_reference_v: float | None

    def _validate_parameters(self) -> None:
        _check_positive("supply_v", self.supply_v, "V")
        _check_positive("reference_ohm", self.reference_ohm, "ohm")
        _check_reference(self.adc_reference_v)

    @property
    def reference_v(self) -> float:
        return self.supply_v if self.adc_reference_v is None else self.adc_reference_v


@dataclass(frozen=True)
class Divider(_SupplyDivider):
    """High-side divider, the paper's eq. 18 (Fig. 4b): the sensor r from the supply V+ to the
    output node, R_ref from the output to ground::

        V_o = V+ R_ref / (R_ref + r)        r = R_ref (V+ / V_o - 1)

    Open (r = inf) gives 0 V, short (r = 0) gives V+. With the defaults the ADC is
    ratiometric (``adc_reference_v = None``: its reference is V+) and has no offset, so code
    0 is open, full scale is short and ``r = R_ref (FS / code - 1)``. A reference below V+
    puts the short level beyond full scale (full scale then reads SATURATED); a negative
    offset puts the open level below code 0 (code 0 then reads SATURATED).
    """

    kind: ClassVar[str] = "high_side"

    supply_v: float = 5.0
    reference_ohm: float = 10e3
    adc_bits: int = 16
    adc_reference_v: float | None = None
    adc_offset_counts: float = 0.0

    @property
    def _plain(self) -> bool:
        """Ratiometric and without offset: the closed form ``R_ref (FS / code - 1)``."""
        return self.adc_offset_counts == 0 and (
            self.adc_reference_v is None or self.adc_reference_v == self.supply_v
        )

    def output_voltage(self, resistance_ohm: ArrayLike) -> FloatArray:
        """V_o for a sensor resistance; inf gives 0 V (open), 0 gives V+ (short)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(all="ignore"):
            v = self.supply_v * self.reference_ohm / (self.reference_ohm + r)
            v = np.where(np.isinf(r), 0.0, v)
            return np.asarray(np.where(r < 0.0, np.nan, v))

    def _code_edges(self) -> tuple[float, float]:
        off = float(self.adc_offset_counts)
        return off, off + self.full_scale * (self.supply_v / self.reference_v)

    def _inverse(self, y: FloatArray) -> FloatArray:
        # V_o = y Vref / FS, r = R_ref (V+ / V_o - 1) = R_ref (FS / (y Vref / V+) - 1)
        ratio = self.reference_v / self.supply_v
        return np.asarray(self.reference_ohm * (self.full_scale / (y * ratio) - 1.0))

    def resistance(self, counts: ArrayLike) -> tuple[FloatArray, StatusArray]:
        """Sensor resistance (ohm) and a ``DividerStatus`` per reading (see ``FrontEnd``).

        Ratiometric without offset (the default) this is the closed form ``R_ref (FS / code
        - 1)``, open at code 0 (+inf), short at full scale (0), with a fast path for integer
        codes (the polling path)."""
        if not self._plain:
            return super().resistance(counts)
        fs = self.full_scale
        raw = np.asarray(counts)
        if raw.dtype.kind in "iu":  # integer counts: no NaN to look for
            flat = raw if raw.ndim == 1 else raw.reshape(-1)
            open_ = flat == 0
            short = flat == fs
            invalid = (flat > fs) | (flat < 0) if flat.dtype.kind == "i" else flat > fs
            with np.errstate(divide="ignore"):
                r = (fs / flat - 1.0) * self.reference_ohm  # 0 counts: +inf; full scale: 0
        else:
            c, invalid = _as_codes(raw, fs)
            open_ = ~invalid & (c == 0.0)
            short = ~invalid & (c == fs)
            ok = ~(invalid | open_ | short)
            with np.errstate(over="ignore"):  # codes below ~1e-308: the largest float, not inf
                r = np.minimum(self.reference_ohm * (fs / np.where(ok, c, 1.0) - 1.0), _MAX_OHM)
            r[open_] = np.inf
            r[short] = 0.0
        status = open_.view(np.int8) + short.view(np.int8) * _SHORT
        if invalid.any():
            r = np.where(invalid, np.nan, r)
            status[invalid] = _INVALID
        if raw.ndim == 1:
            return r, status
        return r.reshape(raw.shape), status.reshape(raw.shape)

    def _equation(self) -> str:
        return (
            f"V = Vs*R_ref/(R_ref + r) (eq. 18), Vs = {_fmt(self.supply_v, 'V')}, "
            f"R_ref = {_fmt(self.reference_ohm, 'ohm')}"
        )

    def _reference_text(self) -> str:
        if self.adc_reference_v is None:
            return "Vref = Vs (ratiometric)"
        return super()._reference_text()


@dataclass(frozen=True)
class LowSideDivider(_SupplyDivider):
    """Low-side divider: R_ref is a pull-up from the supply V+ to the output node, the sensor
    r goes from the output to ground::

        V_o = V+ r / (R_ref + r)        r = R_ref V_o / (V+ - V_o)

    Open gives V+, short 0 V. Ratiometric without offset: ``r = R_ref code / (FS - code)``,
    full scale is open, 0 is short. A pull-up to a rail above the ADC reference (``supply_v >
    adc_reference_v``) puts the open level beyond full scale: full scale then reads
    SATURATED, the bound ``R_ref V_ref / (V+ - V_ref)``.
    """

    kind: ClassVar[str] = "low_side"

    supply_v: float
    reference_ohm: float
    adc_bits: int
    adc_reference_v: float | None = None
    adc_offset_counts: float = 0.0

    def output_voltage(self, resistance_ohm: ArrayLike) -> FloatArray:
        """V_o for a sensor resistance; inf gives V+ (open), 0 gives 0 V (short)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(all="ignore"):
            v = self.supply_v * (r / (self.reference_ohm + r))
            v = np.where(np.isinf(r), self.supply_v, v)
            return np.asarray(np.where(r < 0.0, np.nan, v))

    def _code_edges(self) -> tuple[float, float]:
        off = float(self.adc_offset_counts)
        return off + self.full_scale * (self.supply_v / self.reference_v), off

    def _inverse(self, y: FloatArray) -> FloatArray:
        # u = V_o / V+ = y Vref / (FS V+), r = R_ref u / (1 - u) = R_ref y k / (FS - y k)
        yk = y * (self.reference_v / self.supply_v)
        return np.asarray(self.reference_ohm * yk / (self.full_scale - yk))

    def _equation(self) -> str:
        return (
            f"V = Vs*r/(R_ref + r), Vs = {_fmt(self.supply_v, 'V')}, "
            f"R_ref = {_fmt(self.reference_ohm, 'ohm')} (pull-up)"
        )

    def _reference_text(self) -> str:
        if self.adc_reference_v is None:
            return "Vref = Vs (ratiometric)"
        return super()._reference_text()
