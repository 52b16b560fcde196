"""Parsing one ``[[bus.device]]`` table: register map, divider, model, channels, calibration.

``parse_device`` resolves every channel of an array: its name (``ch00``, ``ch01``, ... unless
named), its position (row-major from ``columns`` and ``pitch_mm``, mm, unless given), its
effects and its sensor parameters, merged in this order: the defaults
(``docs/parameters.md``), the device's ``[bus.device.model.params]``, the calibration file's
``[channel.<name>]`` table, the channel entry's ``params``. Every message names the file and
the key path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

from ..errors import ConfigError
from ..modbus.register_map import (
    BYTE_ORDERS,
    ENCODINGS,
    MAX_ADDRESS,
    STATUS_BITMAP_STRIDE,
    RegisterMap,
    register_blocks,
    status_registers,
)
from ..model import Divider
from ..model.effects import EFFECT_NAMES, PAPER_EFFECTS, UnknownEffectError, parse_effects
from ..model.params import PARAMETER_RANGES, Interval, ParameterError, SensorParams, parameter_names
from .schema import DEVICE_ID, MAX_CHANNELS, PITCH_MM, POSITION_MM, ChannelConfig, DeviceConfig
from .tables import REQUIRED, Context, Table, join_key, parse_toml, show_value, suggest, type_name

__all__ = ["DEVICE_KEYS", "parse_device"]

DEVICE_KEYS: Final = (
    "name",
    "device_id",
    "encoding",
    "channels",
    "columns",
    "pitch_mm",
    "allow_write",
    "calibration",
    "registers",
    "divider",
    "model",
    "channel",
)
_REGISTER_KEYS: Final = (
    "adc_address",
    "float_address",
    "word_order",
    "byte_order",
    "status_address",
    "force_reference_address",
    "temperature_address",
)
_DIVIDER_KEYS: Final = ("supply_v", "reference_ohm", "adc_bits")
_MODEL_KEYS: Final = ("effects", "params")
_CHANNEL_KEYS: Final = ("index", "name", "x_mm", "y_mm", "enabled", "effects", "params")
_CALIBRATION_CHANNEL_TABLE: Final = "channel"

_POSITIVE: Final = Interval(0.0, math.inf, low_inclusive=False, high_inclusive=False)


def _parse_registers(table: Table, n: int) -> RegisterMap:
    status_span = 2 * STATUS_BITMAP_STRIDE + status_registers(n)
    return RegisterMap(
        adc_address=table.integer(
            "adc_address", 100, 0, MAX_ADDRESS + 1 - n, f" (the {n}-register ADC block)"
        ),
        float_address=table.integer(
            "float_address", 400, 0, MAX_ADDRESS + 1 - 2 * n, f" (the {2 * n}-register float32 block)"
        ),
        word_order=table.choice("word_order", "big", BYTE_ORDERS),
        byte_order=table.choice("byte_order", "big", BYTE_ORDERS),
        status_address=table.optional_address("status_address", 16, MAX_ADDRESS + 1 - status_span),
        force_reference_address=table.optional_address(
            "force_reference_address", None, MAX_ADDRESS + 1 - 2 * n
        ),
        temperature_address=table.optional_address("temperature_address", None, MAX_ADDRESS + 1 - 2 * n),
    )


def _check_overlaps(ctx: Context, path: str, device: DeviceConfig) -> None:
    keys = {
        "status": "status_address",
        "adc": "adc_address",
        "float": "float_address",
        "force_reference": "force_reference_address",
        "temperature": "temperature_address",
    }
    blocks = register_blocks(device)
    for i, later in enumerate(blocks):
        for earlier in blocks[:i]:
            if later.kind == earlier.kind and later.address <= earlier.end and earlier.address <= later.end:
                raise ctx.error(
                    f"{path}.registers.{keys[later.purpose]}",
                    f"the {later.name} block {later.address}..{later.end} overlaps the {earlier.name} block "
                    f"{earlier.address}..{earlier.end}; register blocks must not overlap",
                )


def _parse_divider(table: Table) -> Divider:
    return Divider(
        supply_v=table.number("supply_v", 5.0, _POSITIVE, " V"),
        reference_ohm=table.number("reference_ohm", 10e3, _POSITIVE, " ohm"),
        adc_bits=table.integer("adc_bits", 16, 8, 16, " (ADC counts are one 16-bit register)"),
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


def _load_calibration(
    ctx: Context, path: str, file: Path, channel_names: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Per-channel parameter tables ``[channel.<name>]`` of a calibration file."""
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
        for name, params in tables.items():
            if name not in channel_names:
                raise cal_ctx.error(
                    join_key("channel", name),
                    f"no channel {name!r} in this device{suggest(name, channel_names)} "
                    f"(channels: {', '.join(channel_names[:8])}{', ...' if len(channel_names) > 8 else ''})",
                )
            out[name] = _parse_param_overrides(cal_ctx, join_key("channel", name), params)
    except ConfigError as exc:
        raise ConfigError(f"{exc}{note}") from None
    return out


def parse_device(ctx: Context, path: str, data: dict[str, Any]) -> DeviceConfig:
    table = Table(ctx, data, path, DEVICE_KEYS)
    name = table.name("name")
    device_id = table.integer("device_id", REQUIRED, *DEVICE_ID)
    encoding = table.choice("encoding", "adc", ENCODINGS)
    n = table.integer("channels", REQUIRED, 1, MAX_CHANNELS)
    columns = table.integer("columns", math.isqrt(n - 1) + 1, 1, n, f" (at most channels = {n})")
    pitch_mm = table.number("pitch_mm", 2.5, PITCH_MM, " mm")
    allow_write = table.boolean("allow_write", False)
    calibration = table.path_value("calibration")
    registers = _parse_registers(table.table("registers", _REGISTER_KEYS, "[bus.device.registers]"), n)
    divider = _parse_divider(table.table("divider", _DIVIDER_KEYS, "[bus.device.divider]"))

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
    if calibration is not None:
        calibrated = _load_calibration(ctx, table.at("calibration"), calibration, names)

    channels: list[ChannelConfig] = []
    for i, channel_name in enumerate(names):
        x_mm = float((i % columns) * pitch_mm)
        y_mm = float((i // columns) * pitch_mm)
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
        channels.append(ChannelConfig(i, channel_name, x_mm, y_mm, enabled, effects, params))

    device = DeviceConfig(
        name=name,
        device_id=device_id,
        encoding=encoding,
        n_channels=n,
        registers=registers,
        divider=divider,
        channels=tuple(channels),
        allow_write=allow_write,
        columns=columns,
        pitch_mm=pitch_mm,
        calibration=calibration,
    )
    _check_overlaps(ctx, path, device)
    return device
