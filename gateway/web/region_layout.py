"""The regions of a device as the page draws them (``layout_json``'s ``regions`` and ``groups``).

A device made of regions (a hand: fingertips, nails, pads, a palm) is drawn region by region,
each in its configured place (mm, x to the right, y downward): the page outlines each
region's box and names it, and sums the forces of each region and of each group (a finger:
its tip, nail and pad) from the frame. ``cells`` lists a region's device channels as drawn,
row by row from the top and left to right, whatever the region's quarter-turn, so that a
program can take a region's force grid as drawn without the turning rules.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

from ..runtime.frame import DECIMALS
from ..runtime.snapshot import finite_or_none


class RegionDescription(Protocol):
    """What the page needs of a configured region (``config.regions.Region`` is one)."""

    @property
    def name(self) -> str: ...
    @property
    def group(self) -> str: ...
    @property
    def first_channel(self) -> int: ...
    @property
    def n_channels(self) -> int: ...
    @property
    def rows(self) -> int: ...
    @property
    def columns(self) -> int: ...
    @property
    def x_mm(self) -> float: ...
    @property
    def y_mm(self) -> float: ...
    @property
    def rotation_deg(self) -> int: ...
    @property
    def drawn_pitch_mm(self) -> tuple[float, float]: ...
    def drawn_box_mm(self) -> tuple[float, float, float, float]: ...
    def position_mm(self, k: int) -> tuple[float, float]: ...


def drawn_cells(region: RegionDescription) -> list[list[int]]:
    """The region's device channels as drawn: rows from the top, each left to right."""
    px, py = region.drawn_pitch_mm
    turned = region.rotation_deg in (90, 270)
    n_rows, n_cols = (region.columns, region.rows) if turned else (region.rows, region.columns)
    out = [[-1] * n_cols for _ in range(n_rows)]
    for k in range(region.n_channels):
        x, y = region.position_mm(k)
        out[round((y - region.y_mm) / py)][round((x - region.x_mm) / px)] = region.first_channel + k
    return out


def _mm(values: Sequence[float]) -> list[float | None]:
    return [finite_or_none(float(v), DECIMALS) for v in values]


def regions_json(regions: Sequence[RegionDescription]) -> list[dict[str, Any]]:
    """Each region: name, group, grid (rows x columns, before turning), drawn place of its
    top-left cell, quarter-turn, drawn pitch and box (left, top, right, bottom; mm), its
    channels (first, count) and its cells as drawn."""
    return [
        {
            "name": r.name,
            "group": r.group,
            "rows": r.rows,
            "columns": r.columns,
            "x_mm": finite_or_none(float(r.x_mm), DECIMALS),
            "y_mm": finite_or_none(float(r.y_mm), DECIMALS),
            "rotation_deg": r.rotation_deg,
            "pitch_mm": _mm(r.drawn_pitch_mm),
            "box_mm": _mm(r.drawn_box_mm()),
            "first_channel": r.first_channel,
            "n_channels": r.n_channels,
            "cells": drawn_cells(r),
        }
        for r in regions
    ]


def groups_json(regions: Sequence[RegionDescription]) -> list[dict[str, Any]]:
    """The groups (a finger, the palm) in the order of their first region, each with its regions."""
    groups: dict[str, list[str]] = {}
    for r in regions:
        groups.setdefault(r.group, []).append(r.name)
    return [{"name": g, "regions": names} for g, names in groups.items()]
