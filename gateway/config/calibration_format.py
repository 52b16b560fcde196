"""The calibration file's format: written, read and recognised here and nowhere else.

A calibration file (``docs/calibration.md``, ``docs/configuration.md`` "Calibration files")
is a TOML file with a ``[meta]`` table (the record it was fitted to, the effects), per-channel
``[channel.<name>]`` tables (sensor parameter overrides, ``baseline_ohm``, the calibrated force
range ``calibrated_min_n``/``calibrated_max_n``) and per-channel ``[line.<name>]``,
``[lookup.<name>]`` or ``[curve.<name>]`` conversion tables. ``CalibrationFile`` is that file
as a value: ``CalibrationFile.to_toml`` writes it (tomlkit: every string and key escaped, floats
exact), ``read_calibration`` reads it back with the gateway's checks (``ConfigError`` naming the
file and the key path), ``set_table_values`` edits values of a written file and keeps the rest.

This module sits below ``device`` (which reads a device's ``calibration`` through
``read_calibration``, passing its own check of a table of sensor parameters);
``calibration_file`` above both is the API the rest of the gateway uses (``load_calibration``,
``check_calibration_file``, and the device ``tactile-gateway apply`` reads a record with).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import tomlkit
from tomlkit.items import KeyType, SingleKey, Table

from ..errors import ConfigError
from ..model.conversion import CONVERSION_KINDS
from ..model.effects import EFFECT_NAMES, UnknownEffectError, parse_effects
from .tables import Context, join_key, parse_toml, read_text_file, show_path, show_value, suggest, type_name

__all__ = [
    "CALIBRATED_RANGE_KEYS",
    "CALIBRATION_TABLES",
    "END",
    "CalibrationFile",
    "ChannelCalibration",
    "CheckParams",
    "ConversionTable",
    "read_calibration",
    "read_toml",
    "replace_table",
    "set_table_values",
]

#: The top-level tables of a calibration file; the gateway ignores any other (``[meta]`` it
#: reads only for ``record`` and ``effects``), ``check_calibration_file`` refuses them.
CALIBRATION_TABLES: Final = ("meta", "channel", *CONVERSION_KINDS)
#: The keys of a calibration's ``[channel.<name>]`` table that are not sensor parameters: the
#: force range the channel was calibrated on (N; written by ``calibrate``; a force outside it
#: reads ``extrapolated``).
CALIBRATED_RANGE_KEYS: Final = ("calibrated_min_n", "calibrated_max_n")
#: The key of a table's ``comments`` written after its last key.
END: Final = ""
#: Comments: lines written before the key they are filed under (``END``: after the last key).
#: ``read_calibration`` does not read comments back, so they take no part in equality.
Comments = Mapping[str, tuple[str, ...]]
#: How a ``[channel.<name>]`` table's sensor parameters are checked: (the file's context, the
#: table's key path, the table without its other keys) -> the overrides, or ``ConfigError``
#: (the configuration's own check of every table of sensor parameters, ``device``'s).
CheckParams = Callable[[Context, str, object], dict[str, float]]


def _no_comments() -> dict[str, tuple[str, ...]]:
    return {}


@dataclass(frozen=True)
class ChannelCalibration:
    """A ``[channel.<name>]`` table: sensor parameter overrides (checked as the gateway checks
    them, in file order), the unloaded ``baseline_ohm`` and the calibrated force range
    ``(calibrated_min_n, calibrated_max_n)`` (N; a missing bound reads 0 N / inf)."""

    params: Mapping[str, float] = field(default_factory=dict)
    baseline_ohm: float | None = None
    calibrated_range_n: tuple[float, float] | None = None
    comments: Comments = field(default_factory=_no_comments, compare=False)

    def values(self) -> dict[str, float]:
        """The table's keys and values, as written."""
        out = {k: float(v) for k, v in self.params.items()}
        if self.baseline_ohm is not None:
            out["baseline_ohm"] = float(self.baseline_ohm)
        if self.calibrated_range_n is not None:
            low, high = self.calibrated_range_n
            out.update(calibrated_min_n=float(low), calibrated_max_n=float(high))
        return out


@dataclass(frozen=True)
class ConversionTable:
    """A ``[line.<name>]``, ``[lookup.<name>]`` or ``[curve.<name>]`` table (``kind``). Its
    values are checked with the channel's parameters (a line without its own force range takes
    the channel's), by ``device.parse_device`` (``model.conversion.conversion_from_table``)."""

    kind: str
    values: Mapping[str, Any]
    comments: Comments = field(default_factory=_no_comments, compare=False)


