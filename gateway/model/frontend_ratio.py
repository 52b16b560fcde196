"""The ratio read-out (numpy only): a divider whose values are not known, read in units of its
own reference resistor. ``frontend`` describes it with the other front ends.

A ratiometric divider's code depends on the sensor r and the reference resistor R_ref only
through their ratio ``r_rel = r / R_ref``: the supply cancels, and so does R_ref once r is
counted in units of it. Reading counts as ``r_rel`` therefore assumes no circuit value at
all, only the topology, which the user sees in ``scan`` (do the counts rise or fall when the
cell is pressed?):

* counts rise with load: the sensor is on the high side (``Divider``, the paper's eq. 18; the
  resistance of a piezoresistive cell falls under load, so the output rises):
  ``r_rel = FS / code - 1``;
* counts fall with load: the sensor is on the low side below a pull-up (``LowSideDivider``):
  ``r_rel = code / (FS - code)``.

``RatioFrontEnd`` is that divider with ``supply_v = 1`` and ``reference_ohm = 1`` and a
ratiometric converter; every quantity (the inverse, the statuses, the open/short codes, the
measurable range) is the divider's own, in units of R_ref. A force from such a value needs a
calibration in the same units (``tactile-gateway calibrate`` on a record of the channel): the
default sensor parameters are in ohm and do not apply.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

from numpy.typing import ArrayLike

from .frontend_base import FloatArray, FrontEnd, StatusArray
from .frontend_dividers import Divider, LowSideDivider, _SupplyDivider


def _relative(value: float) -> str:
    """``0.25`` -> ``"0.25 R_ref"``: a value in units of the unknown reference resistor."""
    return f"{value:.4g} R_ref"


@dataclass(frozen=True)
class RatioFrontEnd(FrontEnd):
    """A ratiometric divider read without any circuit value: the sensor resistance in units of
    the board's unknown reference resistor, ``r_rel = r / R_ref`` (dimensionless)::

        rises_with_load = True  (high side, eq. 18):  r_rel = FS / y - 1
        rises_with_load = False (low side, pull-up):  r_rel = y / (FS - y)

    with ``y = code - adc_offset_counts`` and ``FS = 2^adc_bits - 1``. ``output_voltage`` is
    in units of the supply (1 = the supply rail). The statuses are those of the divider:
    high side, code 0 (the open sensor) reads OPEN and full scale (the short) SHORT; low side
    the other way round.
    """

    kind: ClassVar[str] = "ratio"

    adc_bits: int
    rises_with_load: bool = True
    adc_offset_counts: float = 0.0

    @functools.cached_property
    def divider(self) -> _SupplyDivider:
        """The divider this reads as: ``supply_v = 1``, ``reference_ohm = 1``, ratiometric."""
        cls = Divider if self.rises_with_load else LowSideDivider
        return cls(
            supply_v=1.0, reference_ohm=1.0, adc_bits=self.adc_bits, adc_offset_counts=self.adc_offset_counts
        )

    @property
    def adc_reference_v(self) -> float | None:  # type: ignore[override]
        """None: the converter is ratiometric (its reference is the divider's supply)."""
        return None

    @property
    def reference_v(self) -> float:
        return 1.0

    def output_voltage(self, resistance_ohm: ArrayLike) -> FloatArray:
        """The divider's output in units of its supply for ``r_rel`` (here ``resistance_ohm``
        is in units of R_ref): inf is an open sensor, 0 a shorted one."""
        return self.divider.output_voltage(resistance_ohm)

    def _code_edges(self) -> tuple[float, float]:
        return self.divider._code_edges()

    def _inverse(self, y: FloatArray) -> FloatArray:
        return self.divider._inverse(y)

    def resistance(self, counts: ArrayLike) -> tuple[FloatArray, StatusArray]:
        """``r_rel`` (units of R_ref, not ohm) and a ``DividerStatus`` per code: the divider's
        own, with its fast path for integer codes."""
        return self.divider.resistance(counts)

    def _validate_parameters(self) -> None:
        if not isinstance(self.rises_with_load, bool):
            raise ValueError(
                f"rises_with_load = {self.rises_with_load!r} must be true or false (do the counts rise "
                "when the cell is pressed?)"
            )

    def _unmeasurable_hint(self) -> str:
        return "check adc_offset_counts"

    def _equation(self) -> str:
        if self.rises_with_load:
            return "r/R_ref = FS/code - 1 (counts rise with load: sensor on the high side, eq. 18)"
        return "r/R_ref = code/(FS - code) (counts fall with load: sensor below a pull-up)"

    def _reference_text(self) -> str:
        return "ratiometric"

    def _range_text(self, r_min: float, r_max: float) -> str:
        """The range in units of the unknown reference resistor, and what that means."""
        return (
            f"reads {_relative(r_min)} .. {_relative(r_max)}; values are relative (units of the board's "
            "unknown reference resistor R_ref, not ohm): no circuit value is assumed, and forces "
            "need a calibration (`calibrate`)"
        )
