"""Live frames over Foxglove's WebSocket protocol (``docs/foxglove.md``): one
``foxglove.Grid`` of forces per region, the layout, and a summary per poll."""

from __future__ import annotations

from .grids import RegionPlace, region_grids, region_places
from .link import FoxgloveLink
from .publisher import FoxglovePublisher, FoxgloveStats

__all__ = [
    "FoxgloveLink",
    "FoxglovePublisher",
    "FoxgloveStats",
    "RegionPlace",
    "region_grids",
    "region_places",
]
