"""Read-out front ends against hand-computed numbers: the forward equations, the inverse, the
open/short/rail codes, quantization, garbage input and the refusals.

FS = 2^bits - 1; code = rint(offset + V / Vref * FS) (half to even), clipped to [0, FS].
"""

from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gateway.model import (
    FRONT_END_KINDS,
    Divider,
    DividerStatus,
    FrontEnd,
    LowSideDivider,
    RatioFrontEnd,
    Transimpedance,
    front_end_from_kind,
)

OK, OPEN, SHORT, INVALID, SATURATED = (
    DividerStatus.OK,
    DividerStatus.OPEN,
    DividerStatus.SHORT,
    DividerStatus.INVALID,
    DividerStatus.SATURATED,
)


@contextmanager
def no_warnings() -> Iterator[None]:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def read(fe: FrontEnd, counts: Any) -> tuple[list[float], list[int]]:
    with no_warnings():
        r, status = fe.resistance(np.asarray(counts))
    return r.tolist(), status.tolist()


# --------------------------------------------------------------------------- the status enum


def test_status_values_and_the_old_import_path() -> None:
    from gateway.model.divider import Divider as OldPathDivider
    from gateway.model.divider import DividerStatus as OldPathStatus

    assert OldPathDivider is Divider and OldPathStatus is DividerStatus
    assert [int(s) for s in DividerStatus] == [0, 1, 2, 3, 4]
    assert DividerStatus.SATURATED.name == "SATURATED"
    assert FRONT_END_KINDS == ("high_side", "low_side", "transimpedance", "ratio")
    assert (Divider.kind, LowSideDivider.kind, Transimpedance.kind, RatioFrontEnd.kind) == FRONT_END_KINDS
    assert all(isinstance(fe, FrontEnd) for fe in (Divider(), LowSideDivider(3.3, 1e4, 12)))


# --------------------------------------------------------------------------- high side (eq. 18)


def test_high_side_by_hand_ratiometric() -> None:
    d = Divider(supply_v=5.0, reference_ohm=10e3, adc_bits=16)
    # r = 10k: V = 5 * 10k / 20k = 2.5 V; code = rint(0.5 * 65535 = 32767.5) = 32768 (even);
    # back: r = 10k (65535 / 32768 - 1) = 10k * 32767 / 32768 = 9999.6948...
    assert float(d.output_voltage(10e3)) == 2.5
    assert int(d.counts_for(10e3)) == 32768
    r, status = read(d, [32768])
    assert r[0] == pytest.approx(10e3 * 32767 / 32768, rel=1e-15) and status == [OK]
    # r = 30k: V = 5 * 10k / 40k = 1.25 V; code = rint(0.25 * 65535 = 16383.75) = 16384;
    # back: r = 10k (65535 / 16384 - 1) = 10k * 49151 / 16384 = 29999.39...
    assert float(d.output_voltage(30e3)) == 1.25
    assert int(d.counts_for(30e3)) == 16384
    assert read(d, [16384])[0][0] == pytest.approx(10e3 * 49151 / 16384, rel=1e-15)
    # open: 0 V, code 0, OPEN; short: 5 V, code 65535, SHORT
    assert d.counts_for([np.inf, 0.0]).tolist() == [0, 65535]
    assert read(d, [0, 65535]) == ([math.inf, 0.0], [OPEN, SHORT])


def test_high_side_reference_below_the_supply_saturates_at_full_scale() -> None:
    d = Divider(supply_v=5.0, reference_ohm=10e3, adc_bits=12, adc_reference_v=3.3)
    # r = 10k: V = 2.5 V; x = 2.5 / 3.3 * 4095 = 3102.27 -> 3102;
    # back: V = 3102 * 3.3 / 4095 = 2.49978 V, r = 10k (5 / V - 1) = 10k (20475 / 10236.6 - 1) = 10001.76
    assert int(d.counts_for(10e3)) == 3102
    assert read(d, [3102])[0][0] == pytest.approx(10e3 * (20475 / 10236.6 - 1), rel=1e-12)
    # short: V = 5 V is beyond the 3.3 V rail (x = 6204.5): the converter sits at 4095, which
    # is not the short level: SATURATED, the bound r = 10k (5 / 3.3 - 1) = 5151.52 ohm
    assert int(d.counts_for(0.0)) == 4095
    r, status = read(d, [4095, 0])
    assert status == [SATURATED, OPEN]
    assert r[0] == pytest.approx(10e3 * (5 / 3.3 - 1), rel=1e-12) and r[1] == math.inf
    assert d.measurable_range_ohm()[0] == pytest.approx(10e3 * (5 / 3.3 - 1), rel=1e-12)


