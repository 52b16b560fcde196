"""Channels read with a calibration's line or lookup instead of the physical model."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.errors import ConfigError
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, ForceStatus, SensorModel, SensorParams
from gateway.model.conversion import (
    Conversion,
    ConversionError,
    line_conversion,
    lookup_conversion,
)
from gateway.model.tracker import CurveSet
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus

M, N = 2e-5, 1e-6  # S/N, S
LINE = line_conversion(slope_s_per_n=M, intercept_s=N, force_min_n=0.05, force_max_n=10.0)
LOOKUP = lookup_conversion(resistance_ohm=(1e3, 1e4, 1e5), force_n=(8.0, 2.0, 0.5))


def _apply(conversions: list[Conversion], r: np.ndarray, force: np.ndarray, status: np.ndarray) -> None:
    """The tracker's reading of one sample (force N, ``ForceStatus`` with extrapolated)."""
    curves = CurveSet(conversions)
    f, st, _, extrapolated, _ = curves.track(np.asarray(r, dtype=np.float64), curves.initial_state(), 0.0)
    force[:] = f
    status[:] = np.where(extrapolated, np.int8(ForceStatus.EXTRAPOLATED), st)


def _r_line(force_n: float) -> float:
    return 1.0 / (M * force_n + N)


def make_device(
    conversions: list[Conversion | None],
    encoding: str = "float32",
    baseline_ohm: list[float | None] | None = None,
    enabled: list[bool] | None = None,
) -> DeviceConfig:
    n = len(conversions)
    channels = tuple(
        ChannelConfig(
            index=i,
            name=f"ch{i:02d}",
            x_mm=float(i),
            y_mm=0.0,
            enabled=True if enabled is None else enabled[i],
            effects=PAPER_EFFECTS,
            params=SensorParams(),
            baseline_ohm=None if baseline_ohm is None else baseline_ohm[i],
            conversion=conversions[i],
        )
        for i in range(n)
    )
    return DeviceConfig(
        name="arr",
        device_id=1,
        encoding=encoding,
        n_channels=n,
        registers=RegisterMap(),
        front_end=Divider(),
        channels=channels,
        allow_write=False,
        layout=GridLayout(n, n, 2.5, 2.5),
        calibration=None,
    )


def _read(conversions: list[Conversion | None], r: list[float]) -> tuple[np.ndarray, list[str]]:
    proc = DeviceProcessor(make_device(conversions), "bus", 0.1)
    snap, _ = proc.process(proc.rested_state(), RawSample(resistance_ohm=np.array(r)), 0.0, 0.0)
    np.testing.assert_array_equal(snap.force_static_n, snap.force_n)  # stateless: static = force
    return np.asarray(snap.force_n), [ChannelStatus(s).label for s in snap.status]


def test_line_reads_the_hand_value() -> None:
    r = 1.0 / (2e-5 * 3 + 1e-6)
    assert r == pytest.approx(16393.44, abs=0.01)
    force, status = _read([LINE], [r])
    assert status == ["ok"]
    assert force[0] == pytest.approx(3.000, abs=1e-9)


def test_line_beyond_its_range_reads_along_itself_flagged_extrapolated() -> None:
    rs = [
        _r_line(0.05),  # at the lower bound: inside the calibrated range
        _r_line(0.0501),  # just inside
        _r_line(0.01),  # below it: read along the line, flagged
        _r_line(0.0),  # the line's 0 N: no contact
        _r_line(-0.04),  # the line's negative forces: conductance below its intercept
        1e12,  # far below (nearly open)
        math.inf,  # open at rest (with fault bitmaps the open rail is a reading)
        _r_line(9.999),
        _r_line(10.0),  # at the upper bound
        _r_line(25.0),  # beyond it: read along the line, never clipped, and the status says so
    ]
    force, status = np.zeros(len(rs)), np.zeros(len(rs), dtype=np.int8)
    _apply([LINE] * len(rs), np.array(rs), force, status)
    labels = [ForceStatus(s).name.lower() for s in status]
    assert labels == ["ok", "ok", "extrapolated"] + ["no_contact"] * 4 + ["ok", "ok", "extrapolated"]
    np.testing.assert_allclose(
        force, [0.05, 0.0501, 0.01, 0.0, 0.0, 0.0, 0.0, 9.999, 10.0, 25.0], rtol=1e-9, atol=0
    )
    # through the processor: the same, as channel statuses
    force, labels = _read([LINE] * 4, [_r_line(0.01), _r_line(3.0), _r_line(25.0), 1e12])
    assert labels == ["extrapolated", "ok", "extrapolated", "no_contact"]
    np.testing.assert_allclose(force, [0.01, 3.0, 25.0, 0.0], rtol=1e-9)


