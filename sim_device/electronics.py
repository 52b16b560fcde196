"""The array's read-out, written from the paper's Fig. 4b and eq. 18 (no ``gateway`` code).

The sensor r sits between the supply V+ and the output node, the fixed resistor R_ref from
the output node to ground, so the output is V_o = V+ R_ref / (R_ref + r). The ADC is
ratiometric (its reference is V+): counts = round(V_o / V+ (2^bits - 1) + noise), clipped
to [0, 2^bits - 1]. An open sensor (r = inf) gives 0 V, a shorted one (r = 0) V+. Reading
back, r = R_ref ((2^bits - 1) / counts - 1): 0 counts is +inf (open), full scale 0 (short).

The second half of the module is the read-out of the "rawgrid" board (low-side divider with
a pull-up and board leakage, ``LowSideDivider``; ``docs/register-map-rawgrid.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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


# ----------------------------------------------------------------- low-side divider (rawgrid)
# A second read-out, that of the "rawgrid" board (docs/register-map-rawgrid.md), written
# from its circuit:
#
#     V+ (3.3 V) --- R_pu (10 kohm) ---+--- ADC input (V_o)
#                                      |
#                         sensor r  ||  R_leak (board leakage, 195 kohm)
#                                      |
#                                     GND
#
# The sensor and the board's leakage path form one resistance to ground,
# r_node = r R_leak / (r + R_leak); with the pull-up, V_o = V+ r_node / (R_pu + r_node).
# The ADC is ratiometric (reference V+): counts = round(V_o / V+ (2^bits - 1) + noise),
# clipped to the rails. An open sensor (r = inf) leaves r_node = R_leak, so it reads
# R_leak / (R_pu + R_leak) of full scale, not full scale; without leakage (R_leak = inf) it
# reads full scale. A shorted sensor reads 0.


def parallel_ohm(first_ohm: FloatArray | float, second_ohm: FloatArray | float) -> FloatArray:
    """Two resistances in parallel, a b / (a + b); +inf is an open path (inf || b = b)."""
    a = np.asarray(first_ohm, dtype=np.float64)
    b = np.asarray(second_ohm, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        both = a * b / (a + b)
    out = np.where(np.isposinf(a), b, np.where(np.isposinf(b), a, both))
    return np.asarray(np.where((a == 0.0) | (b == 0.0), 0.0, out))


def pullup_fraction(node_ohm: FloatArray, pullup_ohm: float) -> FloatArray:
    """V_o / V+ = r / (R_pu + r) of a resistance r to ground under a pull-up R_pu; 1 for r = inf."""
    r = np.asarray(node_ohm, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        fraction = r / (pullup_ohm + r)
    return np.asarray(np.where(np.isposinf(r), 1.0, fraction))


def low_side_counts(
    resistance_ohm: FloatArray,
    pullup_ohm: float,
    adc_bits: int,
    leakage_ohm: float = math.inf,
    noise_lsb: FloatArray | float = 0.0,
) -> IntArray:
    """Converter codes of sensors to ground under a pull-up, each shunted by ``leakage_ohm``,
    with ``noise_lsb`` (LSB) added before rounding half to even and clipping to the rails."""
    fs = full_scale(adc_bits)
    node = parallel_ohm(resistance_ohm, leakage_ohm)
    code = pullup_fraction(node, pullup_ohm) * fs + noise_lsb
    return np.clip(np.rint(code), 0, fs).astype(np.int64)


def low_side_resistance_from_counts(
    counts: IntArray, pullup_ohm: float, adc_bits: int, leakage_ohm: float = math.inf
) -> FloatArray:
    """The sensor resistance a reading implies, the known leakage taken out.

    The node: r_node = R_pu counts / (full scale - counts) (+inf at full scale, 0 at 0
    counts). The sensor: 1 / r = 1 / r_node - 1 / R_leak, so r = r_node R_leak / (R_leak -
    r_node); a node at or above R_leak (the leakage alone, or a noisy reading beyond it)
    is an open sensor, +inf.
    """
    fs = full_scale(adc_bits)
    c = np.asarray(counts, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        node = np.where(c >= fs, np.inf, pullup_ohm * c / (fs - c))
        node = np.maximum(node, 0.0)
        if math.isinf(leakage_ohm):
            return np.asarray(node)
        sensor = node * leakage_ohm / (leakage_ohm - node)
    return np.asarray(np.where(node >= leakage_ohm, np.inf, sensor))


@dataclass(frozen=True)
class LowSideDivider:
    """The rawgrid board's read-out: pull-up ``pullup_ohm`` from ``supply_v`` to the ADC
    input, each sensor to ground shunted by ``leakage_ohm`` (+inf: no leakage), a
    ratiometric ``adc_bits`` converter."""

    pullup_ohm: float = 10e3
    supply_v: float = 3.3
    adc_bits: int = 12
    leakage_ohm: float = 195e3

    def node_ohm(self, resistance_ohm: FloatArray) -> FloatArray:
        """The resistance from the ADC input to ground: the sensor in parallel with the leakage."""
        return parallel_ohm(resistance_ohm, self.leakage_ohm)

    def output_v(self, resistance_ohm: FloatArray) -> FloatArray:
        """The ADC input voltage V_o = V+ r_node / (R_pu + r_node)."""
        return np.asarray(self.supply_v * pullup_fraction(self.node_ohm(resistance_ohm), self.pullup_ohm))

    def counts(self, resistance_ohm: FloatArray, noise_lsb: FloatArray | float = 0.0) -> IntArray:
        return low_side_counts(resistance_ohm, self.pullup_ohm, self.adc_bits, self.leakage_ohm, noise_lsb)

    def resistance_from_counts(self, counts: IntArray) -> FloatArray:
        return low_side_resistance_from_counts(counts, self.pullup_ohm, self.adc_bits, self.leakage_ohm)

    def open_sensor_counts(self) -> int:
        """The noise-free reading of an open (unloaded) sensor: the leakage alone."""
        return int(self.counts(np.array([math.inf]))[0])