def test_high_side_offset_shifts_the_open_and_short_codes() -> None:
    up = Divider(supply_v=5.0, reference_ohm=10e3, adc_bits=12, adc_offset_counts=3.0)
    # open: x = 3 + 0 = 3: codes 0..3 read OPEN (at or beyond the open code)
    assert int(up.counts_for(np.inf)) == 3
    r, status = read(up, [0, 1, 2, 3, 4])
    assert status == [OPEN, OPEN, OPEN, OPEN, OK] and r[:4] == [math.inf] * 4
    # code 4: y = 4 - 3 = 1, r = 10k (4095 / 1 - 1) = 40.94 Mohm
    assert r[4] == pytest.approx(10e3 * 4094, rel=1e-15)
    # r = 10k: x = 3 + 2047.5 = 2050.5 -> 2050 (half to even); back y = 2047:
    # r = 10k (4095 / 2047 - 1) = 10k * 2048 / 2047 = 10004.885
    assert int(up.counts_for(10e3)) == 2050
    assert read(up, [2050])[0][0] == pytest.approx(10e3 * 2048 / 2047, rel=1e-12)
    # short: x = 3 + 4095 = 4098, beyond the rail: 4095 is SATURATED, y = 4092,
    # r = 10k (4095 / 4092 - 1) = 10k * 3 / 4092 = 7.331 ohm
    assert read(up, [4095]) == ([pytest.approx(10e3 * 3 / 4092, rel=1e-12)], [SATURATED])

    down = Divider(supply_v=5.0, reference_ohm=10e3, adc_bits=12, adc_offset_counts=-3.0)
    # open: x = -3, below the 0 rail: code 0 is SATURATED, y = 3, r = 10k (4095 / 3 - 1) = 13.64 Mohm;
    # short: x = 4092: codes 4092..4095 read SHORT
    assert down.counts_for([np.inf, 0.0]).tolist() == [0, 4092]
    r, status = read(down, [0, 4091, 4092, 4095])
    assert status == [SATURATED, OK, SHORT, SHORT]
    assert r[0] == pytest.approx(10e3 * 1364, rel=1e-12) and r[2:] == [0.0, 0.0]
    assert r[1] == pytest.approx(10e3 * (4095 / 4094 - 1), rel=1e-12)
    assert down.measurable_range_ohm()[1] == pytest.approx(13.64e6, rel=1e-12)


def test_default_divider_reads_exactly_the_closed_form_for_every_code() -> None:
    d = Divider()
    codes = np.arange(65536, dtype=np.int64)
    c = codes[1:-1].astype(np.float64)
    expected = np.concatenate([[np.inf], 10e3 * (65535 / c - 1), [0.0]])
    expected_status = np.zeros(65536, dtype=np.int8)
    expected_status[0], expected_status[-1] = OPEN, SHORT
    for counts in (codes, codes.astype(np.uint16), codes.astype(np.float64), codes.astype(np.int32)):
        with no_warnings():
            r, status = d.resistance(counts)
        assert r.dtype == np.float64 and status.dtype == np.int8
        assert np.array_equal(r, expected), counts.dtype
        assert np.array_equal(status, expected_status), counts.dtype
    # a reference spelled out equal to the supply is the same circuit and the same numbers
    r2, status2 = Divider(adc_reference_v=5.0).resistance(codes)
    assert np.array_equal(r2, expected) and np.array_equal(status2, expected_status)


def test_measurable_range_and_describe_of_the_default() -> None:
    d = Divider()
    # the extreme codes that are neither open nor short: 65534 and 1
    r_min, r_max = d.measurable_range_ohm()
    assert r_min == pytest.approx(10e3 / 65534, rel=1e-9)  # 10k (65535 / 65534 - 1) = 0.1526 ohm
    assert r_max == pytest.approx(10e3 * 65534, rel=1e-15)  # 655.34 Mohm
    text = d.describe()
    assert "\n" not in text
    for part in ("high_side", "Vs*R_ref/(R_ref + r)", "5 V", "10 kohm", "16 bit", "ratiometric"):
        assert part in text
    assert "code 0 (OPEN)" in text and "code 65535 (SHORT)" in text and "655.3 Mohm" in text


