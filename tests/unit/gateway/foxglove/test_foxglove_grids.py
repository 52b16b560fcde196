"""Each region's forces as a 2-D grid (hand-built expected grids) and its place on the
drawing (the cell centres of a posed grid are the drawn positions of ``config.regions``)."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_helpers import HEAD, PAD_N, TIP_N, hand_config, hand_snapshot

from gateway.config import parse_config
from gateway.foxglove.grids import region_grids, region_places


def test_each_region_is_its_grid_of_forces() -> None:
    device = hand_config().buses[0].devices[0]
    grids = region_grids(hand_snapshot(), device)
    assert [(name, rows, cols) for name, rows, cols, _ in grids] == [("tip", 2, 3), ("pad", 3, 2)]
    assert grids[0][3].dtype == np.float32 and grids[0][3].flags.c_contiguous
    np.testing.assert_array_equal(grids[0][3], np.array(TIP_N, dtype=np.float32))
    np.testing.assert_array_equal(grids[1][3], np.array(PAD_N, dtype=np.float32))


def test_a_cell_without_a_force_is_nan() -> None:
    device = hand_config().buses[0].devices[0]
    # channel 4 (tip row 1, col 1) not in the snapshot; channel 6 (pad row 2, col 0) stale
    grids = region_grids(hand_snapshot(missing=(4,), stale=(6,)), device)
    tip = np.array(TIP_N, dtype=np.float32)
    tip[1, 1] = np.nan
    pad = np.array(PAD_N, dtype=np.float32)
    pad[2, 0] = np.nan
    np.testing.assert_array_equal(grids[0][3], tip)
    np.testing.assert_array_equal(grids[1][3], pad)


def test_a_device_without_regions_is_one_region_named_after_it() -> None:
    text = """
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = 502

[[bus.device]]
name = "pad4"
device_id = 1
channels = 4
columns = 2
pitch_mm = 2.5
layout = { origin = "top-right" }

[bus.device.registers]
adc_address = 0

[bus.device.front_end]
kind = "high_side"
supply_v = 5.0
reference_ohm = 10000.0
adc_bits = 16
"""
    device = parse_config(text).buses[0].devices[0]
    snap = hand_snapshot(n=4)
    [(name, rows, cols, grid)] = region_grids(snap, device)
    assert (name, rows, cols) == ("pad4", 2, 2)
    # index 0 at the top-right, row-major: [[1, 0], [3, 2]]
    np.testing.assert_array_equal(grid, np.array([[1.5, 0.5], [3.5, 2.5]], dtype=np.float32))
    [place] = region_places(device)
    assert (place.corner_x_mm, place.corner_y_mm) == (-1.25, -1.25)


@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
def test_the_posed_grid_puts_each_cell_where_the_page_draws_its_taxel(rotation: int) -> None:
    device = parse_config(HEAD.replace("rotation_deg = 90", f"rotation_deg = {rotation}")).buses[0].devices[0]
    for region, place in zip(device.regions, region_places(device), strict=True):
        assert place.rotation_deg == rotation or region.name == "tip"
        for row in range(region.rows):
            for col in range(region.columns):
                k = int(region.grid_indices()[row, col])
                ch = device.channels[k]
                assert place.cell_centre_mm(row, col) == pytest.approx((ch.x_mm, ch.y_mm), abs=1e-9)