def test_a_short_rail_read_as_a_reading_is_saturated_not_extrapolated_to_1e300_n() -> None:
    """With fault bitmaps a 0 ohm reading that is not flagged short reaches the conversion as
    the smallest normal float: less than the converter resolves, so saturated at the bound."""
    proc = DeviceProcessor(make_device([LINE, LOOKUP]), "bus", 0.1)
    no_fault = np.zeros(2, dtype=np.bool_)
    raw = RawSample(resistance_ohm=np.array([0.0, 0.0]), open_bits=no_fault, short_bits=no_fault)
    snap, _ = proc.process(proc.rested_state(), raw, 0.0, 0.0)
    assert [ChannelStatus(s).label for s in snap.status] == ["saturated"] * 2
    np.testing.assert_array_equal(snap.force_n, [10.0, 8.0])


def test_garbage_resistances_are_errors_not_forces() -> None:
    r = np.array([np.nan, -5.0, 0.0, -np.inf])
    force = np.zeros(4)
    status = np.zeros(4, dtype=np.int8)
    _apply([LINE, LINE, LOOKUP, LOOKUP], r, force, status)
    assert status.tolist() == [ForceStatus.INVALID] * 4
    assert np.isnan(force).all()
    # through the processor: NaN and negative are errors; 0 ohm and +inf are the rails, as for any channel
    out, labels = _read([LINE, LOOKUP, LINE, LOOKUP], [math.nan, -5.0, 0.0, math.inf])
    assert labels == ["error", "error", "short", "open"]
    assert np.isnan(out).all()


def test_lookup_three_points_by_hand() -> None:
    # ln R midway between 1e3 and 1e4 -> midway between 8 N and 2 N; a quarter of the way
    # from 1e4 to 1e5 -> 2 - 0.25 * 1.5 N; the knots' forces (8 N, 0.5 N) are inside the range
    rs = [math.sqrt(1e3 * 1e4), 1e4, 1e4 * 10**0.25, 1e3, 1e5, 1e5 * 0.999]
    force, status = _read([LOOKUP] * len(rs), rs)
    assert status == ["ok"] * 6
    tail = 0.5 + 1.5 * (np.log(1e5) - np.log(1e5 * 0.999)) / np.log(10.0)
    np.testing.assert_allclose(force, [5.0, 2.0, 1.625, 8.0, 0.5, tail], rtol=1e-12)


def test_lookup_beyond_its_knots_reads_along_its_end_segments_flagged_extrapolated() -> None:
    # before the first knot along the first segment (-6 N per decade of R), beyond the last
    # along the last (-1.5 N per decade) down to 0 N at 1e5 * 10^(1/3) ohm, then no contact
    rs = [500.0, 100.0, 1e5 * 10 ** (1 / 6), 1e5 * 10 ** (1 / 3) * 1.01, 1e6, math.inf]
    force, status = _read([LOOKUP] * len(rs), rs)
    assert status == ["extrapolated", "extrapolated", "extrapolated", "no_contact", "no_contact", "open"]
    expected = [8.0 + 6.0 * math.log10(2.0), 14.0, 0.25, 0.0, 0.0, math.nan]
    np.testing.assert_allclose(force, expected, rtol=1e-12)
    raw_force, raw_status = np.zeros(1), np.zeros(1, dtype=np.int8)
    _apply([LOOKUP], np.array([math.inf]), raw_force, raw_status)  # open as a reading
    assert raw_status[0] == ForceStatus.NO_CONTACT and raw_force[0] == 0.0


def test_a_lookup_with_flat_ends_extends_along_its_sloped_end_segments() -> None:
    """A bench's holds give bins of equal median force: a flat end extended flat would read
    its force at any resistance beyond it (a phantom force at rest). The lookup extends along
    the segment to the nearest knot of another force, as its unloaded conductance does."""
    flat = lookup_conversion((1e3, 2e3, 1e4, 1e5, 2e5), (8.0, 8.0, 2.0, 0.5, 0.5))
    rs = [500.0, 2e5 * 10 ** (1 / 6), 1e7, flat.unloaded_resistance_ohm]
    force, status = _read([flat] * len(rs), rs)
    assert status == ["extrapolated", "extrapolated", "no_contact", "no_contact"]
    # first sloped segment: 1e3..1e4 (8 -> 2 N), last: 1e4..2e5 (2 -> 0.5 N)
    up = 8.0 + 6.0 * math.log(2.0) / math.log(10.0)
    down = 0.5 - 1.5 * (math.log(10 ** (1 / 6))) / math.log(20.0)
    np.testing.assert_allclose(force, [up, down, 0.0, 0.0], rtol=1e-12)


