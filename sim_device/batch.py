"""What one array's conversions produce (``SampleBatch``): made by ``array.SimArray``, served
by the register maps (``maps``, ``rawgrid``), recorded by ``record``; below all of them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SampleBatch:
    """Consecutive ADC conversions of one array; arrays are (T,) or (T, N)."""

    device_id: int
    time_s: FloatArray
    adc_counts: NDArray[np.int64]
    resistance_ohm: FloatArray  # measured, from the counts by eq. 18
    true_resistance_ohm: FloatArray  # before the ADC, no noise
    force_n: FloatArray
    temperature_c: FloatArray
    modes: NDArray[np.int8]

    def last(self) -> SampleBatch:
        """A batch holding only the last sample."""
        return SampleBatch(
            self.device_id,
            self.time_s[-1:],
            self.adc_counts[-1:],
            self.resistance_ohm[-1:],
            self.true_resistance_ohm[-1:],
            self.force_n[-1:],
            self.temperature_c[-1:],
            self.modes[-1:],
        )
