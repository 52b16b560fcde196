"""What a device table says about its read-out: the front end (ADC counts to ohm), the
layout of its channels and their unloaded baselines (``device.parse_device`` uses it)."""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np

from ..model import (
    FRONT_END_KINDS,
    Divider,
    DividerStatus,
    FrontEnd,
    LowSideDivider,
    RatioFrontEnd,
    Transimpedance,
)
from ..model.params import Interval
from .layout import LAYOUT_ORDERS, LAYOUT_ORIGINS, GridLayout
from .schema import PITCH_MM
from .tables import REQUIRED, Context, Table, show_value, type_name

__all__ = [
    "DIVIDER_KEYS",
    "LAYOUT_KEYS",
    "parse_baselines",
    "parse_divider",
    "parse_front_end",
    "parse_layout",
]

LAYOUT_KEYS: Final = ("columns", "pitch_mm", "pitch_x_mm", "pitch_y_mm", "origin", "order")
DIVIDER_KEYS: Final = ("supply_v", "reference_ohm", "adc_bits")
_ADC_KEYS: Final = ("adc_bits", "adc_reference_v", "adc_offset_counts")
_FRONT_END_KEYS: Final = {
    "high_side": ("kind", "supply_v", "reference_ohm", *_ADC_KEYS),
    "low_side": ("kind", "supply_v", "reference_ohm", *_ADC_KEYS),
    "transimpedance": ("kind", "bias_v", "feedback_ohm", "output_offset_v", *_ADC_KEYS),
    "ratio": ("kind", "adc_bits", "rises_with_load", "adc_offset_counts"),
}
_POSITIVE: Final = Interval(0.0, math.inf, low_inclusive=False, high_inclusive=False)
_POSITIVE_OR_UNSET: Final = Interval(0.0, math.inf, low_inclusive=True, high_inclusive=False)
_FINITE: Final = Interval(-math.inf, math.inf, low_inclusive=False, high_inclusive=False)


def parse_layout(device: Table, table: Table, n: int) -> GridLayout:
    for key in ("columns", "pitch_mm"):
        if device.has(key) and table.has(key):
            raise device.error(key, f"given twice: here and as layout.{key}; keep one")
    source = table if table.has("columns") else device
    columns = source.integer("columns", math.isqrt(n - 1) + 1, 1, n, f" (at most channels = {n})")
    source = table if table.has("pitch_mm") else device
    pitch = source.number("pitch_mm", 2.5, PITCH_MM, " mm")
    return GridLayout(
        n_channels=n,
        columns=columns,
        pitch_x_mm=table.number("pitch_x_mm", pitch, PITCH_MM, " mm"),
        pitch_y_mm=table.number("pitch_y_mm", pitch, PITCH_MM, " mm"),
        origin=table.choice("origin", "top-left", LAYOUT_ORIGINS),
        order=table.choice("order", "row-major", LAYOUT_ORDERS),
    )


#: A ``baseline_ohm``/``baseline_counts`` entry for a channel without a baseline.
NO_BASELINE = "none"