# --------------------------------------------------------------------------- low side


def test_low_side_by_hand_ratiometric() -> None:
    d = LowSideDivider(supply_v=3.3, reference_ohm=10e3, adc_bits=12)
    # r = 10k: V = 3.3 * 10k / 20k = 1.65 V; code = rint(0.5 * 4095 = 2047.5) = 2048 (half to
    # even); back: r = 10k * 2048 / (4095 - 2048) = 10k * 2048 / 2047 = 10004.88...
    assert float(d.output_voltage(10e3)) == pytest.approx(1.65, rel=1e-15)
    assert int(d.counts_for(10e3)) == 2048
    assert read(d, [2048]) == ([pytest.approx(10e3 * 2048 / 2047, rel=1e-15)], [OK])
    # r = 1k: V = 3.3 / 11 = 0.3 V; x = 4095 / 11 = 372.27 -> 372;
    # back: r = 10k * 372 / (4095 - 372) = 3.72e6 / 3723 = 999.19 ohm
    assert int(d.counts_for(1e3)) == 372
    assert read(d, [372])[0][0] == pytest.approx(3.72e6 / 3723, rel=1e-15)
    # open: V = Vs, code 4095, OPEN; short: 0 V, code 0, SHORT
    assert d.counts_for([np.inf, 0.0]).tolist() == [4095, 0]
    assert read(d, [4095, 0]) == ([math.inf, 0.0], [OPEN, SHORT])
    assert float(d.output_voltage(np.inf)) == 3.3 and float(d.output_voltage(0.0)) == 0.0
    # every code: r = 10k c / (4095 - c), rising with the code
    c = np.arange(1, 4095, dtype=np.float64)
    r, status = d.resistance(np.arange(1, 4095))
    np.testing.assert_allclose(r, 10e3 * c / (4095 - c), rtol=1e-13)
    assert np.all(status == OK) and np.all(np.diff(r) > 0)


def test_low_side_pull_up_above_the_adc_reference_saturates_instead_of_open() -> None:
    d = LowSideDivider(supply_v=5.0, reference_ohm=10e3, adc_bits=12, adc_reference_v=3.3)
    # r = 10k: V = 2.5 V; x = 2.5 / 3.3 * 4095 = 3102.27 -> 3102;
    # back: V = 3102 * 3.3 / 4095, r = 10k V / (5 - V) = 10k * 2047.32 / 2047.68 = 9998.24
    assert int(d.counts_for(10e3)) == 3102
    v = 3102 * 3.3 / 4095
    assert read(d, [3102])[0][0] == pytest.approx(10e3 * v / (5 - v), rel=1e-12)
    assert read(d, [3102])[0][0] == pytest.approx(10e3 * 2047.32 / 2047.68, rel=1e-12)
    # open: V = 5 V, beyond the 3.3 V rail: code 4095 is SATURATED, not OPEN, and reads the
    # bound r = 10k * 3.3 / (5 - 3.3) = 19411.76 ohm: the largest measurable resistance
    assert int(d.counts_for(np.inf)) == 4095
    r, status = read(d, [4095, 0])
    assert status == [SATURATED, SHORT]
    assert r == [pytest.approx(10e3 * 3.3 / 1.7, rel=1e-12), 0.0]
    r_min, r_max = d.measurable_range_ohm()
    assert r_max == pytest.approx(10e3 * 3.3 / 1.7, rel=1e-12)
    # r_min at code 1: V = 3.3 / 4095, r = 10k V / (5 - V) = 1.612 ohm
    assert r_min == pytest.approx(10e3 * (3.3 / 4095) / (5 - 3.3 / 4095), rel=1e-12)
    assert "beyond the rail (code 4095 reads SATURATED)" in d.describe()


