"""``series_resistance``: a constant resistance in series (leads, traces), in ohm.

It adds ``series_resistance_ohm`` to the sensor and nothing to the slope; the null variant
adds 0 ohm.
"""

from __future__ import annotations

from typing import ClassVar

from ..params import ChannelParams
from .base import SeriesTerm, zeros_like


class SeriesResistance(SeriesTerm):
    effect: ClassVar[str] = "series_resistance"
    description: ClassVar[str] = "a constant resistance in series (leads, traces)"
    parameters: ClassVar[tuple[str, ...]] = ("series_resistance_ohm",)

    def __init__(self, params: ChannelParams) -> None:
        super().__init__(params)
        self.coefficient = params.series_resistance_ohm


class NoSeriesResistance(SeriesTerm):
    """``series_resistance`` switched off: a series term of 0 ohm (a sibling of ``SeriesResistance``)."""

    effect: ClassVar[str] = SeriesResistance.effect
    active: ClassVar[bool] = False
    description: ClassVar[str] = SeriesResistance.description
    parameters: ClassVar[tuple[str, ...]] = SeriesResistance.parameters

    def __init__(self, params: ChannelParams) -> None:
        super().__init__(params)
        self.coefficient = zeros_like(params)
