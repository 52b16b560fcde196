"""Devices made of regions: ``[[bus.device.region]]`` and the ``Region`` value.

A region is one named sub-grid of a device (a fingertip, a nail, a palm): ``rows`` x
``columns`` taxels whose values lie at consecutive value slots from ``address``, stored in
the region's ``order`` from its ``origin`` corner (as a ``GridLayout``), ``pitch_x_mm`` /
``pitch_y_mm`` apart. A device's channels are its regions' taxels, in region order; channel
``k`` of region ``tip`` at grid cell (row r, column c) is called ``tip-r<r>c<c>``.

Drawing. A region is placed on a drawing of the device (x to the right, y downward, mm):
it is turned by ``rotation_deg`` (0, 90, 180 or 270) clockwise as drawn, then shifted so
that the cell drawn top-left sits at (``x_mm``, ``y_mm``); a channel's position is its
cell's centre. Turned 90 degrees, a cell (u, v) = (column x pitch_x, row x pitch_y) is
drawn at (x_mm + (rows - 1) pitch_y - v, y_mm + u). Regions may not be drawn over each
other (their cells' rectangles may touch, not overlap): the page and the Foxglove layout
draw each region in its place. A region given no place is drawn below the ones before it,
one pitch apart.

Addresses. ``address_unit`` (``"register"``, the default, or ``"byte"``) says how the
device's region addresses and its ``value_stride`` are counted: a byte address is register
byte / 2 (an odd one is refused). ``value_stride`` is the distance from one value to the
next (default: one value's width, one 16-bit register for uint16): a device that keeps each
16-bit value in the first register of two is ``value_stride = 2`` in registers, or 4 in
bytes. Regions may not share registers.

A device without regions has ``DeviceConfig.regions == ()``: its channels are the grid of
its ``layout``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..modbus.register_map import FRAME_TYPE_WIDTHS, MAX_ADDRESS, MAX_VALUE_STRIDE, FrameBlock
from .layout import LAYOUT_ORDERS, LAYOUT_ORIGINS, GridLayout
from .limits import MAX_CHANNELS, PITCH_MM, POSITION_MM
from .tables import REQUIRED, Context, Table

__all__ = [
    "ADDRESS_UNITS",
    "REGION_KEYS",
    "ROTATIONS_DEG",
    "Region",
    "RegionSet",
    "parse_regions",
]

ROTATIONS_DEG: Final = (0, 90, 180, 270)
ADDRESS_UNITS: Final = ("register", "byte")
REGION_KEYS: Final = (
    "name",
    "group",
    "address",
    "rows",
    "columns",
    "count",
    "order",
    "origin",
    "pitch_mm",
    "pitch_x_mm",
    "pitch_y_mm",
    "x_mm",
    "y_mm",
    "rotation_deg",
)
#: The most rows or columns of one region (a region is at most MAX_CHANNELS taxels anyway).
MAX_REGION_SIDE: Final = MAX_CHANNELS
_DEFAULT_PITCH_MM: Final = 2.5
_EPS_MM: Final = 1e-9


@dataclass(frozen=True)
class Region:
    """One named sub-grid of a device (module docstring). ``first_channel`` is the device
    channel of the region's first value, ``address`` the register address of that value,
    ``x_mm``/``y_mm`` where the cell drawn top-left sits, ``group`` what it sums with
    (``index`` for ``index-tip`` and ``index-pad``; by default its own name)."""

    name: str
    group: str
    first_channel: int
    n_channels: int
    rows: int
    columns: int
    pitch_x_mm: float
    pitch_y_mm: float
    x_mm: float
    y_mm: float
    rotation_deg: int
    address: int
    order: str = "row-major"
    origin: str = "top-left"

    def __post_init__(self) -> None:
        where = f"region {self.name!r}"
        for key in ("rows", "columns"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_REGION_SIDE:
                raise ConfigError(f"{where}: {key}: {value!r} is out of range; allowed: 1..{MAX_REGION_SIDE}")
        if self.n_channels != self.rows * self.columns:
            raise ConfigError(
                f"{where}: n_channels: {self.n_channels!r} does not match rows x columns = "
                f"{self.rows * self.columns}"
            )
        if self.rotation_deg not in ROTATIONS_DEG:
            raise ConfigError(
                f"{where}: rotation_deg: {self.rotation_deg!r} is not allowed; allowed: 0, 90, 180, 270"
            )
        if not 0 <= self.first_channel <= MAX_CHANNELS - self.n_channels:
            raise ConfigError(
                f"{where}: first_channel: {self.first_channel!r} is out of range; "
                f"allowed: 0..{MAX_CHANNELS - self.n_channels}"
            )
        if not 0 <= self.address <= MAX_ADDRESS:
            raise ConfigError(
                f"{where}: address: {self.address!r} is out of range; allowed: 0..{MAX_ADDRESS}"
            )
        for key in ("x_mm", "y_mm"):
            if not POSITION_MM.contains(float(getattr(self, key))):
                raise ConfigError(
                    f"{where}: {key}: {getattr(self, key)!r} is out of range; "
                    f"allowed: {POSITION_MM.describe()} mm"
                )
        self.layout  # noqa: B018 -- GridLayout checks the pitch, order and origin

    @property
    def layout(self) -> GridLayout:
        """The region's own grid: which (row, column) each of its values is, before turning."""
        return GridLayout(
            self.n_channels, self.columns, self.pitch_x_mm, self.pitch_y_mm, self.origin, self.order
        )

    @property
    def channel_slice(self) -> slice:
        """The region's channels among the device's."""
        return slice(self.first_channel, self.first_channel + self.n_channels)

    def cell(self, k: int) -> tuple[int, int]:
        """The grid (row, column) of the region's ``k``-th value, before turning."""
        return self.layout.cell(k)

    def channel_name(self, k: int) -> str:
        row, col = self.cell(k)
        return f"{self.name}-r{row}c{col}"

    @property
    def drawn_size_mm(self) -> tuple[float, float]:
        """Width and height (mm) of the region as drawn, from cell centre to cell centre."""
        width = (self.columns - 1) * self.pitch_x_mm
        height = (self.rows - 1) * self.pitch_y_mm
        return (height, width) if self.rotation_deg in (90, 270) else (width, height)

    @property
    def drawn_pitch_mm(self) -> tuple[float, float]:
        """The pitch along the drawing's x and y (a quarter turn swaps them)."""
        if self.rotation_deg in (90, 270):
            return self.pitch_y_mm, self.pitch_x_mm
        return self.pitch_x_mm, self.pitch_y_mm

    def drawn_box_mm(self) -> tuple[float, float, float, float]:
        """(left, top, right, bottom) of the region's cells as drawn, each cell one pitch wide."""
        width, height = self.drawn_size_mm
        px, py = self.drawn_pitch_mm
        return (
            self.x_mm - px / 2,
            self.y_mm - py / 2,
            self.x_mm + width + px / 2,
            self.y_mm + height + py / 2,
        )

    def position_mm(self, k: int) -> tuple[float, float]:
        """Where the region's ``k``-th value is drawn (mm; module docstring)."""
        row, col = self.cell(k)
        u, v = col * self.pitch_x_mm, row * self.pitch_y_mm
        w = (self.columns - 1) * self.pitch_x_mm
        h = (self.rows - 1) * self.pitch_y_mm
        if self.rotation_deg == 0:
            dx, dy = u, v
        elif self.rotation_deg == 90:
            dx, dy = h - v, u
        elif self.rotation_deg == 180:
            dx, dy = w - u, h - v
        else:
            dx, dy = v, w - u
        return float(self.x_mm + dx), float(self.y_mm + dy)

    def grid_indices(self) -> NDArray[np.intp]:
        """A rows x columns array of the device channel drawn at each cell of the region's own
        grid (before turning): ``force[region.grid_indices()]`` is the region's force grid."""
        out = np.empty((self.rows, self.columns), dtype=np.intp)
        for k in range(self.n_channels):
            row, col = self.cell(k)
            out[row, col] = self.first_channel + k
        return out

    def describe(self) -> str:
        turned = f", turned {self.rotation_deg} deg" if self.rotation_deg else ""
        return (
            f"{self.name} ({self.group}): {self.rows} x {self.columns} at register {self.address}, "
            f"channels {self.first_channel}..{self.first_channel + self.n_channels - 1}, "
            f"drawn at ({self.x_mm:g}, {self.y_mm:g}) mm{turned}"
        )


