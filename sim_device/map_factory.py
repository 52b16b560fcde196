"""The register map an array serves, by name (``ArrayConfig.register_map``; see ``maps``).

The factory sits above the maps it picks from (``maps.TactileSimMap``, and
``rawgrid.RawgridMap`` which builds on ``maps``), so that neither map module needs the other's.
"""

from __future__ import annotations

from .config import ArrayConfig
from .maps import DeviceMap, TactileSimMap
from .rawgrid import RawgridMap


def make_map(config: ArrayConfig) -> DeviceMap:
    """The map ``config.register_map`` names, for that array."""
    pitch_um = round(config.pitch_mm * 1000.0)
    if config.register_map == RawgridMap.name:
        return RawgridMap(config.channels, config.columns, pitch_um, config.board_leakage_ohm)
    return TactileSimMap(config.channels, config.columns, pitch_um)
