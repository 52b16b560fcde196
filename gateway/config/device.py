"""Parsing one ``[[bus.device]]`` table: profile, register map, clock, checks, front end,
layout, zero baselines, model, channels, calibration.

A device names its wire format: a ``profile`` (``profiles``) and/or its own ``registers``
table; nothing is read that neither names (no implicit clock, no implicit status bitmaps).
``parse_device`` resolves every channel of an array: its name (``ch00``, ``ch01``, ... unless
named), its position (from the ``layout``, mm, unless given), its unloaded baseline, its
effects and its sensor parameters, merged in this order: the defaults
(``docs/parameters.md``), the device's ``[bus.device.model.params]``, the calibration file's
``[channel.<name>]`` table, the channel entry's ``params``. A calibrated channel is read with
the calibration's values and effects: a configuration key that contradicts them is an error
unless the configuration says it overrides them (``overrides``). Every message names the file
and the key path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

from ..errors import ConfigError
from ..modbus.register_map import (
    FRAME_ENCODINGS,
    FRAME_TYPE_WIDTHS,
    MAX_READ_REGISTERS,
    Encoding,
    ValueFrame,
)
from ..model.conversion import Conversion, ConversionError, conversion_from_table
from ..model.curves import DRIFT_KEYS, CurveError, Drift
from ..model.effects import EFFECT_NAMES, PAPER_EFFECTS, UnknownEffectError, parse_effects
from ..model.frontend_base import FrontEnd
from ..model.params import PARAMETER_RANGES, ParameterError, SensorParams, parameter_names
from .calibration_format import CalibrationFile, read_calibration
from .layout import GridLayout
from .limits import DEFAULT_DEAD_AFTER_S
from .overrides import (
    DEVICE_OVERRIDE_KEY,
    EFFECTS,
    OVERRIDE_KEY,
    ChannelValues,
    Contradiction,
    conflict_error,
    parse_override_list,
    resolve_channel,
)
from .profiles import load_profile, merge_profile
from .readout import DIVIDER_KEYS, LAYOUT_KEYS, parse_baselines, parse_divider, parse_front_end, parse_layout
from .regions import parse_regions
from .rois import parse_rois
from .schema import DEAD_AFTER_S, DEVICE_ID, MAX_CHANNELS, POSITION_MM, RAILS, ChannelConfig, DeviceConfig
from .status_words import parse_status_words
from .tables import (
    REQUIRED,
    Context,
    Table,
    join_key,
    show_value,
    type_name,
)
from .wire import (
    CHECK_KEYS,
    FRAME_KEYS,
    REGISTER_KEYS,
    check_overlaps,
    parse_actions,
    parse_checks,
    parse_clock,
    parse_frame,
    parse_registers,
    parse_setup,
)

__all__ = ["DEVICE_KEYS", "device_overrides", "parse_device"]

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
    "frame",
    "setup",
    "actions",
    "clock",
    "checks",
    "front_end",
    "divider",
    "layout",
    "baseline_counts",
    "baseline_ohm",
    "model",
    "channel",
    "region",
    "address_unit",
    "value_stride",
    "dead_after_s",
    "status_word",
    "rails",
    "roi",
)
_MODEL_KEYS: Final = ("effects", "params", DEVICE_OVERRIDE_KEY)
_CHANNEL_KEYS: Final = ("index", "name", "x_mm", "y_mm", "enabled", "effects", "params", OVERRIDE_KEY)


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


def _conversion(
    cal: tuple[Path, str],
    name: str,
    table: tuple[str, dict[str, Any]],
    params: SensorParams,
    front_end: FrontEnd | None,
) -> Conversion:
    """A channel's line or lookup; a line without its own force range takes the channel's, a
    lookup in counts is read through ``front_end`` (the device's ADC front end, None: none)."""
    file, note = cal
    kind, data = table
    try:
        return conversion_from_table(kind, data, params.force_min_n, params.force_max_n, front_end)
    except ConversionError as exc:
        field, _, index = exc.key.partition("[")
        where = join_key(join_key(kind, name), field) + (f"[{index}" if index else "")
        raise ConfigError(f"{Context(file).error(where, exc.message)}{note}") from None


def _load_calibration(ctx: Context, path: str, file: Path, channel_names: Sequence[str]) -> CalibrationFile:
    """The calibration file named at ``path`` of ``ctx`` (``calibration_format.read_calibration``):
    per-channel parameter tables ``[channel.<name>]``, the channels' unloaded baselines
    (``baseline_ohm``), their line, lookup or curve tables (kind, table), their calibrated
    force ranges (``calibrated_min_n``/``calibrated_max_n``) and the effects (``[meta]``)."""
    return read_calibration(file, channel_names, _parse_param_overrides, named_at=(ctx, path))


def _output_drift(table: Table, frame: ValueFrame | None) -> Drift | None:
    """``drift = { creep_fraction = ..., ... }`` in ``[bus.device.frame]``: our drift
    correction on top of a device's own calibrated output (``curves.Drift``)."""
    if not table.has("drift"):
        return None
    if frame is None or frame.quantity not in ("force", "pressure"):
        raise table.error(
            "drift", "drift correction on a frame applies to a device's own force or pressure output"
        )
    raw = table.raw_table("drift", "drift = { creep_fraction = ..., creep_tau_s = ... }")
    Table(table.ctx, raw, table.at("drift"), DRIFT_KEYS)
    try:
        return Drift(**{k: v for k, v in raw.items()})
    except CurveError as exc:
        raise table.ctx.error(join_key(table.at("drift"), exc.key), exc.message) from None


def parse_device(ctx: Context, path: str, data: dict[str, Any]) -> DeviceConfig:
    """The ``[[bus.device]]`` table ``data`` at key path ``path`` of ``ctx``'s file."""
    return _parse_device(ctx, path, data)[0]


def device_overrides(ctx: Context, path: str, data: dict[str, Any]) -> tuple[Contradiction, ...]:
    """The keys of the ``[[bus.device]]`` table ``data`` that override its calibration, as the
    table says (``override`` / ``override_calibration``): what ``check-config`` lists."""
    return _parse_device(ctx, path, data)[1]


def _parse_device(
    ctx: Context, path: str, data: dict[str, Any]
) -> tuple[DeviceConfig, tuple[Contradiction, ...]]:
    Table(ctx, data, path, DEVICE_KEYS)  # unknown keys of the device's own table
    profile: str | None = None
    if "profile" in data:
        reference = Table(ctx, data, path, DEVICE_KEYS).required_string("profile", "a profile name or file")
        profile, profile_data = load_profile(ctx, join_key(path, "profile"), reference)
        data = merge_profile(profile_data, data)
    table = Table(ctx, data, path, DEVICE_KEYS)
    name = table.name("name")
    device_id = table.integer("device_id", REQUIRED, *DEVICE_ID)
    frame_table = table.table("frame", FRAME_KEYS, "[bus.device.frame]")
    region_set = parse_regions(ctx, table, frame_table.choice("type", "uint16", tuple(FRAME_TYPE_WIDTHS)))
    if region_set is None:
        n = table.integer("channels", REQUIRED, 1, MAX_CHANNELS)
    else:
        n = table.integer("channels", region_set.n_channels, 1, MAX_CHANNELS)
        if n != region_set.n_channels:
            raise table.error(
                "channels",
                f"{n}, but the regions hold {region_set.n_channels} (the sum of their rows x columns); "
                "drop this key or make them agree",
            )
    regions = () if region_set is None else region_set.regions
    frame = parse_frame(frame_table, n, MAX_READ_REGISTERS, region_set)
    if frame is None:
        encoding = table.choice("encoding", Encoding.ADC, (Encoding.ADC, Encoding.FLOAT32))
    else:
        encoding = FRAME_ENCODINGS[frame.quantity]
        if table.has("encoding") and data["encoding"] != encoding:
            raise table.error(
                "encoding",
                f"[bus.device.frame] says the values are {frame.quantity} (encoding {encoding!r}); "
                "drop this key",
            )
    output_drift = _output_drift(frame_table, frame)
    if regions:
        # the grid the device's consumers without regions see; contact area uses its cell
        layout = GridLayout(n, math.isqrt(n - 1) + 1, regions[0].pitch_x_mm, regions[0].pitch_y_mm)
    else:
        layout = parse_layout(table, table.table("layout", LAYOUT_KEYS, "[bus.device.layout]"), n)
    allow_write = table.boolean("allow_write", False)
    calibration = table.path_value("calibration")
    registers = parse_registers(
        table.table("registers", REGISTER_KEYS, "[bus.device.registers]"), n, encoding, profile, frame
    )
    registers = replace(registers, setup=parse_setup(table), actions=parse_actions(table))
    clock = parse_clock(ctx, table.at("clock"), data.get("clock"))
    if clock is not None:
        registers = replace(registers, clock=clock)
    checks = parse_checks(table.table("checks", CHECK_KEYS, "[bus.device.checks]"), n)
    if table.has("divider") and table.has("front_end"):
        raise table.error(
            "divider", "give front_end or divider (the older spelling of a high-side front end), not both"
        )
    if table.has("front_end"):
        front_end = parse_front_end(
            ctx, table.at("front_end"), table.raw_table("front_end", "[bus.device.front_end]")
        )
    elif table.has("divider") or encoding is not Encoding.ADC:
        front_end = parse_divider(table.table("divider", DIVIDER_KEYS, "[bus.device.divider]"))
    else:
        raise table.error(
            "front_end",
            "required key is missing: the read-out circuit that turns ADC counts into resistance "
            '(kind = "high_side" | "low_side" | "transimpedance", docs/front-ends.md), '
            "or a profile that names it",
        )
    baselines = parse_baselines(table, n, front_end if encoding is Encoding.ADC else None)

    model = table.table("model", _MODEL_KEYS, "[bus.device.model]")
    device_effects = (
        _parse_effects(ctx, model.at("effects"), model.data["effects"])
        if model.has("effects")
        else PAPER_EFFECTS
    )
    device_params = _parse_param_overrides(
        ctx, model.at("params"), model.raw_table("params", "[bus.device.model.params]")
    )
    device_override = frozenset[str]()
    if model.has(DEVICE_OVERRIDE_KEY):
        own = [*device_params, *([EFFECTS] if model.has("effects") else [])]
        device_override = parse_override_list(
            ctx, model.at(DEVICE_OVERRIDE_KEY), model.data[DEVICE_OVERRIDE_KEY], own
        )

    # Per-channel entries, keyed by channel index.
    entries: dict[int, tuple[Table, dict[str, float], frozenset[str]]] = {}
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
        override = frozenset[str]()
        if entry.has(OVERRIDE_KEY):
            own = [*overrides, *([EFFECTS] if entry.has("effects") else [])]
            override = parse_override_list(ctx, entry.at(OVERRIDE_KEY), entry.data[OVERRIDE_KEY], own)
        entries[index] = (entry, overrides, override)
        entry_paths[index] = entry.at("index")

    names: list[str] = []
    # name -> (index, key path of an explicit name or None for a default name)
    name_owner: dict[str, tuple[int, str | None]] = {}
    region_names = [r.channel_name(k) for r in regions for k in range(r.n_channels)]
    for i in range(n):
        channel_name = region_names[i] if regions else f"ch{i:02d}"
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
                "(unnamed channels are called ch00, ch01, ..., or <region>-r<row>c<column>); "
                "channel names are unique within a device",
            )
        name_owner[channel_name] = (i, where)
        names.append(channel_name)

    cal = CalibrationFile()
    cal_note = (calibration or Path(), f" (calibration file of {table.at('calibration')} in {ctx.label})")
    if calibration is not None:
        cal = _load_calibration(ctx, table.at("calibration"), calibration, names)
    calibrated, conversions = cal.params(), cal.conversion_tables()
    calibrated_baselines, calibrated_ranges = cal.baselines(), cal.calibrated_ranges()

    channels: list[ChannelConfig] = []
    contradictions: list[Contradiction] = []
    positions = [r.position_mm(k) for r in regions for k in range(r.n_channels)]
    for i, channel_name in enumerate(names):
        x_mm, y_mm = positions[i] if regions else layout.position_mm(i)
        enabled = True
        entry_table, own_params, own_override = entries.get(i, (None, {}, frozenset[str]()))
        own_effects = None
        blame = model.at("params")
        source = ["defaults"] + (["config"] if device_params else [])
        if channel_name in calibrated or channel_name in conversions:
            source.append("calibration")
        if channel_name in calibrated:
            blame = f"{table.at('calibration')} [channel.{channel_name}]"
        if entry_table is not None:
            x_mm = entry_table.number("x_mm", x_mm, POSITION_MM, " mm")
            y_mm = entry_table.number("y_mm", y_mm, POSITION_MM, " mm")
            enabled = entry_table.boolean("enabled", True)
            if entry_table.has("effects"):
                own_effects = _parse_effects(ctx, entry_table.at("effects"), entry_table.data["effects"])
            if own_params:
                blame = entry_table.at("params")
                source.append("channel")
        said = ChannelValues(
            device_params,
            model.at("params"),
            device_effects,
            model.at("effects") if model.has("effects") else None,
            device_override,
            own_params,
            entry_table.at("params") if entry_table is not None else "",
            own_effects,
            entry_table.at("effects") if entry_table is not None else "",
            own_override,
        )
        resolved = resolve_channel(
            channel_name,
            i,
            said,
            calibrated.get(channel_name),
            cal.effects,
            calibration or Path(),
            channel_name not in conversions,
        )
        contradictions.extend(resolved.contradictions)
        effects = resolved.effects
        try:
            params = SensorParams(**resolved.params)
        except ParameterError as exc:
            raise ctx.error(blame, f"{exc} (channel {channel_name!r}, index {i})") from None
        baseline = baselines[i] if baselines is not None else calibrated_baselines.get(channel_name)
        conversion = None
        if channel_name in conversions:
            adc_front_end = front_end if encoding is Encoding.ADC else None
            conversion = _conversion(cal_note, channel_name, conversions[channel_name], params, adc_front_end)
        channels.append(
            ChannelConfig(
                i,
                channel_name,
                x_mm,
                y_mm,
                enabled,
                effects,
                params,
                baseline,
                conversion,
                calibrated_ranges.get(channel_name),
                tuple(source),
            )
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
        output_drift=output_drift,
        regions=regions,
        status_words=parse_status_words(
            ctx,
            table,
            registers,
            "byte" if regions and table.data.get("address_unit") == "byte" else "register",
        ),
        dead_after_s=table.number(
            "dead_after_s", DEFAULT_DEAD_AFTER_S if regions else 0.0, DEAD_AFTER_S, " s (0: off)"
        ),
        rails=table.choice("rails", "faults", RAILS),
        rois=parse_rois(ctx, table, name, names, regions),
    )
    check_overlaps(ctx, path, device)
    refused = [c for c in contradictions if not c.overridden]
    if refused:
        raise conflict_error(ctx, path, refused)
    return device, tuple(c for c in contradictions if c.overridden)
