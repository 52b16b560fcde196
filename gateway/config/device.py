"""Parsing one ``[[bus.device]]`` table: profile, register map, clock, checks, front end,
layout, zero baselines, model, channels, calibration.

A device names its wire format: a ``profile`` (``profiles``) and/or its own ``registers``
table; nothing is read that neither names (no implicit clock, no implicit status bitmaps).
``parse_device`` resolves every channel of an array: its name (``ch00``, ``ch01``, ... unless
named), its position (from the ``layout``, mm, unless given), its unloaded baseline, its
effects and its sensor parameters, merged in this order: the defaults
(``docs/parameters.md``), the device's ``[bus.device.model.params]``, the calibration file's
``[channel.<name>]`` table, the channel entry's ``params``. Every message names the file and
the key path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import numpy as np

from ..errors import ConfigError
from ..modbus.register_map import (
    BYTE_ORDERS,
    CLOCK_REGISTERS,
    CLOCK_UNITS,
    ENCODINGS,
    IDENTIFICATION_FIELDS,
    MAX_ADDRESS,
    REGISTER_TABLES,
    STATUS_BITMAP_STRIDE,
    DeviceChecks,
    DeviceClock,
    RegisterCheck,
    RegisterMap,
    register_blocks,
    status_registers,
)
from ..model import FRONT_END_KINDS, Divider, DividerStatus, FrontEnd, LowSideDivider, Transimpedance
from ..model.conversion import CONVERSION_KINDS, Conversion, ConversionError, conversion_from_table
from ..model.effects import EFFECT_NAMES, PAPER_EFFECTS, UnknownEffectError, parse_effects
from ..model.params import PARAMETER_RANGES, Interval, ParameterError, SensorParams, parameter_names
from .layout import LAYOUT_ORDERS, LAYOUT_ORIGINS, GridLayout
from .profiles import load_profile, merge_profile
from .schema import DEVICE_ID, MAX_CHANNELS, PITCH_MM, POSITION_MM, ChannelConfig, DeviceConfig
from .tables import REQUIRED, Context, Table, join_key, parse_toml, show_value, suggest, type_name

__all__ = ["DEVICE_KEYS", "parse_device"]

DEVICE_KEYS: Final = (
    "name",
    "device_id",
    "profile",
    "encoding",
    "channels",
    "columns",
    "pitch_mm",
    "allow_write",
    "calibration",
    "registers",
    "clock",
    "checks",
    "front_end",
    "divider",
    "layout",
    "baseline_counts",
    "baseline_ohm",
    "model",
    "channel",
)
_REGISTER_KEYS: Final = (
    "table",
    "adc_address",
    "float_address",
    "word_order",
    "byte_order",
    "status_address",
    "force_reference_address",
    "temperature_address",
)
_CLOCK_KEYS: Final = ("address", "registers", "unit", "tick_s", "table")
_CHECK_KEYS: Final = ("registers", "channel_count", "identification")
_REGISTER_CHECK_KEYS: Final = ("what", "table", "address", "value")
_COUNT_CHECK_KEYS: Final = ("table", "address")
_LAYOUT_KEYS: Final = ("columns", "pitch_mm", "pitch_x_mm", "pitch_y_mm", "origin", "order")
_DIVIDER_KEYS: Final = ("supply_v", "reference_ohm", "adc_bits")
_ADC_KEYS: Final = ("adc_bits", "adc_reference_v", "adc_offset_counts")
_FRONT_END_KEYS: Final = {
    "high_side": ("kind", "supply_v", "reference_ohm", *_ADC_KEYS),
    "low_side": ("kind", "supply_v", "reference_ohm", *_ADC_KEYS),
    "transimpedance": ("kind", "bias_v", "feedback_ohm", "output_offset_v", *_ADC_KEYS),
}
_MODEL_KEYS: Final = ("effects", "params")
_CHANNEL_KEYS: Final = ("index", "name", "x_mm", "y_mm", "enabled", "effects", "params")
_CALIBRATION_CHANNEL_TABLE: Final = "channel"

_POSITIVE: Final = Interval(0.0, math.inf, low_inclusive=False, high_inclusive=False)
_POSITIVE_OR_UNSET: Final = Interval(0.0, math.inf, low_inclusive=True, high_inclusive=False)
_FINITE: Final = Interval(-math.inf, math.inf, low_inclusive=False, high_inclusive=False)


def _parse_registers(table: Table, n: int, encoding: str, profile: str | None) -> RegisterMap:
    status_span = 2 * STATUS_BITMAP_STRIDE + status_registers(n)
    value_key = "adc_address" if encoding == "adc" else "float_address"
    if not table.has(value_key):
        hint = f" ({profile} does not give it)" if profile else ""
        raise table.error(
            value_key,
            f"required key is missing{hint}: where the device keeps its {encoding} values; name a "
            'profile (profile = "tactile-sim" for the simulator, docs/profiles.md) or give '
            f"[bus.device.registers] {value_key} (`tactile-gateway scan` finds it)",
        )
    defaults = RegisterMap()
    return RegisterMap(
        adc_address=table.integer(
            "adc_address", defaults.adc_address, 0, MAX_ADDRESS + 1 - n, f" (the {n}-register ADC block)"
        ),
        float_address=table.integer(
            "float_address",
            defaults.float_address,
            0,
            MAX_ADDRESS + 1 - 2 * n,
            f" (the {2 * n}-register float32 block)",
        ),
        word_order=table.choice("word_order", "big", BYTE_ORDERS),
        byte_order=table.choice("byte_order", "big", BYTE_ORDERS),
        status_address=table.optional_address("status_address", None, MAX_ADDRESS + 1 - status_span),
        force_reference_address=table.optional_address(
            "force_reference_address", None, MAX_ADDRESS + 1 - 2 * n
        ),
        temperature_address=table.optional_address("temperature_address", None, MAX_ADDRESS + 1 - 2 * n),
        clock=None,
        table=table.choice("table", "input", REGISTER_TABLES),
    )


def _parse_clock(ctx: Context, path: str, value: object) -> DeviceClock | None:
    """``clock = "host"`` (the host's monotonic clock) or a table naming the register."""
    if value is None or value == "host":
        return None
    if not isinstance(value, dict):
        raise ctx.error(
            path,
            f'expected "host" or a table {{ address = ..., registers = 1 | 2 | 4, unit = "ms" }}, '
            f"got {type_name(value)} {show_value(value)}",
        )
    table = Table(ctx, value, path, _CLOCK_KEYS)
    registers = table.integer("registers", REQUIRED, 1, 4, " (1, 2 or 4: a 16, 32 or 64-bit counter)")
    if registers not in CLOCK_REGISTERS:
        raise table.error(
            "registers", f"{registers} is not allowed; allowed: 1, 2, 4 (16, 32 or 64-bit counter)"
        )
    address = table.integer("address", REQUIRED, 0, MAX_ADDRESS + 1 - registers)
    if table.has("unit") and table.has("tick_s"):
        raise table.error("tick_s", "give unit or tick_s, not both")
    if table.has("tick_s"):
        tick_s = table.number("tick_s", REQUIRED, Interval(0.0, 3600.0, low_inclusive=False), " s")
    else:
        tick_s = CLOCK_UNITS[table.choice("unit", REQUIRED, tuple(CLOCK_UNITS))]
    return DeviceClock(address, registers, tick_s, table.choice("table", "input", REGISTER_TABLES))


def _parse_checks(table: Table, n: int) -> DeviceChecks:
    ctx = table.ctx
    registers: list[RegisterCheck] = []
    for rpath, item in table.tables("registers", "registers = [{ what = ..., address = ..., value = ... }]"):
        entry = Table(ctx, item, rpath, _REGISTER_CHECK_KEYS)
        registers.append(
            RegisterCheck(
                what=entry.string("what", "register", "a short description") or "register",
                table=entry.choice("table", "input", REGISTER_TABLES),
                address=entry.integer("address", REQUIRED, 0, MAX_ADDRESS),
                value=entry.integer("value", REQUIRED, 0, 0xFFFF),
            )
        )
    if table.has("channel_count"):
        count = table.table(
            "channel_count", _COUNT_CHECK_KEYS, "channel_count = { table = ..., address = ... }"
        )
        registers.append(
            RegisterCheck(
                what="channel count",
                table=count.choice("table", "holding", REGISTER_TABLES),
                address=count.integer("address", REQUIRED, 0, MAX_ADDRESS),
                value=n,
            )
        )
    ident = table.table("identification", IDENTIFICATION_FIELDS, "identification = { product_code = ... }")
    expected = tuple(
        (key, ident.required_string(key, "the text the device reports"))
        for key in IDENTIFICATION_FIELDS
        if ident.has(key)
    )
    return DeviceChecks(tuple(registers), expected)


def _parse_layout(device: Table, table: Table, n: int) -> GridLayout:
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


def _parse_baselines(table: Table, n: int, front_end: FrontEnd | None) -> tuple[float | None, ...] | None:
    """Per-channel unloaded resistance (ohm) from ``baseline_counts`` or ``baseline_ohm``."""
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
        if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
            raise table.ctx.error(where, f"expected a number, got {type_name(value)} {show_value(value)}")
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


def _check_overlaps(ctx: Context, path: str, device: DeviceConfig) -> None:
    keys = {
        "status": "status_address",
        "adc": "adc_address",
        "float": "float_address",
        "force_reference": "force_reference_address",
        "temperature": "temperature_address",
        "device_time": "address",
    }
    blocks = register_blocks(device)
    for i, later in enumerate(blocks):
        for earlier in blocks[:i]:
            if later.kind == earlier.kind and later.address <= earlier.end and earlier.address <= later.end:
                # the clock is the block a user adds over a map, so it carries the blame
                blamed, other = (earlier, later) if earlier.purpose == "device_time" else (later, earlier)
                table = "clock" if blamed.purpose == "device_time" else "registers"
                raise ctx.error(
                    f"{path}.{table}.{keys[blamed.purpose]}",
                    f"the {blamed.name} block {blamed.address}..{blamed.end} overlaps the {other.name} block "
                    f"{other.address}..{other.end}; register blocks must not overlap",
                )


def _parse_divider(table: Table) -> FrontEnd:
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


def _parse_front_end(ctx: Context, path: str, data: dict[str, Any]) -> FrontEnd:
    """``[bus.device.front_end]``: the read-out circuit (docs/front-ends.md)."""
    kind_table = Table(ctx, data, path, sorted({k for keys in _FRONT_END_KEYS.values() for k in keys}))
    kind = kind_table.choice("kind", REQUIRED, FRONT_END_KINDS)
    table = Table(ctx, data, path, _FRONT_END_KEYS[kind])
    adc: dict[str, Any] = {
        "adc_bits": table.integer("adc_bits", REQUIRED, 8, 16, " (ADC counts are one 16-bit register)"),
        "adc_offset_counts": table.number("adc_offset_counts", 0.0, _FINITE, " counts"),
    }
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


def _parse_effects(ctx: Context, path: str, value: object) -> tuple[str, ...]:
    expected = f"an array of effect names ({', '.join(EFFECT_NAMES)})"
    if not isinstance(value, list):
        raise ctx.error(path, f"expected {expected}, got {type_name(value)} {show_value(value)}")
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise ctx.error(
                f"{path}[{i}]", f"expected an effect name, got {type_name(item)} {show_value(item)}"
            )
        try:
            parse_effects([item])
        except UnknownEffectError as exc:
            raise ctx.error(f"{path}[{i}]", str(exc)) from None
    return parse_effects(value)


def _parse_param_overrides(ctx: Context, path: str, value: object) -> dict[str, float]:
    """Check each override on its own: a known name, a number, inside its allowed range."""
    if not isinstance(value, dict):
        raise ctx.error(
            path, f"expected a table of sensor parameters, got {type_name(value)} {show_value(value)}"
        )
    out: dict[str, float] = {}
    known = parameter_names()
    for key, raw in value.items():
        try:
            if key not in known:
                SensorParams.from_mapping({key: raw})
            SensorParams(**{key: raw})
        except ParameterError as exc:
            in_range = (
                key in known
                and not isinstance(raw, bool)
                and isinstance(raw, int | float)
                and PARAMETER_RANGES[key].contains(float(raw))
            )
            if not in_range:  # else it only conflicts with a default; the resolved set is checked later
                raise ctx.error(join_key(path, key), str(exc)) from None
        out[key] = float(raw)
    return out


def _unknown_channel(cal_ctx: Context, where: str, name: str, channel_names: Sequence[str]) -> ConfigError:
    return cal_ctx.error(
        where,
        f"no channel {name!r} in this device{suggest(name, channel_names)} "
        f"(channels: {', '.join(channel_names[:8])}{', ...' if len(channel_names) > 8 else ''})",
    )


def _conversion_tables(
    cal_ctx: Context, data: dict[str, Any], channel_names: Sequence[str]
) -> dict[str, tuple[str, dict[str, Any]]]:
    """``[line.<name>]`` / ``[lookup.<name>]`` tables by channel: (kind, table), checked later."""
    out: dict[str, tuple[str, dict[str, Any]]] = {}
    for kind in CONVERSION_KINDS:
        tables = data.get(kind, {})
        if not isinstance(tables, dict):
            raise cal_ctx.error(kind, f"expected tables [{kind}.<name>], got {type_name(tables)}")
        for name, body in tables.items():
            where = join_key(kind, name)
            if name not in channel_names:
                raise _unknown_channel(cal_ctx, where, name, channel_names)
            if not isinstance(body, dict):
                raise cal_ctx.error(where, f"expected a table [{where}], got {type_name(body)}")
            if name in out:
                raise cal_ctx.error(where, f"channel {name!r} has a [line] and a [lookup] table; keep one")
            out[name] = (kind, body)
    return out


def _conversion(
    cal: tuple[Path, str], name: str, table: tuple[str, dict[str, Any]], params: SensorParams
) -> Conversion:
    """A channel's line or lookup; a line without its own force range takes the channel's."""
    file, note = cal
    kind, data = table
    try:
        return conversion_from_table(kind, data, params.force_min_n, params.force_max_n)
    except ConversionError as exc:
        field, _, index = exc.key.partition("[")
        where = join_key(join_key(kind, name), field) + (f"[{index}" if index else "")
        raise ConfigError(f"{Context(file).error(where, exc.message)}{note}") from None


def _load_calibration(
    ctx: Context, path: str, file: Path, channel_names: Sequence[str]
) -> tuple[dict[str, dict[str, float]], dict[str, float], dict[str, tuple[str, dict[str, Any]]]]:
    """Per-channel parameter tables ``[channel.<name>]`` of a calibration file, the
    channels' unloaded baselines (``baseline_ohm`` in the same tables) and their line or
    lookup tables (``[line.<name>]``, ``[lookup.<name>]``)."""
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ctx.error(path, f"{file} does not exist (calibration file)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ctx.error(path, f"cannot read calibration file {file}: {exc}") from None
    cal_ctx = Context(file)
    note = f" (calibration file of {path} in {ctx.label})"
    try:
        data = parse_toml(cal_ctx, text, "calibration")
        tables = data.get(_CALIBRATION_CHANNEL_TABLE, {})
        if not isinstance(tables, dict):
            raise cal_ctx.error("channel", f"expected tables [channel.<name>], got {type_name(tables)}")
        out: dict[str, dict[str, float]] = {}
        baselines: dict[str, float] = {}
        for name, params in tables.items():
            if name not in channel_names:
                raise _unknown_channel(cal_ctx, join_key("channel", name), name, channel_names)
            where = join_key("channel", name)
            if isinstance(params, dict) and "baseline_ohm" in params:
                params = dict(params)
                value = params.pop("baseline_ohm")
                if (
                    isinstance(value, bool)
                    or not isinstance(value, int | float)
                    or not 0.0 < value < math.inf
                ):
                    raise cal_ctx.error(
                        join_key(where, "baseline_ohm"),
                        f"{show_value(value)} is out of range; allowed: (0, inf) ohm",
                    )
                baselines[name] = float(value)
            out[name] = _parse_param_overrides(cal_ctx, where, params)
        conversions = _conversion_tables(cal_ctx, data, channel_names)
    except ConfigError as exc:
        raise ConfigError(f"{exc}{note}") from None
    return out, baselines, conversions


def parse_device(ctx: Context, path: str, data: dict[str, Any]) -> DeviceConfig:
    Table(ctx, data, path, DEVICE_KEYS)  # unknown keys of the device's own table
    profile: str | None = None
    if "profile" in data:
        reference = Table(ctx, data, path, DEVICE_KEYS).required_string("profile", "a profile name or file")
        profile, profile_data = load_profile(ctx, join_key(path, "profile"), reference)
        data = merge_profile(profile_data, data)
    table = Table(ctx, data, path, DEVICE_KEYS)
    name = table.name("name")
    device_id = table.integer("device_id", REQUIRED, *DEVICE_ID)
    encoding = table.choice("encoding", "adc", ENCODINGS)
    n = table.integer("channels", REQUIRED, 1, MAX_CHANNELS)
    layout = _parse_layout(table, table.table("layout", _LAYOUT_KEYS, "[bus.device.layout]"), n)
    allow_write = table.boolean("allow_write", False)
    calibration = table.path_value("calibration")
    registers = _parse_registers(
        table.table("registers", _REGISTER_KEYS, "[bus.device.registers]"), n, encoding, profile
    )
    clock = _parse_clock(ctx, table.at("clock"), data.get("clock"))
    if clock is not None:
        registers = replace(registers, clock=clock)
    checks = _parse_checks(table.table("checks", _CHECK_KEYS, "[bus.device.checks]"), n)
    if table.has("divider") and table.has("front_end"):
        raise table.error(
            "divider", "give front_end or divider (the older spelling of a high-side front end), not both"
        )
    if table.has("front_end"):
        front_end = _parse_front_end(
            ctx, table.at("front_end"), table.raw_table("front_end", "[bus.device.front_end]")
        )
    elif table.has("divider") or encoding == "float32":
        front_end = _parse_divider(table.table("divider", _DIVIDER_KEYS, "[bus.device.divider]"))
    else:
        raise table.error(
            "front_end",
            "required key is missing: the read-out circuit that turns ADC counts into resistance "
            '(kind = "high_side" | "low_side" | "transimpedance", docs/front-ends.md), '
            "or a profile that names it",
        )
    baselines = _parse_baselines(table, n, front_end if encoding == "adc" else None)

    model = table.table("model", _MODEL_KEYS, "[bus.device.model]")
    device_effects = (
        _parse_effects(ctx, model.at("effects"), model.data["effects"])
        if model.has("effects")
        else PAPER_EFFECTS
    )
    device_params = _parse_param_overrides(
        ctx, model.at("params"), model.raw_table("params", "[bus.device.model.params]")
    )

    # Per-channel entries, keyed by channel index.
    entries: dict[int, tuple[Table, dict[str, float]]] = {}
    entry_paths: dict[int, str] = {}
    for cpath, item in table.tables("channel", "[[bus.device.channel]]"):
        entry = Table(ctx, item, cpath, _CHANNEL_KEYS)
        index = entry.integer("index", REQUIRED, 0, n - 1, f" (channels = {n})")
        if index in entries:
            raise entry.error(
                "index",
                f"duplicate channel index {index} (also {entry_paths[index]}); each index once, 0..{n - 1}",
            )
        overrides = _parse_param_overrides(
            ctx, entry.at("params"), entry.raw_table("params", "params = {...}")
        )
        entries[index] = (entry, overrides)
        entry_paths[index] = entry.at("index")

    names: list[str] = []
    # name -> (index, key path of an explicit name or None for a default name)
    name_owner: dict[str, tuple[int, str | None]] = {}
    for i in range(n):
        channel_name = f"ch{i:02d}"
        where: str | None = None
        if i in entries and entries[i][0].has("name"):
            channel_name = entries[i][0].name("name")
            where = entries[i][0].at("name")
        if channel_name in name_owner:
            other, other_where = name_owner[channel_name]
            blame_path = where or other_where or f"{path}.channel"
            raise ctx.error(
                blame_path,
                f"duplicate channel name {channel_name!r}: channels {other} and {i} both have it "
                "(unnamed channels are called ch00, ch01, ...); channel names are unique within a device",
            )
        name_owner[channel_name] = (i, where)
        names.append(channel_name)

    calibrated: dict[str, dict[str, float]] = {}
    calibrated_baselines: dict[str, float] = {}
    conversions: dict[str, tuple[str, dict[str, Any]]] = {}
    cal_note = (calibration or Path(), f" (calibration file of {table.at('calibration')} in {ctx.label})")
    if calibration is not None:
        calibrated, calibrated_baselines, conversions = _load_calibration(
            ctx, table.at("calibration"), calibration, names
        )

    channels: list[ChannelConfig] = []
    for i, channel_name in enumerate(names):
        x_mm, y_mm = layout.position_mm(i)
        enabled = True
        effects = device_effects
        merged = dict(device_params)
        merged.update(calibrated.get(channel_name, {}))
        blame = model.at("params")
        if channel_name in calibrated:
            blame = f"{table.at('calibration')} [channel.{channel_name}]"
        if i in entries:
            entry, overrides = entries[i]
            x_mm = entry.number("x_mm", x_mm, POSITION_MM, " mm")
            y_mm = entry.number("y_mm", y_mm, POSITION_MM, " mm")
            enabled = entry.boolean("enabled", True)
            if entry.has("effects"):
                effects = _parse_effects(ctx, entry.at("effects"), entry.data["effects"])
            merged.update(overrides)
            if overrides:
                blame = entry.at("params")
        try:
            params = SensorParams(**merged)
        except ParameterError as exc:
            raise ctx.error(blame, f"{exc} (channel {channel_name!r}, index {i})") from None
        baseline = baselines[i] if baselines is not None else calibrated_baselines.get(channel_name)
        conversion = None
        if channel_name in conversions:
            conversion = _conversion(cal_note, channel_name, conversions[channel_name], params)
        channels.append(
            ChannelConfig(i, channel_name, x_mm, y_mm, enabled, effects, params, baseline, conversion)
        )

    device = DeviceConfig(
        name=name,
        device_id=device_id,
        encoding=encoding,
        n_channels=n,
        registers=registers,
        front_end=front_end,
        channels=tuple(channels),
        allow_write=allow_write,
        layout=layout,
        calibration=calibration,
        checks=checks,
        profile=profile,
    )
    _check_overlaps(ctx, path, device)
    return device
