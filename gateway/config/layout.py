"""Where each channel of a grid array sits: ``GridLayout``.

Coordinates are in millimetres as the array is drawn: x to the right, y downward, the
top-left cell at (0, 0). A device stores its channels in some order; the layout says which:
``order`` is ``row-major`` (index 0, 1, 2, ... along a row) or ``column-major`` (down a
column), and ``origin`` is the drawn corner where index 0 sits (``top-left``,
``top-right``, ``bottom-left``, ``bottom-right``). A device that stores its rows bottom-up
is ``origin = "bottom-left"``; a mirrored one ``top-right``. Cells are ``pitch_x_mm`` apart
along x and ``pitch_y_mm`` along y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from ..errors import ConfigError

__all__ = ["LAYOUT_ORDERS", "LAYOUT_ORIGINS", "GridLayout"]

LAYOUT_ORIGINS: Final = ("top-left", "top-right", "bottom-left", "bottom-right")
LAYOUT_ORDERS: Final = ("row-major", "column-major")
MAX_PITCH_MM: Final = 1_000.0


@dataclass(frozen=True)
class GridLayout:
    """A grid of ``n_channels`` cells, ``columns`` wide (see the module docstring)."""

    n_channels: int
    columns: int
    pitch_x_mm: float
    pitch_y_mm: float
    origin: str = "top-left"
    order: str = "row-major"

    def __post_init__(self) -> None:
        where = "layout"
        n = self.n_channels
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ConfigError(f"{where}: channels: {n!r} is out of range; allowed: 1 or more")
        if isinstance(self.columns, bool) or not isinstance(self.columns, int) or not 1 <= self.columns <= n:
            raise ConfigError(
                f"{where}: columns: {self.columns!r} is out of range; "
                f"allowed: 1..{n} (at most channels = {n})"
            )
        for name in ("pitch_x_mm", "pitch_y_mm"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not 0.0 < value <= MAX_PITCH_MM
            ):
                raise ConfigError(
                    f"{where}: {name}: {value!r} is out of range; allowed: (0, {MAX_PITCH_MM:g}] mm"
                )
        if self.origin not in LAYOUT_ORIGINS:
            raise ConfigError(
                f"{where}: origin: {self.origin!r} is not allowed; allowed: {', '.join(LAYOUT_ORIGINS)}"
            )
        if self.order not in LAYOUT_ORDERS:
            raise ConfigError(
                f"{where}: order: {self.order!r} is not allowed; allowed: {', '.join(LAYOUT_ORDERS)}"
            )

    @property
    def rows(self) -> int:
        return math.ceil(self.n_channels / self.columns)

    @property
    def cell_area_mm2(self) -> float:
        return float(self.pitch_x_mm * self.pitch_y_mm)

    def cell(self, index: int) -> tuple[int, int]:
        """The drawn (row, column) of channel ``index``; row 0 is the top row."""
        if not 0 <= index < self.n_channels:
            raise IndexError(f"channel index {index} is outside 0..{self.n_channels - 1}")
        if self.order == "row-major":
            row, col = divmod(index, self.columns)
        else:
            col, row = divmod(index, self.rows)
        if self.origin.startswith("bottom"):
            row = self.rows - 1 - row
        if self.origin.endswith("right"):
            col = self.columns - 1 - col
        return row, col

    def position_mm(self, index: int) -> tuple[float, float]:
        """(x, y) of channel ``index`` in mm: x to the right, y downward from the top-left cell."""
        row, col = self.cell(index)
        return float(col * self.pitch_x_mm), float(row * self.pitch_y_mm)

    def describe(self) -> str:
        """One line: the grid, the pitch and where index 0 is."""
        pitch = (
            f"{self.pitch_x_mm:g} mm"
            if self.pitch_x_mm == self.pitch_y_mm
            else f"{self.pitch_x_mm:g} x {self.pitch_y_mm:g} mm"
        )
        return f"{self.rows} x {self.columns} grid, pitch {pitch}, {self.order}, index 0 at the {self.origin}"