def test_low_side_open_level_just_inside_the_rounding_of_full_scale_reads_open() -> None:
    # Vs slightly above Vref: x_open = 4095 * 3.3001 / 3.3 = 4095.12, rint = 4095: the code an
    # open sensor gives is full scale, so full scale reads OPEN (not SATURATED)
    d = LowSideDivider(supply_v=3.3001, reference_ohm=10e3, adc_bits=12, adc_reference_v=3.3)
    assert int(d.counts_for(np.inf)) == 4095
    assert read(d, [4095])[1] == [OPEN]


# --------------------------------------------------------------------------- transimpedance


def test_transimpedance_by_hand() -> None:
    t = Transimpedance(bias_v=1.0, feedback_ohm=10e3, adc_bits=12, adc_reference_v=3.3)
    # r = 10k: V = 1 * 10k / 10k = 1 V; x = 1 / 3.3 * 4095 = 1240.91 -> 1241;
    # back: V = 1241 * 3.3 / 4095 = 1.000073 V, r = 1 * 10k / V = 4.095e7 / 4095.3 = 9999.27
    assert float(t.output_voltage(10e3)) == 1.0
    assert int(t.counts_for(10e3)) == 1241
    assert read(t, [1241]) == ([pytest.approx(4.095e7 / 4095.3, rel=1e-12)], [OK])
    # r = 100k: V = 0.1 V; x = 124.09 -> 124; back: r = 10k * 4095 / (124 * 3.3) = 100073.3
    assert int(t.counts_for(100e3)) == 124
    assert read(t, [124])[0][0] == pytest.approx(4.095e7 / 409.2, rel=1e-12)
    # open: V = 0, code 0, OPEN; short: unbounded output, code 4095 is SATURATED and reads the
    # smallest measurable resistance 1 * 10k / 3.3 = 3030.30 ohm
    assert t.counts_for([np.inf, 0.0]).tolist() == [0, 4095]
    assert read(t, [0, 4095]) == ([math.inf, pytest.approx(10e3 / 3.3, rel=1e-12)], [OPEN, SATURATED])
    r_min, r_max = t.measurable_range_ohm()
    assert r_min == pytest.approx(10e3 / 3.3, rel=1e-12)
    assert r_max == pytest.approx(10e3 * 4095 / 3.3, rel=1e-12)  # code 1: 12.41 Mohm
    assert "Vb*R_f/r" in t.describe() and "code 4095 reads SATURATED" in t.describe()
    # linear in conductance: codes 1..4094 read r = 10k * 4095 / (3.3 c)
    c = np.arange(1, 4095)
    np.testing.assert_allclose(t.resistance(c)[0], 10e3 * 4095 / (3.3 * c), rtol=1e-13)


def test_transimpedance_output_and_adc_offsets_move_the_open_code() -> None:
    t = Transimpedance(1.0, 10e3, 12, 3.3, output_offset_v=0.01, adc_offset_counts=2.0)
    # open: V = Vos = 10 mV; x = 2 + 0.01 / 3.3 * 4095 = 14.41 -> 14: codes 0..14 read OPEN
    assert int(t.counts_for(np.inf)) == 14
    r, status = read(t, [0, 14, 15])
    assert status == [OPEN, OPEN, OK] and r[:2] == [math.inf, math.inf]
    # code 15: V = 13 * 3.3 / 4095, r = 10k / (V - 0.01) = 21.0 Mohm
    assert r[2] == pytest.approx(10e3 / (13 * 3.3 / 4095 - 0.01), rel=1e-12)
    # r = 10k: V = 1.01 V; x = 2 + 1.01 / 3.3 * 4095 = 1255.32 -> 1255;
    # back: V = 1253 * 3.3 / 4095 = 1.009758, r = 10k / 0.999758 = 10002.42
    assert int(t.counts_for(10e3)) == 1255
    assert read(t, [1255])[0][0] == pytest.approx(10e3 / (1253 * 3.3 / 4095 - 0.01), rel=1e-12)


def test_transimpedance_with_a_negative_output_offset_saturates_at_zero() -> None:
    t = Transimpedance(1.0, 10e3, 12, 3.3, output_offset_v=-0.033)
    # open: x = -0.033 / 3.3 * 4095 = -40.95, below the rail: code 0 is SATURATED,
    # r = 10k / (0 + 0.033) = 303030 ohm, the largest measurable resistance
    r, status = read(t, [0])
    assert status == [SATURATED] and r[0] == pytest.approx(10e3 / 0.033, rel=1e-12)
    assert t.measurable_range_ohm()[1] == pytest.approx(10e3 / 0.033, rel=1e-12)