def test_lookups_of_different_lengths_and_lines_in_one_device() -> None:
    five = lookup_conversion((100.0, 200.0, 400.0, 800.0, 1600.0), (20.0, 10.0, 10.0, 5.0, 1.0))
    rs = [_r_line(3.0), math.sqrt(1e4 * 1e5), 300.0, 1131.370849898476, _r_line(7.5)]
    force, status = _read([LINE, LOOKUP, five, five, LINE], rs)
    assert status == ["ok"] * 5
    np.testing.assert_allclose(force, [3.0, 1.25, 10.0, 3.0, 7.5], rtol=1e-9)


def test_a_lookup_that_goes_below_zero_reads_no_contact_there() -> None:
    lk = lookup_conversion((1e3, 1e4), (4.0, -4.0))
    force, status = _read([lk, lk, lk], [1e3 * 10**0.25, math.sqrt(1e3 * 1e4), 1e3 * 10**0.75])
    assert status == ["ok", "no_contact", "no_contact"]
    np.testing.assert_allclose(force, [2.0, 0.0, 0.0], rtol=1e-12)
    assert lk.unloaded_resistance_ohm == pytest.approx(math.sqrt(1e3 * 1e4))


def test_channels_without_a_conversion_are_bitwise_unchanged() -> None:
    model = SensorModel(PAPER_EFFECTS, [SensorParams()] * 4)
    r_phys = model.resistance(np.array([0.3, 1.0, 2.0, 4.0]))
    rs = np.array([r_phys[0], _r_line(3.0), r_phys[1], r_phys[2], 2000.0, r_phys[3]])
    mixed = make_device([None, LINE, None, None, LOOKUP, None])
    plain = make_device([None] * 6, enabled=[True, False, True, True, False, True])
    a, b = DeviceProcessor(mixed, "bus", 0.1), DeviceProcessor(plain, "bus", 0.1)
    assert DeviceProcessor(make_device([None] * 6), "bus", 0.1).curves is None
    sa, sb = a.initial_state(), b.initial_state()
    for k, t in enumerate([0.0, 1.0, 5.0, 30.0]):
        raw = RawSample(resistance_ohm=rs * (1.0 - 0.01 * k), device_time_s=t)
        snap_a, sa = a.process(sa, raw, t, t)
        snap_b, sb = b.process(sb, RawSample(resistance_ohm=raw.resistance_ohm), t, t)
        phys = [0, 2, 3, 5]
        np.testing.assert_array_equal(snap_a.force_n[phys], snap_b.force_n)
        np.testing.assert_array_equal(snap_a.status[phys], snap_b.status)
        np.testing.assert_array_equal(snap_a.force_static_n[phys], snap_b.force_static_n)
        assert snap_a.status[1] == ChannelStatus.OK and snap_a.force_static_n[1] == snap_a.force_n[1]
    # the converted channels carry no creep state; the others do
    strain = np.asarray(dataclasses.astuple(sa.model_state)[0])
    assert np.all(strain[[1, 4]] == 0.0) and np.all(strain[[0, 2, 3, 5]] != 0.0)


def test_a_device_of_converted_channels_only() -> None:
    force, status = _read([LINE, LOOKUP], [_r_line(1.5), 1e4])
    assert status == ["ok", "ok"]
    np.testing.assert_allclose(force, [1.5, 2.0])


def test_baseline_is_taken_off_before_the_line() -> None:
    # the channel reads 40 kohm unloaded where the line has 1/n at 0 N: 1/40k - n is leakage
    baseline = 40e3
    dev = make_device([LINE, LOOKUP], baseline_ohm=[baseline, 2e5])
    proc = DeviceProcessor(dev, "bus", 0.1)
    excess = 1.0 / baseline - 1.0 / LINE.unloaded_resistance_ohm
    loaded = 1.0 / (M * 3.0 + N + excess)
    raw = RawSample(resistance_ohm=np.array([baseline, 2e5]))
    snap, _ = proc.process(proc.rested_state(), raw, 0.0, 0.0)
    assert [ChannelStatus(s).label for s in snap.status] == ["no_contact", "no_contact"]
    # the lookup's 0 N end: its last segment (2 N at 1e4, 0.5 N at 1e5) extended to 1e5 * 10^(1/3)
    assert LOOKUP.unloaded_resistance_ohm == pytest.approx(1e5 * 10 ** (1 / 3))
    g_lookup = 1.0 / 1e4 + 1.0 / 2e5 - 1.0 / LOOKUP.unloaded_resistance_ohm
    raw = RawSample(resistance_ohm=np.array([loaded, 1.0 / g_lookup]))
    snap, _ = proc.process(proc.rested_state(), raw, 0.0, 0.0)
    assert snap.force_n[0] == pytest.approx(3.0, rel=1e-9)
    assert snap.force_n[1] == pytest.approx(2.0, rel=1e-9)