@dataclass(frozen=True)
class CalibrationFile:
    """A calibration file as a value. ``record`` and ``effects`` are its ``[meta]`` table (None:
    not given; ``effects`` as read back are in canonical order, ``model.effects.parse_effects``,
    and the gateway reads the calibrated channels with them); ``channels`` its
    ``[channel.<name>]`` tables and ``conversions`` its line, lookup and curve tables, by
    channel name. ``header`` (comment lines at the top of the file)
    and ``meta_comments`` (after the ``[meta]`` keys) are written, not read back."""

    channels: Mapping[str, ChannelCalibration] = field(default_factory=dict)
    conversions: Mapping[str, ConversionTable] = field(default_factory=dict)
    record: str | None = None
    effects: tuple[str, ...] | None = None
    header: tuple[str, ...] = field(default=(), compare=False)
    meta_comments: tuple[str, ...] = field(default=(), compare=False)

    def channel_names(self) -> tuple[str, ...]:
        """Every channel the file has a table for, in the order they first appear (``[channel]``
        tables first, then ``[line]``, ``[lookup]``, ``[curve]``)."""
        return tuple(dict.fromkeys([*self.channels, *self.conversions]))

    def params(self) -> dict[str, dict[str, float]]:
        return {name: dict(ch.params) for name, ch in self.channels.items()}

    def baselines(self) -> dict[str, float]:
        return {n: ch.baseline_ohm for n, ch in self.channels.items() if ch.baseline_ohm is not None}

    def calibrated_ranges(self) -> dict[str, tuple[float, float]]:
        return {
            n: ch.calibrated_range_n for n, ch in self.channels.items() if ch.calibrated_range_n is not None
        }

    def conversion_tables(self) -> dict[str, tuple[str, dict[str, Any]]]:
        return {name: (t.kind, dict(t.values)) for name, t in self.conversions.items()}

    def to_toml(self) -> str:
        """The file's TOML text (tomlkit): ``[meta]``, the ``[channel.<name>]`` tables, then
        the line, lookup and curve tables; names are quoted keys, floats exact (``repr``;
        ``inf``)."""
        doc = tomlkit.document()
        for line in self.header:
            doc.add(tomlkit.comment(_comment(line)))
        if self.record is not None or self.effects is not None or self.meta_comments:
            meta: dict[str, Any] = {}
            if self.record is not None:
                meta["record"] = self.record
            if self.effects is not None:
                meta["effects"] = list(self.effects)
            doc.add("meta", _table(meta, {END: self.meta_comments}))
        groups: list[tuple[str, dict[str, tuple[Mapping[str, Any], Comments]]]] = [
            ("channel", {n: (ch.values(), ch.comments) for n, ch in self.channels.items()})
        ]
        for kind in CONVERSION_KINDS:
            groups.append(
                (kind, {n: (t.values, t.comments) for n, t in self.conversions.items() if t.kind == kind})
            )
        for kind, tables in groups:
            if tables:
                group = tomlkit.table(is_super_table=True)
                for name, (values, comments) in tables.items():
                    group.add(SingleKey(name, t=KeyType.Basic), _table(values, comments))
                doc.add(kind, group)
        return tomlkit.dumps(doc)


def _comment(text: str) -> str:
    """A comment's text on one line (control characters shown escaped)."""
    return "".join(c if c.isprintable() or c == "\t" else repr(c)[1:-1] for c in text)


def _value(value: Any) -> Any:
    if isinstance(value, bool | str):
        return value
    if isinstance(value, int | float):
        return int(value) if isinstance(value, int) else float(value)
    if isinstance(value, list | tuple):
        return [_value(v) for v in value]
    raise TypeError(f"a calibration file holds numbers, strings and arrays, not {type_name(value)}")


def _table(values: Mapping[str, Any], comments: Comments) -> Table:
    """A TOML table of ``values``, with ``comments`` before their keys (``END``: after the last)."""
    unknown = set(comments) - set(values) - {END}
    if unknown:
        raise ValueError(f"comments filed under keys the table does not have: {sorted(unknown)}")
    table = tomlkit.table()
    for key, value in values.items():
        for line in comments.get(key, ()):
            table.add(tomlkit.comment(_comment(line)))
        table.add(SingleKey(key), _value(value))
    for line in comments.get(END, ()):
        table.add(tomlkit.comment(_comment(line)))
    return table