# --------------------------------------------------------------------------- round trips


def _forward_code(fe: FrontEnd, r: float) -> float:
    """The exact (unrounded) code, written out from each equation."""
    fs, off = fe.full_scale, fe.adc_offset_counts
    if isinstance(fe, RatioFrontEnd):  # the divider with V+ = 1 V and R_ref = 1
        fe = fe.divider
    if isinstance(fe, Divider):
        v = fe.supply_v * fe.reference_ohm / (fe.reference_ohm + r)
    elif isinstance(fe, LowSideDivider):
        v = fe.supply_v * r / (fe.reference_ohm + r)
    else:
        assert isinstance(fe, Transimpedance)
        v = fe.output_offset_v + fe.bias_v * fe.feedback_ohm / r
    return off + v / fe.reference_v * fs


def _slope_ohm_per_code(fe: FrontEnd, x: float) -> float:
    """|dr/dcode| at the (fractional) code x, from the derivative of each inverse."""
    if isinstance(fe, RatioFrontEnd):  # the divider with V+ = 1 V and R_ref = 1
        fe = fe.divider
    fs, vref = fe.full_scale, fe.reference_v
    v = (x - fe.adc_offset_counts) / fs * vref
    if isinstance(fe, Divider):  # r = R (Vs / V - 1): dr/dV = -R Vs / V^2
        dr_dv = fe.reference_ohm * fe.supply_v / v**2
    elif isinstance(fe, LowSideDivider):  # r = R V / (Vs - V): dr/dV = R Vs / (Vs - V)^2
        dr_dv = fe.reference_ohm * fe.supply_v / (fe.supply_v - v) ** 2
    else:  # r = Vb Rf / (V - Vos): dr/dV = -Vb Rf / (V - Vos)^2
        assert isinstance(fe, Transimpedance)
        dr_dv = fe.bias_v * fe.feedback_ohm / (v - fe.output_offset_v) ** 2
    return abs(dr_dv) * vref / fs


@st.composite
def front_ends(draw: st.DrawFn) -> FrontEnd:
    kind = draw(st.sampled_from(FRONT_END_KINDS))
    bits = draw(st.integers(8, 24))
    half = (2**bits - 1) / 2
    offset = draw(st.one_of(st.just(0.0), st.floats(-0.2 * half, 0.2 * half)))
    vref = draw(st.floats(0.5, 10.0))
    try:
        if kind == "ratio":
            return RatioFrontEnd(bits, draw(st.booleans()), offset)
        if kind == "transimpedance":
            return Transimpedance(
                bias_v=draw(st.floats(0.01, 10.0)),
                feedback_ohm=draw(st.floats(10.0, 1e7)),
                adc_bits=bits,
                adc_reference_v=vref,
                output_offset_v=draw(st.floats(-0.2, 0.3)) * vref,
                adc_offset_counts=offset,
            )
        ratiometric = draw(st.booleans())
        return front_end_from_kind(
            kind,
            supply_v=draw(st.floats(0.5, 10.0)),
            reference_ohm=draw(st.floats(10.0, 1e7)),
            adc_bits=bits,
            adc_reference_v=None if ratiometric else vref,
            adc_offset_counts=offset,
        )
    except ValueError:
        assume(False)
        raise


@settings(max_examples=400, deadline=None)
@given(fe=front_ends(), where=st.floats(0.0, 1.0))
def test_round_trip_within_half_an_lsb(fe: FrontEnd, where: float) -> None:
    """resistance -> code -> resistance moves r by at most the resistance change of half an
    LSB: |r' - r| <= |code - x| max |dr/dcode| on [x, code], with |code - x| <= 1/2 (mean
    value theorem; |dr/dcode| is monotone between the open and short codes)."""
    r_min, r_max = fe.measurable_range_ohm()
    assert 0.0 < r_min < r_max < math.inf
    r = math.exp(math.log(r_min) + where * (math.log(r_max) - math.log(r_min)))
    r = min(max(r, r_min), r_max)
    x = _forward_code(fe, r)
    with no_warnings():
        code = int(fe.counts_for(r))
        back, status = fe.resistance(np.array([code]))
    assert code == np.rint(x) or abs(code - x) <= 0.5 + 1e-6  # x within float noise of a half
    assert int(status[0]) in (OK, SATURATED)
    if int(status[0]) == SATURATED:
        assert code in (0, fe.full_scale)
    bound = abs(code - x) * max(_slope_ohm_per_code(fe, x), _slope_ohm_per_code(fe, code))
    # a divider's inverse r = R (FS / y - 1) (or R y / (FS - y)) subtracts numbers of size R:
    # near the short end (r << R) its rounding error is a few ulps of R, not of r
    divider = fe.divider if isinstance(fe, RatioFrontEnd) else fe
    ref = divider.reference_ohm if isinstance(divider, Divider | LowSideDivider) else 0.0
    rounding = 8 * sys.float_info.epsilon * (ref + r)
    assert abs(float(back[0]) - r) <= bound * (1 + 1e-9) + 1e-9 * r + rounding


