"""A device's forces as one 2-D grid per region, and where each grid is drawn.

A device made of regions (``DeviceConfig.regions``) gives one grid per region: ``rows`` x
``columns`` forces (N, float32) in the region's own grid (row 0 on top, before its drawn
quarter-turn), cell (r, c) holding the force of the channel the region stores there. A
device without regions is one region named after the device: the grid of its ``layout``.
A cell whose channel is disabled, or carries no force in this poll (stale, open, short,
error, uncalibrated: ``DeviceSnapshot.force_n`` is NaN there), is NaN.

Placement. Foxglove draws a ``foxglove.Grid`` from its pose: cell (r, c) covers
[c px, (c+1) px] x [r py, (r+1) py] in the grid's own x-y plane, turned by the pose's
orientation and shifted by its position. In the device's frame (x to the right, y down the
drawing, z into it, mm as on the page; ``config.regions``) a region turned ``rotation_deg``
clockwise as drawn is a turn of +rotation_deg about z; the pose's position is where the
corner of cell (0, 0) lands, so that each cell's centre is the drawn position of its channel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..config.schema import DeviceConfig
from ..runtime.snapshot import DeviceSnapshot

__all__ = ["RegionPlace", "region_grids", "region_places"]

Float32Array = NDArray[np.float32]


@dataclass(frozen=True)
class RegionPlace:
    """One region of a device as Foxglove draws it: its grid shape, pitch (mm), the corner of
    its cell (0, 0) in the device's drawing (mm) and its turn about z (degrees, clockwise as
    drawn); ``indices`` is the device channel at each cell (rows x columns)."""

    name: str
    group: str
    rows: int
    columns: int
    pitch_x_mm: float
    pitch_y_mm: float
    corner_x_mm: float
    corner_y_mm: float
    rotation_deg: int
    indices: NDArray[np.intp]

    def cell_centre_mm(self, row: int, col: int) -> tuple[float, float]:
        """Where the centre of cell (row, col) is drawn (mm)."""
        theta = math.radians(self.rotation_deg)
        u, v = (col + 0.5) * self.pitch_x_mm, (row + 0.5) * self.pitch_y_mm
        c, s = round(math.cos(theta)), round(math.sin(theta))
        return self.corner_x_mm + c * u - s * v, self.corner_y_mm + s * u + c * v


def region_places(device: DeviceConfig) -> list[RegionPlace]:
    """The regions of ``device`` (or the device as one region) in channel order."""
    if not device.regions:
        layout = device.layout
        indices = np.full((layout.rows, layout.columns), -1, dtype=np.intp)
        for k in range(layout.n_channels):
            indices[layout.cell(k)] = k
        return [
            RegionPlace(
                device.name,
                device.name,
                layout.rows,
                layout.columns,
                layout.pitch_x_mm,
                layout.pitch_y_mm,
                -layout.pitch_x_mm / 2,
                -layout.pitch_y_mm / 2,
                0,
                indices,
            )
        ]
    places = []
    for region in device.regions:
        theta = math.radians(region.rotation_deg)
        c, s = round(math.cos(theta)), round(math.sin(theta))
        indices = region.grid_indices()
        k0 = int(indices[0, 0]) - region.first_channel
        x0, y0 = region.position_mm(k0)  # drawn centre of cell (0, 0)
        hx, hy = region.pitch_x_mm / 2, region.pitch_y_mm / 2
        places.append(
            RegionPlace(
                region.name,
                region.group,
                region.rows,
                region.columns,
                region.pitch_x_mm,
                region.pitch_y_mm,
                x0 - (c * hx - s * hy),
                y0 - (s * hx + c * hy),
                region.rotation_deg,
                indices,
            )
        )
    return places


def snapshot_positions(snapshot: DeviceSnapshot, n_device_channels: int) -> NDArray[np.intp]:
    """For each device channel, its position in the snapshot's arrays (-1: not in it)."""
    where = np.full(n_device_channels + 1, -1, dtype=np.intp)
    where[np.asarray(snapshot.channel_index, dtype=np.intp)] = np.arange(snapshot.n_channels)
    return where


def region_grids(
    snapshot: DeviceSnapshot, device: DeviceConfig, places: list[RegionPlace] | None = None
) -> list[tuple[str, int, int, Float32Array]]:
    """``(region name, rows, columns, forces)`` per region: ``forces`` a C-ordered float32
    rows x columns array in N, NaN where a cell has no force (module docstring)."""
    places = region_places(device) if places is None else places
    where = snapshot_positions(snapshot, device.n_channels)
    force = np.append(np.asarray(snapshot.force_n, dtype=np.float32), np.float32(np.nan))
    out = []
    for place in places:
        # -1 (a cell no channel fills, or a channel not in the snapshot) picks the NaN at the end
        grid = force[where[place.indices]]
        out.append((place.name, place.rows, place.columns, np.ascontiguousarray(grid, dtype=np.float32)))
    return out
