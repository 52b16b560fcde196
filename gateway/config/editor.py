"""The comment-keeping editor of channel settings (``tactile-gateway channels set|enable|disable``).

The file is edited with tomlkit, so the operator's comments and layout stay; the edited text
is validated with ``parse_config`` before anything is written, and the write is atomic. An
edit that would make the configuration invalid (or would not take effect) is refused with a
``ConfigError`` and leaves the file byte for byte as it was. Keys: ``name``, ``x_mm``,
``y_mm`` (mm), ``enabled``, ``effects`` (comma list), ``override`` (comma list: the entry's keys
that win over a calibration, ``overrides``), or any sensor parameter (into the channel's
``params`` table). ``ParameterSources`` tells where each resolved parameter of a
channel comes from: default, device, calibration file or channel.
"""

from __future__ import annotations

import difflib
import math
import stat
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomlkit
from tomlkit.items import AoT, Array, InlineTable, Item, Table

from ..atomic import atomic_write_text
from ..errors import ConfigError
from ..keys import check_keys
from ..model import UnknownEffectError, parameter_names, parse_effects
from .overrides import DEVICE_OVERRIDE_KEY, OVERRIDE_KEY
from .parser import parse_config
from .readout import NO_BASELINE
from .schema import BusConfig, ChannelConfig, DeviceConfig, GatewayConfig
from .tables import read_text_file

__all__ = [
    "PLAIN_KEYS",
    "Assignment",
    "ChannelTarget",
    "EditResult",
    "ParameterSources",
    "edit_channel",
    "find_channel",
    "find_devices",
    "flag_assignment",
    "parse_assignment",
    "parse_edited",
    "read_config_text",
    "write_config",
]

#: Channel keys set directly (the rest are sensor parameters, set in ``params``).
PLAIN_KEYS = ("name", "x_mm", "y_mm", "enabled", "effects")
#: ``check_keys``'s message for ``channels set``: it lists the plain keys only
_UNKNOWN_KEY = "unknown key {key}{hint} (allowed: {allowed}, or a sensor parameter such as r0_ohm)"
_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


@dataclass(frozen=True)
class ChannelTarget:
    bus_index: int
    device_index: int
    bus: BusConfig
    device: DeviceConfig
    channel: ChannelConfig