@settings(max_examples=150, deadline=None)
@given(fe=front_ends())
def test_every_code_reads_monotonically_with_consistent_status(fe: FrontEnd) -> None:
    fs = fe.full_scale
    codes = np.unique(np.linspace(0, fs, min(fs + 1, 5000)).round().astype(np.int64))
    with no_warnings():
        r, status = fe.resistance(codes)
    assert not np.any(status == INVALID)
    assert np.all(np.isinf(r) == (status == OPEN)) and np.all((r == 0.0) == (status == SHORT))
    finite = (status == OK) | (status == SATURATED)
    assert np.all(np.isfinite(r[finite]) & (r[finite] > 0.0))
    assert np.all(np.isin(codes[status == SATURATED], [0, fs]))
    # high side and transimpedance fall with the code, low side rises (a ratio read-out falling with
    # load is a low side); ties only in OPEN/SHORT runs
    r_rises = isinstance(fe, LowSideDivider) or (isinstance(fe, RatioFrontEnd) and not fe.rises_with_load)
    ordered = np.minimum(r[::-1] if r_rises else r, np.finfo(np.float64).max)
    assert np.all(np.diff(ordered) <= 0.0)
    # the open sensor's code reads OPEN, or SATURATED at a rail when its level is beyond it
    open_code = int(fe.counts_for(np.inf))
    _, open_status = fe.resistance(np.array([open_code]))
    assert int(open_status[0]) in (OPEN, SATURATED)


# --------------------------------------------------------------------------- garbage in


GARBAGE_FLOATS = [np.nan, np.inf, -np.inf, -1.0, -0.5, -1e300, 1e300, 65536.0, 4096.0, 1e20, 0.5, 5e-324]

ALL_FRONT_ENDS = [
    Divider(),
    Divider(adc_bits=12, adc_reference_v=3.3, adc_offset_counts=-2.5),
    LowSideDivider(3.3, 10e3, 12),
    LowSideDivider(5.0, 10e3, 16, adc_reference_v=3.3, adc_offset_counts=7.0),
    Transimpedance(1.0, 10e3, 12, 3.3),
    Transimpedance(0.5, 1e6, 16, 2.5, output_offset_v=0.02, adc_offset_counts=-4.0),
    RatioFrontEnd(12),
    RatioFrontEnd(16, rises_with_load=False, adc_offset_counts=3.0),
]


@pytest.mark.parametrize("fe", ALL_FRONT_ENDS, ids=lambda fe: fe.describe()[:60])
def test_garbage_never_raises_or_warns(fe: FrontEnd) -> None:
    fs = fe.full_scale
    i64 = np.iinfo(np.int64)
    with np.errstate(over="ignore"):
        as_float32 = np.array(GARBAGE_FLOATS, dtype=np.float32)
    inputs: list[Any] = [
        np.array(GARBAGE_FLOATS),
        as_float32,
        np.array([i64.min, -1, 0, fs, fs + 1, i64.max], dtype=np.int64),
        np.array([0, 1, fs, 2**64 - 1], dtype=np.uint64),
        np.array([-128, -1, 0, 1, 127], dtype=np.int8),
        np.array([[np.nan, 0.0], [fs / 2, -3.0]]),
        np.array([], dtype=np.float64),
        np.array([], dtype=np.int64),
        np.array([True, False]),
        np.array([1 + 2j, 3 + 0j]),
        np.array([None, "x", 1.5, 10**400], dtype=object),
        np.array(["12", "abc"]),
        np.nan,
        -7,
        fs + 1,
        [1, 2.5, np.inf],
        "nonsense",
    ]
    for counts in inputs:
        shape = np.shape(counts)
        with no_warnings():
            r, status = fe.resistance(counts)
        assert r.shape == shape and status.shape == shape, counts
        assert r.dtype == np.float64 and status.dtype == np.int8
        assert np.all(np.isin(status, [0, 1, 2, 3, 4]))
        assert np.array_equal(np.isnan(r), status == INVALID), counts
    r, status = fe.resistance(np.array(GARBAGE_FLOATS))
    expect_invalid = [True, True, True, True, True, True, True, fs < 65536, fs < 4096, True, False, False]
    assert (status == INVALID).tolist() == expect_invalid


