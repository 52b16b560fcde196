"""Regions of interest per poll: ``array_quantities`` over each region's channels.

A device's ``[[bus.device.roi]]`` (``config.rois.Roi``) names sets of its channels. Each
poll, each region gets the whole array's quantities computed over its enabled channels
alone, by the one function that computes them (``snapshot.array_quantities``): the sum of
the forces in contact (N), the peak (N), the contact area (the cells' areas in contact,
mm^2) and the centre of pressure (mm). A disabled channel is never polled and is in no
region's figures.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from .snapshot import FloatArray, RoiQuantities, StatusArray, array_quantities

__all__ = ["RoiSlots", "roi_quantities", "roi_slots"]


class RoiDescription(Protocol):
    """What a region of interest is made of (``config.rois.Roi`` is one)."""

    @property
    def name(self) -> str: ...
    @property
    def channels(self) -> tuple[int, ...]: ...


@dataclass(frozen=True)
class RoiSlots:
    """A region's name, its enabled channels (device indices) and their positions in a
    snapshot's per-channel arrays."""

    name: str
    channels: tuple[int, ...]
    slots: NDArray[np.intp]


def roi_slots(rois: Sequence[RoiDescription], channel_index: NDArray[np.integer]) -> tuple[RoiSlots, ...]:
    """Where each region's channels sit in arrays of the channels ``channel_index`` (the
    enabled channels' device indices, in array order)."""
    index = np.asarray(channel_index)
    out = []
    for roi in rois:
        slots = np.flatnonzero(np.isin(index, np.asarray(roi.channels, dtype=np.int64)))
        out.append(RoiSlots(roi.name, tuple(int(i) for i in index[slots]), slots.astype(np.intp)))
    return tuple(out)


def roi_quantities(
    rois: Sequence[RoiSlots],
    force_n: FloatArray,
    status: StatusArray,
    x_mm: FloatArray,
    y_mm: FloatArray,
    cell_area_mm2: float | FloatArray,
) -> tuple[RoiQuantities, ...]:
    """Each region's quantities over its channels (``array_quantities`` of their subset;
    ``cell_area_mm2`` one for every cell or one per array entry)."""
    out = []
    for roi in rois:
        k = roi.slots
        area = cell_area_mm2 if isinstance(cell_area_mm2, float | int) else np.asarray(cell_area_mm2)[k]
        q = array_quantities(force_n[k], status[k], x_mm[k], y_mm[k], area)
        peak = 0.0 if q.peak_force_n is None else q.peak_force_n
        out.append(RoiQuantities(roi.name, roi.channels, q.total_force_n, peak, q.contact_area_mm2,
                                 q.center_of_pressure_mm))  # fmt: skip
    return tuple(out)
