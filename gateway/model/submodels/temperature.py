"""``temperature``: the polymer's resistance depends on the sensor temperature.

T(temp) = exp(c (temp - temp_ref)) multiplies the polymer resistance, c =
``temperature_coeff_per_k`` (1/K), temp_ref = ``reference_temperature_c`` (degC). Without a
temperature (None) or with the null variant, the factor is 1.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from .base import Factor, FloatArray


class Temperature(Factor):
    effect: ClassVar[str] = "temperature"
    description: ClassVar[str] = "polymer resistance depends on sensor temperature"
    parameters: ClassVar[tuple[str, ...]] = ("temperature_coeff_per_k",)

    def factor(self, temperature_c: ArrayLike | None) -> FloatArray | float:
        if temperature_c is None:
            return 1.0
        p = self.params
        dt = np.asarray(temperature_c, dtype=np.float64) - p.reference_temperature_c
        return np.asarray(np.exp(p.temperature_coeff_per_k * dt))


class NoTemperature(Factor):
    """``temperature`` switched off: ``Factor``'s unit factor (a sibling of ``Temperature``)."""

    effect: ClassVar[str] = Temperature.effect
    active: ClassVar[bool] = False
    description: ClassVar[str] = Temperature.description
    parameters: ClassVar[tuple[str, ...]] = Temperature.parameters