@settings(max_examples=200, deadline=None)
@given(
    fe=st.sampled_from(ALL_FRONT_ENDS),
    codes=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=20)
    | st.lists(st.integers(-(2**63), 2**63 - 1), max_size=20),
)
def test_any_number_reads_without_warnings(fe: FrontEnd, codes: list[float] | list[int]) -> None:
    with no_warnings():
        r, status = fe.resistance(np.array(codes))
    c = np.array(codes, dtype=np.float64)
    outside = ~np.isfinite(c) | (c < 0) | (c > fe.full_scale)
    assert np.array_equal(status == INVALID, outside)
    assert np.all(np.isnan(r[outside])) and not np.any(np.isnan(r[~outside]))
    assert np.all(r[~outside] >= 0.0)


@pytest.mark.parametrize("fe", ALL_FRONT_ENDS, ids=lambda fe: fe.kind)
def test_counts_for_refuses_what_has_no_code(fe: FrontEnd) -> None:
    for bad in (np.nan, -1.0, [10.0, -np.inf]):
        with pytest.raises(ValueError, match=r"resistance_ohm must be in \[0, inf\] ohm"):
            fe.counts_for(bad)
    with no_warnings():
        codes = fe.counts_for(np.array([[0.0, 1e-300], [1e300, np.inf]]))
    assert codes.shape == (2, 2) and codes.dtype == np.int64
    assert np.all((codes >= 0) & (codes <= fe.full_scale))


