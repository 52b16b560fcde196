"""Limits shared by the configuration's values and its parser: how many channels a device
has, how far from the drawing's origin a channel may sit (mm), how wide a cell may be (mm)."""

from __future__ import annotations

from typing import Final

from ..model.params import Interval

__all__ = [
    "DEFAULT_DEAD_AFTER_S",
    "MAX_CHANNELS",
    "MAX_PITCH_MM",
    "MAX_POSITION_MM",
    "PITCH_MM",
    "POSITION_MM",
]

#: A robot hand carries 1,062 taxels; a device has at most this many channels.
MAX_CHANNELS: Final = 2048
#: Channel positions must lie within this many millimetres of the origin.
MAX_POSITION_MM: Final = 10_000.0
MAX_PITCH_MM: Final = 1_000.0
POSITION_MM: Final = Interval(-MAX_POSITION_MM, MAX_POSITION_MM, low_inclusive=True)
PITCH_MM: Final = Interval(0.0, MAX_PITCH_MM, low_inclusive=False)
#: The default time (s) a taxel frozen while its region moves takes to read dead, for a
#: device made of regions (``runtime.dead_taxels``); other devices track nothing by default.
DEFAULT_DEAD_AFTER_S: Final = 10.0