@dataclass(frozen=True)
class RegionSet:
    """The regions of a device with what the frame needs: their blocks and the stride."""

    regions: tuple[Region, ...]
    value_stride: int  # registers from one value to the next

    @property
    def n_channels(self) -> int:
        return sum(r.n_channels for r in self.regions)

    def blocks(self) -> tuple[FrameBlock, ...]:
        return tuple(FrameBlock(r.address, r.n_channels) for r in self.regions)


def _in_registers(table: Table, key: str, value: int, unit: str, what: str) -> int:
    if unit == "byte":
        if value % 2:
            raise table.error(
                key,
                f"{value} is an odd byte address{what}; a 16-bit register starts at an even byte "
                "(register = byte address / 2)",
            )
        return value // 2
    return value


def parse_regions(ctx: Context, device: Table, value_type: str) -> RegionSet | None:
    """``[[bus.device.region]]`` of the device table ``device`` with its ``address_unit`` and
    ``value_stride``, for values of ``value_type``; None when the device has no regions."""
    items = device.tables("region", "[[bus.device.region]]")
    if not items:
        for key in ("address_unit", "value_stride"):
            if device.has(key):
                raise device.error(
                    key, "applies to the addresses of [[bus.device.region]]; the device has none"
                )
        return None
    for key in ("columns", "pitch_mm", "layout"):
        if device.has(key):
            raise device.error(
                key, "the regions say where each channel sits; give rows, columns and pitch_mm per region"
            )
    unit = device.choice("address_unit", "register", ADDRESS_UNITS)
    width = FRAME_TYPE_WIDTHS[value_type]
    per_register = 2 if unit == "byte" else 1
    stride_raw = device.integer(
        "value_stride", width * per_register, 1, MAX_VALUE_STRIDE * per_register, f" {unit}s per value"
    )
    if unit == "byte" and stride_raw % 2:
        raise device.error(
            "value_stride", f"{stride_raw} bytes is not a whole number of registers; allowed: an even number"
        )
    stride = stride_raw // per_register
    if stride < width:
        raise device.error(
            "value_stride",
            f"{stride} registers is shorter than one {value_type} value ({width} registers); "
            f"allowed: {width}..{MAX_VALUE_STRIDE}",
        )
    _check_total(ctx, device, items)
    regions: list[Region] = []
    first = 0
    names: dict[str, str] = {}
    for rpath, item in items:
        table = Table(ctx, item, rpath, REGION_KEYS)
        name = table.name("name")
        if name in names:
            raise table.error(
                "name", f"duplicate region name {name!r} (also {names[name]}); names are unique"
            )
        names[name] = table.at("name")
        rows = table.integer("rows", REQUIRED, 1, MAX_REGION_SIDE)
        columns = table.integer("columns", REQUIRED, 1, MAX_REGION_SIDE)
        count = table.integer("count", rows * columns, 1, MAX_CHANNELS)
        if count != rows * columns:
            raise table.error(
                "count",
                f"{count} taxels, but rows x columns = {rows} x {columns} = {rows * columns}; "
                "a region is a whole grid",
            )
        span_values = (count - 1) * stride + width
        high = (MAX_ADDRESS + 1 - span_values) * per_register
        raw_address = table.integer("address", REQUIRED, 0, high, f" {unit}s (a region of {count} values)")
        address = _in_registers(table, "address", raw_address, unit, "")
        if table.has("pitch_mm") and (table.has("pitch_x_mm") or table.has("pitch_y_mm")):
            raise table.error("pitch_mm", "give pitch_mm, or pitch_x_mm and pitch_y_mm, not both")
        pitch = table.number("pitch_mm", _DEFAULT_PITCH_MM, PITCH_MM, " mm")
        pitch_x = table.number("pitch_x_mm", pitch, PITCH_MM, " mm")
        pitch_y = table.number("pitch_y_mm", pitch, PITCH_MM, " mm")
        rotation = table.integer("rotation_deg", 0, 0, 270)
        if rotation not in ROTATIONS_DEG:
            raise table.error("rotation_deg", f"{rotation} is not allowed; allowed: 0, 90, 180, 270")
        placed = table.has("x_mm") or table.has("y_mm")
        below = 0.0
        if regions and not placed:
            last = max(regions, key=lambda r: r.drawn_box_mm()[3])
            drawn_py = pitch_x if rotation in (90, 270) else pitch_y
            below = last.drawn_box_mm()[3] + max(last.drawn_pitch_mm[1], drawn_py) + drawn_py / 2
        try:
            region = Region(
                name=name,
                group=table.name("group") if table.has("group") else name,
                first_channel=first,
                n_channels=count,
                rows=rows,
                columns=columns,
                pitch_x_mm=pitch_x,
                pitch_y_mm=pitch_y,
                x_mm=table.number("x_mm", 0.0, POSITION_MM, " mm"),
                y_mm=table.number("y_mm", below, POSITION_MM, " mm"),
                rotation_deg=rotation,
                address=address,
                order=table.choice("order", "row-major", LAYOUT_ORDERS),
                origin=table.choice("origin", "top-left", LAYOUT_ORIGINS),
            )
        except ConfigError as exc:
            raise ctx.error(rpath, str(exc)) from None
        _check_registers(table, region, regions, stride, width)
        _check_drawing(ctx, rpath, region, regions)
        regions.append(region)
        first += count
    return RegionSet(tuple(regions), stride)


