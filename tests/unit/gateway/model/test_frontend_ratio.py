"""The ratio front end against hand-computed numbers: r_rel = r / R_ref from the code alone.

Counts rising with load (high side, eq. 18 with V+ = 1 and R_ref = 1): r_rel = FS / code - 1;
falling (low side, a pull-up): r_rel = code / (FS - code); FS = 2^bits - 1.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.model import Divider, DividerStatus, LowSideDivider, RatioFrontEnd, front_end_from_kind

OK, OPEN, SHORT, INVALID, SATURATED = (
    int(DividerStatus.OK),
    int(DividerStatus.OPEN),
    int(DividerStatus.SHORT),
    int(DividerStatus.INVALID),
    int(DividerStatus.SATURATED),
)


def read(fe: RatioFrontEnd, counts: object) -> tuple[list[float], list[int]]:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r, status = fe.resistance(np.asarray(counts))
    return r.tolist(), status.tolist()


def test_rising_with_load_by_hand() -> None:
    fe = RatioFrontEnd(adc_bits=12)
    # 4095 / 1000 - 1 = 3.095; 4095 / 4094 - 1 = 1 / 4094; 4095 / 1 - 1 = 4094
    r, status = read(fe, [1000, 4094, 1, 2048])
    assert r == pytest.approx([3.095, 1 / 4094, 4094.0, 2047 / 2048], rel=1e-15)
    assert status == [OK] * 4
    # float counts too (a mean of codes, as tare takes it)
    assert read(fe, [1000.5])[0] == pytest.approx([4095 / 1000.5 - 1], rel=1e-15)


def test_falling_with_load_by_hand() -> None:
    fe = RatioFrontEnd(adc_bits=12, rises_with_load=False)
    # 1000 / (4095 - 1000) = 1000 / 3095 = 0.32310177705977383; 4094 / 1 = 4094; 1 / 4094
    r, status = read(fe, [1000, 4094, 1, 2048])
    assert r == pytest.approx([1000 / 3095, 4094.0, 1 / 4094, 2048 / 2047], rel=1e-15)
    assert status == [OK] * 4


def test_statuses_at_the_rails_beyond_and_nan() -> None:
    up, down = RatioFrontEnd(12), RatioFrontEnd(12, rises_with_load=False)
    # rising: code 0 is the open sensor (no current through it), full scale the short
    r, status = read(up, [0, 4095, 4096, -1])
    assert r[:2] == [math.inf, 0.0] and math.isnan(r[2]) and math.isnan(r[3])
    assert status == [OPEN, SHORT, INVALID, INVALID]
    r, status = read(down, [0, 4095, 4096, -1])
    assert r[:2] == [0.0, math.inf] and math.isnan(r[2]) and math.isnan(r[3])
    assert status == [SHORT, OPEN, INVALID, INVALID]
    r, status = read(up, [math.nan, 70000.0])
    assert math.isnan(r[0]) and math.isnan(r[1]) and status == [INVALID, INVALID]
    # a negative offset puts the open code below 0: code 0 reads SATURATED at 4095 / 5 - 1 = 818
    off = RatioFrontEnd(12, adc_offset_counts=-5.0)
    r, status = read(off, [0, 5, 4090])
    assert status == [SATURATED, OK, SHORT]
    assert r[0] == pytest.approx(4095 / 5 - 1, rel=1e-15) and r[1] == pytest.approx(4095 / 10 - 1, rel=1e-15)


def test_the_statuses_are_the_dividers_own() -> None:
    """With R_ref = 1 the divider reads the same numbers and statuses, whatever its supply."""
    codes = np.array([0, 1, 7, 2047, 2048, 4094, 4095, 4096, -3])
    for ratio, divider in (
        (RatioFrontEnd(12), Divider(3.3, 1.0, 12)),
        (RatioFrontEnd(12, rises_with_load=False), LowSideDivider(5.0, 1.0, 12)),
        (RatioFrontEnd(12, adc_offset_counts=2.5), Divider(3.3, 1.0, 12, adc_offset_counts=2.5)),
    ):
        r, s = ratio.resistance(codes)
        r_div, s_div = divider.resistance(codes)
        np.testing.assert_array_equal(s, s_div)
        np.testing.assert_allclose(r, r_div, rtol=1e-15)


@settings(max_examples=200, deadline=None)
@given(bits=st.integers(8, 16), rises=st.booleans(), share=st.floats(0.0, 1.0))
def test_counts_to_r_rel_to_counts(bits: int, rises: bool, share: float) -> None:
    fe = RatioFrontEnd(bits, rises)
    fs = fe.full_scale
    code = 1 + round(share * (fs - 2))  # every code strictly between the rails reads OK
    r, status = fe.resistance(np.array([code]))
    assert int(status[0]) == OK
    expected = fs / code - 1.0 if rises else code / (fs - code)
    assert float(r[0]) == pytest.approx(expected, rel=1e-12)
    assert int(fe.counts_for(r)[0]) == code


def test_describe_says_relative_and_needs_a_calibration() -> None:
    text = RatioFrontEnd(12).describe()
    assert text.startswith("ratio: r/R_ref = FS/code - 1 (counts rise with load")
    assert "FS = 4095" in text and "open -> code 0 (OPEN), short -> code 4095 (SHORT)" in text
    # the measurable range: code 4094 and code 1, 1/4094 = 0.0002443 and 4094
    assert "reads 0.0002443 R_ref .. 4094 R_ref" in text
    assert "units of the board's unknown reference resistor R_ref, not ohm" in text
    assert "no circuit value is assumed" in text and "forces need a calibration" in text
    falling = RatioFrontEnd(12, rises_with_load=False).describe()
    assert "r/R_ref = code/(FS - code) (counts fall with load" in falling
    assert "open -> code 4095 (OPEN), short -> code 0 (SHORT)" in falling


def test_factory_and_refusals() -> None:
    assert front_end_from_kind("ratio", adc_bits=12) == RatioFrontEnd(12, True, 0.0)
    with pytest.raises(ValueError, match=r"unknown parameter 'reference_ohm' for front end kind 'ratio'"):
        front_end_from_kind("ratio", adc_bits=12, reference_ohm=4.7e3)
    with pytest.raises(ValueError, match=r"missing parameter 'adc_bits' for front end kind 'ratio'"):
        front_end_from_kind("ratio")
    with pytest.raises(ValueError, match=r"^adc_bits = 7 must be an integer in \[8, 24\]$"):
        RatioFrontEnd(7)
    with pytest.raises(ValueError, match=r"^rises_with_load = 1 must be true or false"):
        RatioFrontEnd(12, 1)  # type: ignore[arg-type]
    with pytest.raises(
        ValueError, match=r"^adc_offset_counts = 2047.5 must be in \(-2047.5, 2047.5\) counts"
    ):
        RatioFrontEnd(12, adc_offset_counts=2047.5)
    fe = RatioFrontEnd(12)
    with pytest.raises(AttributeError):
        fe.adc_bits = 16  # type: ignore[misc]
    assert len({RatioFrontEnd(12), RatioFrontEnd(12), RatioFrontEnd(12, False)}) == 2