def parse_baselines(table: Table, n: int, front_end: FrontEnd | None) -> tuple[float | None, ...] | None:
    """Per-channel unloaded resistance (ohm) from ``baseline_counts`` or ``baseline_ohm`` (in
    units of the reference resistor for a ``ratio`` front end, as its readings are); the string
    ``"none"`` for a channel without a baseline (None: nothing taken off, the unloaded reading
    guarded as ``no_zero``), as a partial ``tare`` writes for the channels it did not zero."""
    if table.has("baseline_counts") and table.has("baseline_ohm"):
        raise table.error("baseline_ohm", "give baseline_counts or baseline_ohm, not both")
    key = "baseline_counts" if table.has("baseline_counts") else "baseline_ohm"
    if not table.has(key):
        return None
    values = table.data[key]
    if not isinstance(values, list) or len(values) != n:
        got = (
            f"{len(values)} values"
            if isinstance(values, list)
            else f"{type_name(values)} {show_value(values)}"
        )
        raise table.error(
            key, f"expected an array of {n} numbers (one per channel, in index order), got {got}"
        )
    out: list[float | None] = []
    for i, value in enumerate(values):
        where = f"{table.at(key)}[{i}]"
        if value == NO_BASELINE:
            out.append(None)
            continue
        if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
            raise table.ctx.error(
                where,
                f'expected a number or "{NO_BASELINE}" (no baseline), got {type_name(value)} '
                f"{show_value(value)}",
            )
        if key == "baseline_ohm":
            if not value > 0.0:
                raise table.ctx.error(
                    where, f"{value!r} is out of range; allowed: (0, inf] ohm (inf: open at rest)"
                )
            out.append(float(value))
            continue
        if front_end is None:
            raise table.error(key, 'counts need an ADC front end (encoding = "adc"); use baseline_ohm')
        r, status = front_end.resistance(np.array([value], dtype=np.float64))
        resistance = float(r[0])
        if int(status[0]) == int(DividerStatus.INVALID) or not resistance > 0.0:
            raise table.ctx.error(
                where,
                f"{value!r} counts is not an unloaded reading of this front end ({front_end.describe()}): "
                f"it reads {resistance:g} ohm",
            )
        out.append(resistance)
    return tuple(out)


def parse_divider(table: Table) -> FrontEnd:
    """The older spelling of a high-side divider: ``[bus.device.divider]``."""
    return _front_end(
        table,
        Divider,
        supply_v=table.number("supply_v", 5.0, _POSITIVE, " V"),
        reference_ohm=table.number("reference_ohm", 10e3, _POSITIVE, " ohm"),
        adc_bits=table.integer("adc_bits", 16, 8, 16, " (ADC counts are one 16-bit register)"),
    )


def _front_end(table: Table, cls: type[FrontEnd], **params: Any) -> FrontEnd:
    try:
        return cls(**params)
    except ValueError as exc:
        field = str(exc).split(" ", 1)[0]
        key = field if field in params else "kind"
        raise table.error(key, str(exc)) from None


def parse_front_end(ctx: Context, path: str, data: dict[str, Any]) -> FrontEnd:
    """``[bus.device.front_end]``: the read-out circuit (docs/front-ends.md)."""
    kind_table = Table(ctx, data, path, sorted({k for keys in _FRONT_END_KEYS.values() for k in keys}))
    kind = kind_table.choice("kind", REQUIRED, FRONT_END_KINDS)
    table = Table(ctx, data, path, _FRONT_END_KEYS[kind])
    adc: dict[str, Any] = {
        "adc_bits": table.integer("adc_bits", REQUIRED, 8, 16, " (ADC counts are one 16-bit register)"),
        "adc_offset_counts": table.number("adc_offset_counts", 0.0, _FINITE, " counts"),
    }
    if kind == "ratio":
        return _front_end(table, RatioFrontEnd, rises_with_load=table.boolean("rises_with_load", True), **adc)
    if kind == "transimpedance":
        return _front_end(
            table,
            Transimpedance,
            bias_v=table.number("bias_v", REQUIRED, _POSITIVE, " V"),
            feedback_ohm=table.number("feedback_ohm", REQUIRED, _POSITIVE, " ohm"),
            adc_reference_v=table.number("adc_reference_v", REQUIRED, _POSITIVE, " V"),
            output_offset_v=table.number("output_offset_v", 0.0, _FINITE, " V"),
            **adc,
        )
    cls: type[FrontEnd] = Divider if kind == "high_side" else LowSideDivider
    reference_v = table.number("adc_reference_v", 0.0, _POSITIVE_OR_UNSET, " V (0: the supply)")
    return _front_end(
        table,
        cls,
        supply_v=table.number("supply_v", REQUIRED, _POSITIVE, " V"),
        reference_ohm=table.number("reference_ohm", REQUIRED, _POSITIVE, " ohm"),
        adc_reference_v=reference_v or None,
        **adc,
    )
