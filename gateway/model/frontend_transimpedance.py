"""The transimpedance read-out (numpy only): the sensor into an op-amp's virtual ground,
``V_o = V_os + V_b R_f / r``. ``frontend`` describes it with the other front ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from .frontend_base import FloatArray, FrontEnd, _check_finite, _check_positive, _fmt


@dataclass(frozen=True)
class Transimpedance(FrontEnd):
    """Transimpedance amplifier: the sensor r, driven by V_b, feeds the virtual ground of an
    op-amp with feedback resistor R_f; the output (as a magnitude) plus the amplifier's
    output offset V_os is::

        V_o = V_os + V_b R_f / r        r = V_b R_f / (V_o - V_os)

    Linear in the sensor's conductance. Open gives V_os (code ``offset + V_os / V_ref FS``,
    OPEN at and below it), short an unbounded output: full scale reads SATURATED, the
    smallest measurable resistance ``V_b R_f / (V_ref (FS - offset) / FS - V_os)``.
    """

    kind: ClassVar[str] = "transimpedance"

    bias_v: float
    feedback_ohm: float
    adc_bits: int
    adc_reference_v: float
    output_offset_v: float = 0.0
    adc_offset_counts: float = 0.0

    def _validate_parameters(self) -> None:
        _check_positive("bias_v", self.bias_v, "V")
        _check_positive("feedback_ohm", self.feedback_ohm, "ohm")
        _check_positive("adc_reference_v", self.adc_reference_v, "V")
        _check_finite("output_offset_v", self.output_offset_v, "V")

    @property
    def reference_v(self) -> float:
        return self.adc_reference_v

    def output_voltage(self, resistance_ohm: ArrayLike) -> FloatArray:
        """V_o for a sensor resistance; inf gives V_os (open), 0 gives +inf (short)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(all="ignore"):
            v = self.output_offset_v + self.bias_v * self.feedback_ohm / r
            return np.asarray(np.where(r < 0.0, np.nan, v))

    def _code_edges(self) -> tuple[float, float]:
        off = float(self.adc_offset_counts)
        return off + self.full_scale * (self.output_offset_v / self.adc_reference_v), math.inf

    def _inverse(self, y: FloatArray) -> FloatArray:
        v = y / self.full_scale * self.adc_reference_v
        return np.asarray(self.bias_v * self.feedback_ohm / (v - self.output_offset_v))

    def _unmeasurable_hint(self) -> str:
        return (
            f"output_offset_v = {self.output_offset_v!r} V already puts the open-sensor output at or "
            f"beyond the ADC's full scale (adc_reference_v = {self.adc_reference_v!r} V), so every "
            "resistance would read the rail; lower output_offset_v or adc_offset_counts, or raise "
            "adc_reference_v"
        )

    def _equation(self) -> str:
        return (
            f"V = Vos + Vb*R_f/r, Vb = {_fmt(self.bias_v, 'V')}, R_f = {_fmt(self.feedback_ohm, 'ohm')}, "
            f"Vos = {_fmt(self.output_offset_v, 'V')}"
        )