def find_devices(
    config: GatewayConfig, device_name: str | None
) -> list[tuple[int, int, BusConfig, DeviceConfig]]:
    found = [
        (b, d, bus, dev)
        for b, bus in enumerate(config.buses)
        for d, dev in enumerate(bus.devices)
        if device_name is None or dev.name == device_name
    ]
    if device_name is not None and not found:
        names = [dev.name for _, dev in config.devices()]
        close = difflib.get_close_matches(device_name, names, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ConfigError(f"{config.source}: no device {device_name!r}{hint} (devices: {', '.join(names)})")
    return found


def find_channel(config: GatewayConfig, name: str, device_name: str | None) -> ChannelTarget:
    matches: list[ChannelTarget] = []
    for b, d, bus, dev in find_devices(config, device_name):
        for ch in dev.channels:
            if ch.name == name:
                matches.append(ChannelTarget(b, d, bus, dev, ch))
    if len(matches) > 1:
        devices = ", ".join(t.device.name for t in matches)
        raise ConfigError(
            f"{config.source}: channel {name!r} exists in devices {devices}; choose one with --device NAME"
        )
    if not matches:
        names = [ch.name for _, _, _, dev in find_devices(config, device_name) for ch in dev.channels]
        close = difflib.get_close_matches(name, names, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        scope = f" of device {device_name!r}" if device_name else ""
        raise ConfigError(
            f"{config.source}: no channel {name!r}{scope}{hint} (see `tactile-gateway channels list`)"
        )
    return matches[0]


class ParameterSources:
    """Where each parameter of a device's channels comes from: default, device, calibration, channel."""

    def __init__(self, text: str, bus_index: int, device_index: int, device: DeviceConfig) -> None:
        raw: dict[str, Any] = tomllib.loads(text.removeprefix("\ufeff"))["bus"][bus_index]["device"][
            device_index
        ]
        self.device_keys = list(raw.get("model", {}).get("params", {}))
        # the device's keys that win over the calibration ([bus.device.model] override_calibration)
        self.device_wins = set(raw.get("model", {}).get(DEVICE_OVERRIDE_KEY, [])) & set(self.device_keys)
        self.channel_keys: dict[int, list[str]] = {}
        for entry in raw.get("channel", []):
            self.channel_keys[entry["index"]] = list(entry.get("params", {}))
        self.calibration: dict[str, Any] = {}
        if device.calibration is not None:
            self.calibration = tomllib.loads(
                read_text_file(device.calibration, "calibration file").lstrip("\ufeff")
            ).get("channel", {})

    def of(self, channel: ChannelConfig) -> dict[str, str]:
        sources = dict.fromkeys(parameter_names(), "default")
        sources.update(dict.fromkeys(self.device_keys, "device"))
        calibrated = [k for k in self.calibration.get(channel.name, {}) if k not in self.device_wins]
        sources.update(dict.fromkeys(calibrated, "calibration"))
        sources.update(dict.fromkeys(self.channel_keys.get(channel.index, []), "channel"))
        return sources


def _parse_bool(key: str, text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in _TRUE:
        return True
    if lowered in _FALSE:
        return False
    raise ConfigError(f"{key}={text!r}: expected true or false (also yes/no, on/off, 1/0)")


def _parse_number(key: str, text: str) -> Item:
    """A TOML number item; the operator's spelling (``2e5``) is kept when it is valid TOML."""
    try:
        value = tomlkit.parse(f"v = {text.strip()}")["v"]
    except Exception:
        value = None
    if isinstance(value, int | float) and not isinstance(value, bool) and not math.isnan(value):
        return tomlkit.item(value)
    try:
        number = float(text)
    except ValueError:
        raise ConfigError(f"{key}={text!r}: expected a number") from None
    if math.isnan(number):
        raise ConfigError(f"{key}={text!r}: NaN is not allowed")
    return tomlkit.item(number)


@dataclass(frozen=True)
class Assignment:
    """One KEY=VALUE of ``channels set``: the TOML item to write and the value it must load as."""

    key: str
    item: Item
    expected: str | bool | float | tuple[str, ...]


def parse_assignment(pair: str) -> Assignment:
    key, sep, text = pair.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"{pair!r} is not KEY=VALUE")
    allowed = [*PLAIN_KEYS, OVERRIDE_KEY, *parameter_names()]
    shown = (*PLAIN_KEYS, OVERRIDE_KEY)
    check_keys([key], allowed, lambda _key, message: ConfigError(message), _UNKNOWN_KEY, shown=shown)
    if key == "name":
        return Assignment(key, tomlkit.item(text.strip()), text.strip())
    if key == "enabled":
        flag = _parse_bool(key, text)
        return Assignment(key, tomlkit.item(flag), flag)
    if key == "effects":
        names = [n.strip() for n in text.split(",") if n.strip()]
        try:
            canonical = parse_effects(names)
        except UnknownEffectError as exc:
            raise ConfigError(f"effects={text!r}: {exc}") from None
        array = tomlkit.array()
        array.extend(names)
        return Assignment(key, array, canonical)
    if key == OVERRIDE_KEY:
        names = [n.strip() for n in text.split(",") if n.strip()]
        array = tomlkit.array()
        array.extend(names)  # the parser checks the names against the entry's own keys
        return Assignment(key, array, tuple(names))
    item = _parse_number(key, text)
    return Assignment(key, item, float(item.unwrap()))


def _edit_document(
    document: tomlkit.TOMLDocument, target: ChannelTarget, assignments: Sequence[Assignment]
) -> None:
    """Apply the edits to the target's ``[[bus.device.channel]]`` entry, adding one if needed."""
    device: Any = document["bus"][target.bus_index]["device"][target.device_index]
    entries = device.get("channel")
    if entries is not None:
        for entry in entries:
            if entry.get("index") == target.channel.index:
                _apply(entry, assignments)
                return
    if isinstance(device, InlineTable) or isinstance(entries, Array):
        new_inline = tomlkit.inline_table()
        new_inline["index"] = target.channel.index
        _apply(new_inline, assignments)
        if entries is None:
            array = tomlkit.array()
            array.append(new_inline)
            device["channel"] = array
        else:
            entries.append(new_inline)
        return
    # A complete new table (the blank line after it last) appended as [[bus.device.channel]].
    table = tomlkit.table()
    table.add("index", target.channel.index)
    _apply(table, assignments)
    table.add(tomlkit.nl())
    if isinstance(entries, AoT):
        previous = entries[-1] if len(entries) else None
        if isinstance(previous, Table) and not previous.as_string().endswith("\n\n"):
            previous.add(tomlkit.nl())
        entries.append(table)
    else:
        aot = tomlkit.aot()
        aot.append(table)
        device.append("channel", aot)


def _inline(items: Sequence[tuple[str, str]]) -> InlineTable:
    body = ", ".join(f"{key} = {value}" for key, value in items)
    table = tomlkit.parse(f"v = {{ {body} }}\n" if body else "v = {}\n")["v"]
    assert isinstance(table, InlineTable)
    return table


def _set_param(entry: Any, key: str, value: Item) -> None:
    params = entry.get("params")
    if isinstance(params, Table):
        params[key] = value
        return
    if isinstance(params, InlineTable):
        # Rebuilt so that an added key gets the same "{ a = 1, b = 2 }" spacing; the values keep
        # their spelling and a comment after the table stays.
        items = [(k, value.as_string() if k == key else params[k].as_string()) for k in params]
        if key not in params:
            items.append((key, value.as_string()))
        entry["params"] = _inline(items)
        return
    _set_key(entry, "params", _inline([(key, value.as_string())]))


def _set_key(entry: Any, key: str, item: Item) -> None:
    """Set ``key``; a new key of a table goes after its last key, above the comments that end
    the table (often a commented-out example, which the new line would otherwise read as part
    of)."""
    body = entry.value.body if isinstance(entry, Table) else None
    if key in entry or not body:
        entry[key] = item
        return
    last = max((i for i, (k, _) in enumerate(body) if k is not None), default=None)
    if last is None or last == len(body) - 1:
        entry[key] = item
        return
    entry.value._insert_after(body[last][0], key, item)


def _apply(entry: Any, assignments: Sequence[Assignment]) -> None:
    for assignment in assignments:
        if assignment.key in PLAIN_KEYS or assignment.key == OVERRIDE_KEY:
            _set_key(entry, assignment.key, assignment.item)
        else:
            _set_param(entry, assignment.key, assignment.item)


def _took_effect(channel: ChannelConfig, assignment: Assignment) -> bool:
    """Whether the re-parsed channel shows the edit (a safety net against a misplaced edit)."""
    key = assignment.key
    if key == OVERRIDE_KEY:
        return True  # not part of the resolved channel; the parser checked it names the entry's keys
    actual = getattr(channel, key) if key in PLAIN_KEYS else getattr(channel.params, key)
    return bool(actual == assignment.expected)


@dataclass(frozen=True)
class EditResult:
    """What ``edit_channel`` did: the channel as the edited file now resolves it, and the
    assignments as written (``changed`` False when the file already said so)."""

    path: Path
    target: ChannelTarget
    channel: ChannelConfig
    changed: bool
    changes: str


def edit_channel(
    config_path: Path, name: str, device_name: str | None, assignments: Sequence[Assignment]
) -> EditResult:
    """Apply ``assignments`` to the channel called ``name`` in the file, keeping every comment
    and the layout, and write it atomically; or raise ``ConfigError`` and leave the file
    byte for byte as it was (unreadable or invalid file, unknown channel, an edit that would
    make the configuration invalid or would not take effect, a failed write)."""
    text = read_config_text(config_path)
    config = parse_config(text, source=config_path)
    target = find_channel(config, name, device_name)
    document = tomlkit.parse(text)
    _edit_document(document, target, assignments)
    new_text = _before_trailing_comments(tomlkit.dumps(document), target.channel.index)
    edited = parse_edited(config_path, new_text)
    channel = edited.buses[target.bus_index].devices[target.device_index].channels[target.channel.index]
    wrong = [a.key for a in assignments if not _took_effect(channel, a)]
    if wrong:
        raise ConfigError(
            f"refused, {config_path} is unchanged: the edit of {', '.join(wrong)} did not take effect"
        )
    changes = ", ".join(f"{a.key} = {a.item.as_string()}" for a in assignments)
    if new_text == text:
        return EditResult(config_path, target, channel, False, changes)
    write_config(config_path, new_text)
    return EditResult(config_path, target, channel, True, changes)


def parse_edited(config_path: Path, new_text: str) -> GatewayConfig:
    """The edited text as a configuration, or ``ConfigError`` saying the file is unchanged."""
    try:
        return parse_config(new_text, source=config_path)
    except ConfigError as exc:
        raise ConfigError(
            f"refused, {config_path} is unchanged: the edit would make the configuration invalid:\n{exc}"
        ) from None


def _before_trailing_comments(text: str, index: int) -> str:
    """A new ``[[bus.device.channel]]`` table goes where tomlkit puts it: after every comment
    that follows the device's last table, which in a file like the example is a commented-out
    template of another bus; uncommenting the template would then move the channel to that
    bus. So the new table is moved above a comment block that a blank line separates from
    what precedes it."""
    lines = text.split("\n")
    header = "[[bus.device.channel]]"
    starts = [i for i, line in enumerate(lines) if line.strip() == header]
    start = next(
        (i for i in reversed(starts) if i + 1 < len(lines) and lines[i + 1].strip() == f"index = {index}"),
        None,
    )
    if start is None:
        return text
    end = start + 1
    while end < len(lines) and lines[end].strip():
        end += 1
    k = start
    while k > 0 and (not lines[k - 1].strip() or lines[k - 1].lstrip().startswith("#")):
        k -= 1
    run = lines[k:start]
    first_comment = next((j for j, line in enumerate(run) if line.lstrip().startswith("#")), None)
    if first_comment is None or first_comment == 0:
        return text  # no comments, or comments that hang on to the table above
    block = [*lines[start:end], ""]
    moved = [*lines[:k], *run[:first_comment], *block, *run[first_comment:], *lines[end + 1 :]]
    return "\n".join(moved)


def write_config(config_path: Path, new_text: str) -> None:
    """Replace the configuration file with ``new_text`` atomically (``ConfigError`` for a
    read-only file or a failed write, the file unchanged)."""
    try:
        mode = config_path.stat().st_mode
    except OSError:
        mode = stat.S_IWUSR
    if not mode & stat.S_IWUSR:
        raise ConfigError(
            f"{config_path} is read-only (mode {stat.S_IMODE(mode):04o}); refusing to replace it: "
            f"make it writable (chmod u+w) to edit it; the file is unchanged"
        )
    try:
        atomic_write_text(config_path, new_text)
    except OSError as exc:
        raise ConfigError(
            f"{config_path}: cannot write: {exc.strerror or exc}; the file is unchanged"
        ) from None


def read_config_text(path: Path) -> str:
    """The text of a configuration file (``ConfigError`` if unreadable, not a regular file,
    too large or not UTF-8)."""
    return read_text_file(path, "configuration file")


def flag_assignment(enabled: bool) -> Assignment:
    """``enabled = true`` / ``false``."""
    return Assignment("enabled", tomlkit.item(enabled), enabled)


def _number_array(values: Sequence[float | None], per_line: int) -> Array:
    """A TOML array of numbers, ``per_line`` to a line (one grid row), integers as integers;
    None as ``"none"`` (a channel without a baseline)."""
    shown = []
    for v in values:
        if v is None:
            shown.append(f'"{NO_BASELINE}"')
        elif math.isinf(v):
            shown.append("inf")
        elif float(v).is_integer():
            shown.append(str(int(v)))
        else:
            shown.append(repr(float(v)))
    width = max(len(s) for s in shown)
    rows = [
        "    " + ", ".join(s.rjust(width) for s in shown[i : i + per_line]) + ","
        for i in range(0, len(shown), per_line)
    ]
    array = tomlkit.parse("v = [\n" + "\n".join(rows) + "\n]\n")["v"]
    assert isinstance(array, Array)
    return array


def set_device_array(
    config_path: Path,
    device_name: str,
    key: str,
    values: Sequence[float | None],
    replaces: Sequence[str] = (),
    comment: str | None = None,
) -> DeviceConfig:
    """Set the device-table key ``key`` of device ``device_name`` to the array ``values``
    (one grid row per line; the keys in ``replaces`` are removed), keeping every comment and
    the layout; validate and write atomically. Returns the device as the edited file resolves
    it; ``ConfigError`` leaves the file byte for byte as it was."""
    text = read_config_text(config_path)
    config = parse_config(text, source=config_path)
    ((b, d, _, device),) = find_devices(config, device_name)
    document = tomlkit.parse(text)
    table: Any = document["bus"][b]["device"][d]
    for old in replaces:
        if old in table:
            del table[old]
    array = _number_array(values, max(1, device.columns))
    if comment is not None:
        array.comment(comment)
    if key in table or isinstance(table, InlineTable):
        table[key] = array
    else:
        table.add(key, array)  # tomlkit puts a plain key before the device's sub-tables
    new_text = tomlkit.dumps(document)
    edited = parse_edited(config_path, new_text)
    write_config(config_path, new_text)
    return edited.buses[b].devices[d]