def _check_total(ctx: Context, device: Table, items: list[tuple[str, dict[str, object]]]) -> None:
    """All the regions' taxels fit one device (before any region is built on its own)."""
    total = 0
    for rpath, item in items:
        table = Table(ctx, item, rpath, REGION_KEYS)
        total += table.integer("rows", REQUIRED, 1, MAX_REGION_SIDE) * table.integer(
            "columns", REQUIRED, 1, MAX_REGION_SIDE
        )
    if total > MAX_CHANNELS:
        raise device.error(
            "region", f"{total} channels in all; allowed: 1..{MAX_CHANNELS} channels per device"
        )


def _register_span(region: Region, stride: int, width: int) -> tuple[int, int]:
    return region.address, region.address + (region.n_channels - 1) * stride + width - 1


def _check_registers(table: Table, region: Region, before: list[Region], stride: int, width: int) -> None:
    lo, hi = _register_span(region, stride, width)
    for other in before:
        olo, ohi = _register_span(other, stride, width)
        if lo <= ohi and olo <= hi:
            raise table.error(
                "address",
                f"region {region.name!r} (registers {lo}..{hi}) overlaps region {other.name!r} "
                f"(registers {olo}..{ohi}); regions must not share registers",
            )


def _check_drawing(ctx: Context, path: str, region: Region, before: list[Region]) -> None:
    left, top, right, bottom = region.drawn_box_mm()
    for other in before:
        oleft, otop, oright, obottom = other.drawn_box_mm()
        if (
            left < oright - _EPS_MM
            and oleft < right - _EPS_MM
            and top < obottom - _EPS_MM
            and otop < bottom - _EPS_MM
        ):
            raise ctx.error(
                path,
                f"region {region.name!r} (cells over x {left:g}..{right:g}, y {top:g}..{bottom:g} mm) is "
                f"drawn over region {other.name!r} (x {oleft:g}..{oright:g}, y {otop:g}..{obottom:g} mm); "
                "give x_mm, y_mm so that regions do not overlap on the drawing (touching is fine)",
            )


def region_channel_names(regions: tuple[Region, ...]) -> list[str]:
    return [r.channel_name(k) for r in regions for k in range(r.n_channels)]


def region_positions_mm(regions: tuple[Region, ...]) -> list[tuple[float, float]]:
    return [r.position_mm(k) for r in regions for k in range(r.n_channels)]


def device_pitch_mm(regions: tuple[Region, ...]) -> tuple[float, float]:
    """The first region's pitch: the cell the device's layout (and its contact area) uses."""
    return regions[0].pitch_x_mm, regions[0].pitch_y_mm
