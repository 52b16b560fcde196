"""Regions of interest against a real gateway polling the simulated array over loopback
Modbus TCP (issue 35 item 3): each region's sum, peak and contact area in the frame JSON equal
the sum, the largest value and the count times the cell area over its cells in that frame;
the regions are in the metrics, in base units."""

from __future__ import annotations

import math
from typing import Any

import aiohttp
import pytest
from prometheus_client.parser import text_string_to_metric_families
from web_fixtures import PITCH_MM, gateway_with_page, until_async

from gateway.config.rois import Roi

CELL_MM2 = PITCH_MM * PITCH_MM
# a 4 x 4 array: channel k at column k % 4, row k // 4
LEFT = Roi("left", (0, 1, 4, 5, 8, 9, 12, 13))
RIGHT = Roi("right", (2, 3, 6, 7, 10, 11, 14, 15))
ALL = Roi("all", tuple(range(16)))
IN_CONTACT_STATUSES = {0, 2, 7}  # ok, saturated, extrapolated (ChannelStatus)


def by_hand(
    frame: dict[str, Any], channels: list[int]
) -> tuple[float, float, float, tuple[float, float] | None]:
    """Sum, peak, area and centre of pressure over ``channels`` of the frame, computed here."""
    touching = [
        (frame["force_n"][k], (k % 4) * PITCH_MM, (k // 4) * PITCH_MM)
        for k in channels
        if frame["force_n"][k] is not None
        and frame["force_n"][k] > 0
        and frame["status"][k] in IN_CONTACT_STATUSES
    ]
    total = math.fsum(f for f, _, _ in touching)
    if not touching:
        return 0.0, 0.0, 0.0, None
    cop = (math.fsum(f * x for f, x, _ in touching) / total, math.fsum(f * y for f, _, y in touching) / total)
    return total, max(f for f, _, _ in touching), len(touching) * CELL_MM2, cop


async def test_a_regions_figures_are_those_of_its_cells_in_the_frame() -> None:
    async with (
        gateway_with_page(rois=(LEFT, RIGHT, ALL)) as gw,
        aiohttp.ClientSession(gw.server.base_url) as http,
    ):
        frames: list[dict[str, Any]] = []

        async def pressed_on_both_sides() -> bool:
            async with http.get("/api/devices/arr/frame") as resp:
                if resp.status != 200:
                    return False
                frame = await resp.json()
            frames.append(frame)
            return all(r["area_mm2"] > 0 for r in frame["rois"])

        await until_async(pressed_on_both_sides, 30, "a frame with contact in both halves")
        frame = frames[-1]
        assert [r["name"] for r in frame["rois"]] == ["left", "right", "all"]
        for roi in frame["rois"]:
            total, peak, area, cop = by_hand(frame, roi["channels"])
            assert roi["force_n"] == pytest.approx(total, abs=1e-5)
            assert roi["peak_n"] == pytest.approx(peak, abs=1e-6)
            assert roi["area_mm2"] == pytest.approx(area)
            assert cop is not None
            assert (roi["cop_x_mm"], roi["cop_y_mm"]) == pytest.approx(cop, abs=1e-5)
        left, right, whole = frame["rois"]
        assert left["channels"] == list(LEFT.channels)
        assert left["force_n"] + right["force_n"] == pytest.approx(frame["total_force_n"], abs=1e-5)
        assert whole["force_n"] == pytest.approx(frame["total_force_n"], abs=1e-6)
        assert whole["area_mm2"] == pytest.approx(frame["contact_area_mm2"])
        assert whole["peak_n"] == pytest.approx(frame["peak_force_n"], abs=1e-6)
        assert [whole["cop_x_mm"], whole["cop_y_mm"]] == pytest.approx(frame["cop_mm"], abs=1e-6)

        async with http.get("/metrics") as resp:
            families = {f.name: f for f in text_string_to_metric_families(await resp.text())}
        forces = {s.labels["roi"]: s.value for s in families["tactile_roi_force_newtons"].samples}
        assert set(forces) == {"left", "right", "all"}
        areas = families["tactile_roi_contact_area_square_metres"].samples
        # every area is a whole number of cells (6.25e-6 m^2 each), at most the 16 of the array
        for s in areas:
            cells = s.value / (CELL_MM2 * 1e-6)
            assert cells == pytest.approx(round(cells), abs=1e-6) and 0 <= round(cells) <= 16
        assert "tactile_roi_peak_force_newtons" in families
        assert "tactile_roi_center_of_pressure_metres" in families