def _calibrated_range(cal_ctx: Context, where: str, params: dict[str, Any]) -> tuple[float, float] | None:
    """Pop ``calibrated_min_n``/``calibrated_max_n`` off a ``[channel.<name>]`` table: the
    calibrated force range (a missing bound is 0 N / inf), or None when neither is given."""
    if not any(key in params for key in CALIBRATED_RANGE_KEYS):
        return None
    bounds = {"calibrated_min_n": 0.0, "calibrated_max_n": math.inf}
    for key in CALIBRATED_RANGE_KEYS:
        if key not in params:
            continue
        value = params.pop(key)
        low_ok = key == "calibrated_min_n" and isinstance(value, int | float) and 0.0 <= value < math.inf
        high_ok = key == "calibrated_max_n" and isinstance(value, int | float) and 0.0 < value <= math.inf
        if isinstance(value, bool) or not (low_ok or high_ok):
            allowed = "[0, inf) N" if key == "calibrated_min_n" else "(0, inf] N"
            raise cal_ctx.error(
                join_key(where, key), f"{show_value(value)} is out of range; allowed: {allowed}"
            )
        bounds[key] = float(value)
    low, high = bounds["calibrated_min_n"], bounds["calibrated_max_n"]
    if not low < high:
        raise cal_ctx.error(
            join_key(where, "calibrated_max_n"),
            f"{high!r} is out of range; allowed: (calibrated_min_n = {low!r}, inf] N",
        )
    return low, high


def _unknown_channel(cal_ctx: Context, where: str, name: str, channel_names: Sequence[str]) -> ConfigError:
    return cal_ctx.error(
        where,
        f"no channel {name!r} in this device{suggest(name, channel_names)} "
        f"(channels: {', '.join(channel_names[:8])}{', ...' if len(channel_names) > 8 else ''})",
    )


def _check_name(cal_ctx: Context, where: str, name: str, channel_names: Sequence[str] | None) -> None:
    if channel_names is not None and name not in channel_names:
        raise _unknown_channel(cal_ctx, where, name, channel_names)


def _conversion_tables(
    cal_ctx: Context, data: dict[str, Any], channel_names: Sequence[str] | None
) -> dict[str, ConversionTable]:
    """``[line.<name>]`` / ``[lookup.<name>]`` / ``[curve.<name>]`` tables by channel, checked
    later (with the channel's parameters)."""
    out: dict[str, ConversionTable] = {}
    for kind in CONVERSION_KINDS:
        tables = data.get(kind, {})
        if not isinstance(tables, dict):
            raise cal_ctx.error(kind, f"expected tables [{kind}.<name>], got {type_name(tables)}")
        for name, body in tables.items():
            where = join_key(kind, name)
            _check_name(cal_ctx, where, name, channel_names)
            if not isinstance(body, dict):
                raise cal_ctx.error(where, f"expected a table [{where}], got {type_name(body)}")
            if name in out:
                raise cal_ctx.error(
                    where, f"channel {name!r} has a [{out[name].kind}] and a [{kind}] table; keep one"
                )
            out[name] = ConversionTable(kind, body)
    return out


def _channel_tables(
    cal_ctx: Context, data: dict[str, Any], channel_names: Sequence[str] | None, check_params: CheckParams
) -> dict[str, ChannelCalibration]:
    """The ``[channel.<name>]`` tables: parameter overrides, baseline and calibrated range."""
    tables = data.get("channel", {})
    if not isinstance(tables, dict):
        raise cal_ctx.error("channel", f"expected tables [channel.<name>], got {type_name(tables)}")
    out: dict[str, ChannelCalibration] = {}
    for name, params in tables.items():
        where = join_key("channel", name)
        _check_name(cal_ctx, where, name, channel_names)
        calibrated = baseline = None
        if isinstance(params, dict) and any(key in params for key in CALIBRATED_RANGE_KEYS):
            params = dict(params)
            calibrated = _calibrated_range(cal_ctx, where, params)
        if isinstance(params, dict) and "baseline_ohm" in params:
            params = dict(params)
            value = params.pop("baseline_ohm")
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 < value < math.inf:
                raise cal_ctx.error(
                    join_key(where, "baseline_ohm"),
                    f"{show_value(value)} is out of range; allowed: (0, inf) ohm",
                )
            baseline = float(value)
        out[name] = ChannelCalibration(check_params(cal_ctx, where, params), baseline, calibrated)
    return out


def _from_data(
    cal_ctx: Context, data: dict[str, Any], channel_names: Sequence[str] | None, check_params: CheckParams
) -> CalibrationFile:
    channels = _channel_tables(cal_ctx, data, channel_names, check_params)
    conversions = _conversion_tables(cal_ctx, data, channel_names)
    meta = data.get("meta")
    meta = meta if isinstance(meta, dict) else {}  # the gateway reads nothing else of [meta]
    record = meta.get("record")
    effects = _effects(cal_ctx, meta["effects"]) if "effects" in meta else None
    return CalibrationFile(channels, conversions, record if isinstance(record, str) else None, effects)


