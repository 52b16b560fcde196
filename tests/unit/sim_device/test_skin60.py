"""The skin60 device's logic: force tables, dynamic zero, mask, registers and the request log."""

from __future__ import annotations

import io

import numpy as np
import pytest

from sim_device.array import SimArray
from sim_device.scenarios import Scenario
from sim_device.skin60 import (
    HR_AD_MASK,
    HR_DYNAMIC_ZERO,
    HR_OUTPUT_MODE,
    N_POINTS,
    PRODUCT_ID,
    TABLE_COUNTS,
    Skin60Device,
    Skin60Error,
    Skin60Request,
    force_tables,
    skin60_config,
)


def skin(force_n: float = 3.0, seed: int = 1) -> Skin60Device:
    cfg = skin60_config(noise_lsb_rms=0.0, seed=seed)
    scenario = Scenario.constant(force_n, cfg.layout) if force_n else "idle"
    return Skin60Device(SimArray(cfg.with_changes(scenario=scenario)))


def test_tables_rise_from_zero_differ_per_point_and_follow_the_seed() -> None:
    t = force_tables(1)
    assert t.shape == (N_POINTS, 11)
    assert np.all(t[:, 0] == 0.0) and np.all(np.diff(t, axis=1) > 0)
    assert len({round(float(v)) for v in t[:, -1]}) > 50  # every point its own table
    assert np.all(np.abs(t[:, -1] / 20000.0 - 1.0) < 0.075)
    np.testing.assert_array_equal(force_tables(1), t)
    assert not np.array_equal(force_tables(2), t)


def test_force_is_the_piecewise_linear_table() -> None:
    s = skin()
    at_knots = s.force_mn(np.full(N_POINTS, TABLE_COUNTS[5]))
    np.testing.assert_array_equal(at_knots, np.rint(s.tables_mn[:, 5]))
    mid = (TABLE_COUNTS[2] + TABLE_COUNTS[3]) // 2
    frac = (mid - TABLE_COUNTS[2]) / (TABLE_COUNTS[3] - TABLE_COUNTS[2])
    expected = s.tables_mn[:, 2] + frac * (s.tables_mn[:, 3] - s.tables_mn[:, 2])
    np.testing.assert_array_equal(s.force_mn(np.full(N_POINTS, mid)), np.rint(expected))


def test_output_mode_switches_counts_to_mn() -> None:
    s = skin(3.0)
    counts = s.points()
    assert all(300 < c < 4095 for c in counts), counts
    s.write_holding(HR_OUTPUT_MODE, [1])
    force = s.points()
    np.testing.assert_array_equal(force, s.force_mn(np.array(counts)))
    assert all(1000 < f < 20000 for f in force)


def test_dynamic_zero_zeroes_the_loaded_points_and_0_undoes_it() -> None:
    s = skin(3.0)
    before = s.points()
    s.write_holding(HR_DYNAMIC_ZERO, [1])
    assert s.points() == [0] * N_POINTS
    s.write_holding(HR_DYNAMIC_ZERO, [0])
    assert s.points() == before


def test_mask_reads_small_counts_as_zero() -> None:
    s = skin(3.0)
    counts = s.points()
    mask = sorted(counts)[N_POINTS // 2]
    s.write_holding(HR_AD_MASK, [mask])
    masked = s.points()
    assert masked == [c if c >= mask else 0 for c in counts]
    assert 0 in masked and any(masked)


def test_registers_write_only_read_only_and_values() -> None:
    s = skin(0.0)
    assert s.read_registers(3, 0, 3) == [PRODUCT_ID, 60, 0]
    assert s.read_registers(3, 5, 2) == [0, 100]
    for address, count in ((3, 1), (4, 1), (2, 2), (0, 7), (7, 1)):
        with pytest.raises(Skin60Error) as info:
            s.read_registers(3, address, count)
        assert info.value.code == 2
    with pytest.raises(Skin60Error) as info:
        s.write_holding(0, [1])
    assert info.value.code == 2
    for address, value in ((HR_OUTPUT_MODE, 2), (HR_AD_MASK, 4096), (HR_DYNAMIC_ZERO, 5)):
        with pytest.raises(Skin60Error) as info:
            s.write_holding(address, [value])
        assert info.value.code == 3
    with pytest.raises(Skin60Error):
        s.write_holding(HR_OUTPUT_MODE, [1, 0, 0, 0, 0])  # register 6 is read-only: nothing applied
    assert s.output_mode == 0
    s.write_holding(4, [1])
    assert s.auto_zero_at_power_on == 1


def test_auto_zero_at_power_on() -> None:
    s = skin(3.0)
    s.power_on()
    assert any(s.points())
    s.write_holding(4, [1])
    s.power_on()
    assert s.points() == [0] * N_POINTS


def test_points_range() -> None:
    s = skin(3.0)
    assert s.read_points(58, 2) == s.points()[58:]
    assert s.read_registers(4, 0, 60) == s.points()
    for start, count in ((0, 0), (0, 61), (59, 2), (60, 1)):
        with pytest.raises(Skin60Error) as info:
            s.read_points(start, count)
        assert info.value.code == 2


def test_request_log_file() -> None:
    out = io.StringIO()
    cfg = skin60_config(noise_lsb_rms=0.0)
    s = Skin60Device(SimArray(cfg), out)
    s.log(Skin60Request(6, 2, 1, (1,)))
    s.log(Skin60Request(0x42, 0, 60))
    assert s.requests[0].is_write and not s.requests[1].is_write
    assert out.getvalue() == "1\t0x06\t2\t1\t1\n1\t0x42\t0\t60\t\n"


def test_needs_a_skin_array() -> None:
    with pytest.raises(ValueError, match="60-channel, 12-bit"):
        Skin60Device(SimArray())
