"""The simulator's read-out (paper Fig. 4b, eq. 18) against numbers worked by hand.

V_o / V+ = R_ref / (R_ref + r); counts = round(V_o / V+ (2^bits - 1) + noise), rounded half
to even (numpy's ``rint``: 32767.5 -> 32768, 10922.5 -> 10922, 2.5 -> 2), clipped to the
rails; r = R_ref ((2^bits - 1) / counts - 1). R_ref = 10 kohm throughout.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_device import ArrayConfig, Scenario, SimArray
from sim_device.electronics import adc_counts, full_scale, output_fraction, resistance_from_counts

R_REF = 10e3


def test_full_scale() -> None:
    assert [full_scale(b) for b in (8, 12, 16)] == [255, 4095, 65535]


def test_output_fraction_of_the_divider() -> None:
    got = output_fraction(np.array([10e3, 30e3, 0.0, math.inf, 90e3]), R_REF)
    np.testing.assert_array_equal(got, [0.5, 0.25, 1.0, 0.0, 0.1])


@pytest.mark.parametrize(
    ("resistance_ohm", "bits", "counts"),
    [
        (10e3, 16, 32768),  # 65535 / 2 = 32767.5: a tie, to the even 32768
        (30e3, 16, 16384),  # 65535 / 4 = 16383.75
        (50e3, 16, 10922),  # 65535 / 6 = 10922.5: a tie, to the even 10922 (half up: 10923)
        (5.09e6, 16, 128),  # 65535 / 510 = 128.5: to 128 (half up: 129)
        (262.13e6, 16, 2),  # 65535 / 26214 = 2.5: to 2 (half up: 3)
        (10e3, 12, 2048),  # 4095 / 2 = 2047.5
        (10e3, 8, 128),  # 255 / 2 = 127.5
        (90e3, 8, 26),  # 25.5: to 26
        (math.inf, 16, 0),  # open: 0 V
        (0.0, 16, 65535),  # short: V+
    ],
)
def test_counts_by_hand(resistance_ohm: float, bits: int, counts: int) -> None:
    assert adc_counts(np.array([resistance_ohm]), R_REF, bits).tolist() == [counts]


def test_noise_is_added_before_rounding_half_to_even_and_clipping() -> None:
    open_ = np.full(6, math.inf)  # 0.0 LSB before noise
    got = adc_counts(open_, R_REF, 16, np.array([0.5, 1.5, 2.5, 3.5, 0.49, -3.0]))
    assert got.tolist() == [0, 2, 2, 4, 0, 0]
    shorted = np.zeros(3)  # 65535.0 LSB before noise
    assert adc_counts(shorted, R_REF, 16, np.array([-0.5, -1.5, 7.0])).tolist() == [65534, 65534, 65535]
    assert adc_counts(np.array([10e3]), R_REF, 16, 0.5).tolist() == [32768]  # 32768.0


@pytest.mark.parametrize(
    ("counts", "bits", "resistance_ohm"),
    [
        (32768, 16, 9999.69482421875),  # 10k (65535 / 32768 - 1)
        (16384, 16, 29999.3896484375),
        (2048, 12, 9995.1171875),
        (1, 16, 655340000.0),
        (0, 16, math.inf),  # open
        (65535, 16, 0.0),  # short
        (255, 8, 0.0),
    ],
)
def test_resistance_from_counts_by_hand(counts: int, bits: int, resistance_ohm: float) -> None:
    got = resistance_from_counts(np.array([counts], dtype=np.int64), R_REF, bits)
    assert got.tolist() == [resistance_ohm]


def test_the_adc_is_ratiometric_so_the_supply_does_not_change_the_counts() -> None:
    def counts(supply_v: float) -> np.ndarray:
        config = ArrayConfig(scenario=Scenario.constant(2.0), noise_lsb_rms=0.0, param_spread=False)
        array = SimArray(config.with_changes(supply_v=supply_v), clock=lambda: 0.0)
        return array.latest().adc_counts

    at_5v = counts(5.0)
    np.testing.assert_array_equal(counts(3.3), at_5v)
    np.testing.assert_array_equal(counts(12.0), at_5v)
    # 2 N at t = 0: R = 46901.7 ohm (spec table: 46.9 kohm), 65535 / (1 + 4.69017) = 11517.2
    assert at_5v[0, 0] == 11517