def _effects(cal_ctx: Context, value: object) -> tuple[str, ...]:
    """``[meta] effects``: the effects the channels were fitted with, which the gateway reads
    them with; an array of effect names, returned in canonical order (``parse_effects``)."""
    expected = f"an array of effect names ({', '.join(EFFECT_NAMES)})"
    if not isinstance(value, list):
        raise cal_ctx.error(
            "meta.effects", f"expected {expected}, got {type_name(value)} {show_value(value)}"
        )
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise cal_ctx.error(
                f"meta.effects[{i}]", f"expected an effect name, got {type_name(item)} {show_value(item)}"
            )
        try:
            parse_effects([item])
        except UnknownEffectError as exc:
            raise cal_ctx.error(f"meta.effects[{i}]", str(exc)) from None
    return parse_effects(value)


def read_toml(file: Path) -> dict[str, Any]:
    """A calibration file's TOML, unchecked (``ConfigError`` naming the file when it is
    missing, a directory, unreadable or not TOML)."""
    if not file.exists():
        raise ConfigError(f"{file}: no such file (calibration file)")
    if file.is_dir():
        raise ConfigError(f"{file}: is a directory, not a calibration file")
    return parse_toml(Context(file), read_text_file(file, "calibration file"), "calibration")


def read_calibration(
    path: Path,
    channel_names: Sequence[str] | None,
    check_params: CheckParams,
    *,
    named_at: tuple[Context, str] | None = None,
    data: dict[str, Any] | None = None,
) -> CalibrationFile:
    """The calibration file at ``path`` (or its TOML ``data``, already read), checked as the
    gateway checks it: every ``[channel.<name>]`` table's parameters (``check_params``),
    ``baseline_ohm`` and calibrated range, and that every table names one of ``channel_names``
    (None: any name). A line, lookup or curve table's values are checked with the channel's
    parameters, by ``device.parse_device``. Top-level tables other than ``CALIBRATION_TABLES``
    and ``[meta]`` keys other than ``record`` and ``effects`` are ignored.

    ``ConfigError`` names the file and the key path; with ``named_at`` (the configuration and
    the key that names the file, as ``[[bus.device]] calibration = "..."`` does) a missing or
    unreadable file is that key's error, and any other ends with what named the file."""
    if named_at is None:
        return _from_data(
            Context(path), read_toml(path) if data is None else data, channel_names, check_params
        )
    ctx, key = named_at
    if not path.exists():
        raise ctx.error(key, f"{show_path(path)} does not exist (calibration file)")
    try:
        text = read_text_file(path, "calibration file")
    except ConfigError as exc:
        raise ctx.error(key, str(exc)) from None
    cal_ctx = Context(path)
    try:
        return _from_data(cal_ctx, parse_toml(cal_ctx, text, "calibration"), channel_names, check_params)
    except ConfigError as exc:
        raise ConfigError(f"{exc} (calibration file of {key} in {ctx.label})") from None


def set_table_values(text: str, kind: str, updates: Mapping[str, Mapping[str, float]]) -> str:
    """The calibration file ``text`` with the given keys of its ``[<kind>.<name>]`` tables set
    (``updates``: by channel name; a key the table lacks is added at its end), every other line,
    comment and table as it was (tomlkit). ``KeyError`` for a table the file does not have."""
    doc = tomlkit.parse(text)
    for name, values in updates.items():
        table = doc[kind][name]
        for key, value in values.items():
            table[key] = float(value)
    return tomlkit.dumps(doc)


def replace_table(text: str, kind: str, name: str, new_kind: str, values: Mapping[str, object]) -> str:
    """The calibration file ``text`` with its ``[<kind>.<name>]`` table replaced by a
    ``[<new_kind>.<name>]`` table of ``values`` (an empty ``[<kind>]`` removed), every other
    line, comment and table as it was (tomlkit). ``KeyError`` for a table the file lacks."""
    doc = tomlkit.parse(text)
    del doc[kind][name]
    if not doc[kind]:
        del doc[kind]
    if new_kind not in doc:
        doc[new_kind] = tomlkit.table(is_super_table=True)
    table = tomlkit.table()
    for key, value in values.items():
        table[key] = value
    doc[new_kind][name] = table
    return tomlkit.dumps(doc)