def test_adc_channels_with_a_line() -> None:
    dev = make_device([LINE, None], encoding="adc")
    div = Divider()
    r = np.array([_r_line(3.0), SensorModel(PAPER_EFFECTS, [SensorParams()]).resistance(np.array([2.0]))[0]])
    counts = div.counts(div.output_voltage(r))
    proc = DeviceProcessor(dev, "bus", 0.1)
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts), 0.0, 0.0)
    assert [ChannelStatus(s).label for s in snap.status] == ["ok", "ok"]
    np.testing.assert_allclose(snap.force_n, [3.0, 2.0], rtol=0.01)


def test_a_changed_conversion_does_not_carry_creep_state() -> None:
    old = DeviceProcessor(make_device([None, None]), "bus", 0.1)
    new = DeviceProcessor(make_device([LINE, None]), "bus", 0.1)
    assert new.kept_channels(old) == 1


@pytest.mark.parametrize(
    ("build", "key", "allowed"),
    [
        (lambda: line_conversion(0.0, N, 0.05, 10.0), "slope_s_per_n", "(0, inf) S/N"),
        (lambda: line_conversion(-M, N, 0.05, 10.0), "slope_s_per_n", "(0, inf) S/N"),
        (lambda: line_conversion(math.nan, N, 0.05, 10.0), "slope_s_per_n", "finite"),
        (lambda: line_conversion(M, math.inf, 0.05, 10.0), "intercept_s", "finite"),
        (lambda: line_conversion(M, N, 0.0, 10.0), "force_min_n", "(0, inf) N"),
        (lambda: line_conversion(M, N, 5.0, 5.0), "force_max_n", "(force_min_n = 5.0, inf] N"),
        (lambda: line_conversion(M, -2e-5, 0.5, 10.0), "force_min_n", "zero conductance at 1 N"),
        (lambda: lookup_conversion((1e3,), (1.0,)), "resistance_ohm", "at least 2 points"),
        (lambda: lookup_conversion((1e3, 1e4), (1.0, 0.5, 0.2)), "force_n", "one per resistance"),
        (lambda: lookup_conversion((1e3, 1e3), (2.0, 1.0)), "resistance_ohm[1]", "strictly increasing"),
        (lambda: lookup_conversion((1e4, 1e3), (2.0, 1.0)), "resistance_ohm[1]", "strictly increasing"),
        (lambda: lookup_conversion((0.0, 1e3), (2.0, 1.0)), "resistance_ohm[0]", "(0, inf) ohm"),
        (lambda: lookup_conversion((1e3, 1e4), (1.0, 2.0)), "force_n[1]", "non-increasing"),
        (lambda: lookup_conversion((1e3, 1e4), (1.0, 1.0)), "force_n", "force range"),
        (lambda: lookup_conversion((1e3, math.inf), (2.0, 1.0)), "resistance_ohm[1]", "finite"),
        (lambda: lookup_conversion((1e3, 1e4), (2.0, math.nan)), "force_n[1]", "finite"),
    ],
)
def test_conversions_refuse_values_outside_their_ranges(build: object, key: str, allowed: str) -> None:
    with pytest.raises(ConversionError) as info:
        build()  # type: ignore[operator]
    assert info.value.key == key
    assert allowed in str(info.value)


def test_a_channel_refuses_something_that_is_not_a_conversion() -> None:
    with pytest.raises(ConfigError, match="conversion: expected None or a CurveChannel"):
        ChannelConfig(0, "ch00", 0.0, 0.0, True, PAPER_EFFECTS, SensorParams(), None, (M, N))  # type: ignore[arg-type]


def test_a_line_with_a_negative_intercept_reads_no_contact_at_rest() -> None:
    """C = m F + n with n < 0 (the paper's staircase line: n = -1.79e-5 S): with force_min_n
    above -n/m = 1 N, an open sensor and a nearly open one (10 Mohm) read 0 N no contact, and a
    loaded one reads (1/R - n)/m."""
    line = line_conversion(slope_s_per_n=M, intercept_s=-2e-5, force_min_n=1.1, force_max_n=10.0)
    r = np.array([math.inf])
    for resistance, force, code in (
        (math.inf, 0.0, ForceStatus.NO_CONTACT),
        (1e7, 0.0, ForceStatus.NO_CONTACT),
        (1.0 / (M * 3.0 - 2e-5), 3.0, ForceStatus.OK),
    ):
        r[0] = resistance
        f, status = np.zeros(1), np.zeros(1, dtype=np.int8)
        _apply([line], r, f, status)
        assert f[0] == pytest.approx(force) and status[0] == code, resistance