# --------------------------------------------------------------------------- refusals


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: Divider(reference_ohm=-5), r"^reference_ohm = -5 must be in \(0, inf\) ohm$"),
        (lambda: Divider(supply_v=math.nan), r"^supply_v = nan must be in \(0, inf\) V$"),
        (lambda: Divider(supply_v=True), r"^supply_v = True must be in \(0, inf\) V$"),
        (lambda: Divider(adc_bits=7), r"^adc_bits = 7 must be an integer in \[8, 24\]$"),
        (lambda: Divider(adc_bits=12.0), r"^adc_bits = 12.0 must be an integer in \[8, 24\]$"),  # type: ignore[arg-type]
        (lambda: Divider(adc_reference_v=0.0), r"^adc_reference_v = 0.0 must be in \(0, inf\) V$"),
        (
            lambda: Divider(adc_bits=12, adc_offset_counts=2047.5),
            r"^adc_offset_counts = 2047.5 must be in \(-2047.5, 2047.5\) counts",
        ),
        (
            lambda: LowSideDivider(3.3, 10e3, 12, adc_offset_counts=math.inf),
            r"^adc_offset_counts = inf must be in \(-2047.5, 2047.5\) counts",
        ),
        (lambda: LowSideDivider(3.3, math.inf, 12), r"^reference_ohm = inf must be in \(0, inf\) ohm$"),
        (lambda: LowSideDivider(-3.3, 1e4, 12), r"^supply_v = -3.3 must be in \(0, inf\) V$"),
        (lambda: Transimpedance(0.0, 1e4, 12, 3.3), r"^bias_v = 0.0 must be in \(0, inf\) V$"),
        (lambda: Transimpedance(1.0, -1.0, 12, 3.3), r"^feedback_ohm = -1.0 must be in \(0, inf\) ohm$"),
        (lambda: Transimpedance(1.0, 1e4, 25, 3.3), r"^adc_bits = 25 must be an integer in \[8, 24\]$"),
        (lambda: Transimpedance(1.0, 1e4, 12, -3.3), r"^adc_reference_v = -3.3 must be in \(0, inf\) V$"),
        (
            lambda: Transimpedance(1.0, 1e4, 12, 3.3, output_offset_v=math.nan),
            r"^output_offset_v = nan must be a finite number \(V\)",
        ),
    ],
)
def test_bad_parameters_are_refused_naming_the_field(build: Any, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        build()


def test_a_transimpedance_that_saturates_when_open_is_refused() -> None:
    # open: x = 3.3 / 3.3 * 4095 = 4095: the open sensor already reads full scale, so every
    # resistance reads the rail
    with pytest.raises(ValueError, match=r"nothing is measurable.*output_offset_v = 3.3 V"):
        Transimpedance(1.0, 10e3, 12, 3.3, output_offset_v=3.3)
    # open code 4094.5 -> rint 4094 (half to even): 4094 OPEN, 4095 SATURATED: no code left
    with pytest.raises(ValueError, match="nothing is measurable"):
        Transimpedance(1.0, 10e3, 12, 3.3, output_offset_v=3.3 * 4094.5 / 4095)
    # open code 4093: 4094 is the one code with a finite reading
    t = Transimpedance(1.0, 10e3, 12, 3.3, output_offset_v=3.3 * 4093 / 4095)
    assert read(t, [4093, 4094, 4095])[1] == [OPEN, OK, SATURATED]


def test_a_divider_with_no_code_between_open_and_short_is_refused() -> None:
    # Vs = 1 uV on a 5 V reference: the short sensor's code is 4095 * 2e-7 = 0.0008 -> 0
    with pytest.raises(ValueError, match="nothing is measurable"):
        Divider(supply_v=1e-6, reference_ohm=1e4, adc_bits=12, adc_reference_v=5.0)
    with pytest.raises(ValueError, match="nothing is measurable"):
        LowSideDivider(supply_v=1e-6, reference_ohm=1e4, adc_bits=12, adc_reference_v=5.0)


def test_front_ends_are_frozen_and_hashable() -> None:
    d = Divider()
    with pytest.raises(AttributeError):
        d.supply_v = 3.3  # type: ignore[misc]
    assert len({Divider(), Divider(), LowSideDivider(5.0, 10e3, 16)}) == 2
    assert Divider(5.0, 10e3, 16) != LowSideDivider(5.0, 10e3, 16)


# --------------------------------------------------------------------------- the factory


def test_factory_builds_each_kind() -> None:
    assert front_end_from_kind("high_side") == Divider()
    assert front_end_from_kind("high_side", supply_v=3.3, reference_ohm=4.7e3, adc_bits=12) == Divider(
        3.3, 4.7e3, 12
    )
    assert front_end_from_kind("low_side", supply_v=3.3, reference_ohm=1e4, adc_bits=12) == LowSideDivider(
        3.3, 1e4, 12
    )
    t = front_end_from_kind(
        "transimpedance", bias_v=1.0, feedback_ohm=1e4, adc_bits=12, adc_reference_v=3.3, output_offset_v=0.01
    )
    assert t == Transimpedance(1.0, 1e4, 12, 3.3, output_offset_v=0.01)


def test_factory_names_unknown_kinds_and_keys() -> None:
    with pytest.raises(
        ValueError,
        match=r"unknown front end kind 'divider'; allowed kinds: high_side, low_side, transimpedance, ratio",
    ):
        front_end_from_kind("divider")
    with pytest.raises(
        ValueError, match=r"unknown parameter 'bias_v' for front end kind 'low_side'; allowed"
    ):
        front_end_from_kind("low_side", supply_v=3.3, reference_ohm=1e4, adc_bits=12, bias_v=1.0)
    with pytest.raises(
        ValueError, match=r"allowed parameters: supply_v, reference_ohm, adc_bits, adc_reference_v"
    ):
        front_end_from_kind("high_side", R=1.0)
    with pytest.raises(ValueError, match=r"missing parameters 'feedback_ohm', 'adc_bits', 'adc_reference_v'"):
        front_end_from_kind("transimpedance", bias_v=1.0)
    with pytest.raises(ValueError, match=r"^reference_ohm = -5 must be in \(0, inf\) ohm$"):
        front_end_from_kind("low_side", supply_v=3.3, reference_ohm=-5, adc_bits=12)
