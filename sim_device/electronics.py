"""The array's read-out, written from the paper's Fig. 4b and eq. 18 (no ``gateway`` code).

The sensor r sits between the supply V+ and the output node, the fixed resistor R_ref from
the output node to ground, so the output is V_o = V+ R_ref / (R_ref + r). The ADC is
ratiometric (its reference is V+): counts = round(V_o / V+ (2^bits - 1) + noise), clipped
to [0, 2^bits - 1]. An open sensor (r = inf) gives 0 V, a shorted one (r = 0) V+. Reading
back, r = R_ref ((2^bits - 1) / counts - 1): 0 counts is +inf (open), full scale 0 (short).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def full_scale(adc_bits: int) -> int:
    """The largest code of a ``adc_bits`` converter, 2^bits - 1."""
    return (1 << int(adc_bits)) - 1


def output_fraction(resistance_ohm: FloatArray, reference_ohm: float) -> FloatArray:
    """V_o / V+ = R_ref / (R_ref + r); 0 for an open sensor (r = inf), 1 for a short (r = 0)."""
    r = np.asarray(resistance_ohm, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        fraction = reference_ohm / (reference_ohm + r)
    return np.asarray(np.where(np.isposinf(r), 0.0, fraction))


def adc_counts(
    resistance_ohm: FloatArray,
    reference_ohm: float,
    adc_bits: int,
    noise_lsb: FloatArray | float = 0.0,
) -> IntArray:
    """Converter codes for sensor resistances, with ``noise_lsb`` (LSB) added before rounding
    to the nearest code (half to even) and clipping to the rails."""
    fs = full_scale(adc_bits)
    code = output_fraction(resistance_ohm, reference_ohm) * fs + noise_lsb
    return np.clip(np.rint(code), 0, fs).astype(np.int64)


def resistance_from_counts(counts: IntArray, reference_ohm: float, adc_bits: int) -> FloatArray:
    """r = R_ref (full scale / counts - 1): +inf at 0 counts (open), 0 at full scale (short)."""
    fs = full_scale(adc_bits)
    c = np.asarray(counts, dtype=np.float64)
    with np.errstate(divide="ignore"):
        r = reference_ohm * (fs / c - 1.0)
    return np.asarray(np.where(c <= 0.0, np.inf, np.maximum(r, 0.0)))
