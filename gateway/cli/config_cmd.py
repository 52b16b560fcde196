"""``tactile-gateway check-config`` and ``tactile-gateway channels ...``.

``check-config`` validates a configuration file and prints the read plan of every device.
``channels`` lists, shows and edits per-channel settings in place: the file is edited with
tomlkit (the operator's comments and layout stay), the edited text is validated with
``parse_config`` before anything is written, and the write is atomic. An edit that would make
the configuration invalid is refused and leaves the file untouched.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import click
import tomlkit
from tomlkit.items import AoT, Array, InlineTable, Item, Table

from ..atomic import atomic_write_text
from ..config import BusConfig, ChannelConfig, DeviceConfig, GatewayConfig, parse_config
from ..errors import ConfigError
from ..modbus.plan import MERGE_GAP, device_plan
from ..model import UnknownEffectError, parameter_names, parse_effects
from .common import config_option

__all__ = ["channels", "check_config"]

#: Exit status of an invalid configuration or a refused edit (as for click usage errors).
EXIT_INVALID = 2

_PLAIN_KEYS = ("name", "x_mm", "y_mm", "enabled", "effects")
_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")

F = TypeVar("F", bound=Callable[..., Any])


def _fail(message: str) -> NoReturn:
    click.echo(message, err=True)
    raise click.exceptions.Exit(EXIT_INVALID)


def _device_option(func: F) -> F:
    option = click.option(
        "--device",
        "device_name",
        default=None,
        metavar="NAME",
        help="the device (needed if the name is ambiguous)",
    )
    return option(func)


def _read(path: Path) -> str:
    try:
        return path.read_bytes().decode("utf-8")
    except OSError as exc:
        _fail(f"{path}: cannot read the configuration file: {exc.strerror or exc}")
    except UnicodeDecodeError as exc:
        _fail(f"{path}: not UTF-8 text (byte {exc.start}): TOML files are UTF-8")


def _load(path: Path) -> tuple[str, GatewayConfig]:
    text = _read(path)
    try:
        return text, parse_config(text, source=path)
    except ConfigError as exc:
        _fail(str(exc))


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


# ----------------------------------------------------------------------------------------------
# check-config


def _bus_line(bus: BusConfig) -> str:
    if bus.kind == "rtu":
        where = f"rtu {bus.serial_port} {bus.baudrate} {bus.bytesize}{bus.parity}{bus.stopbits}"
    else:
        where = f"{bus.kind} {bus.endpoint}"
    return (
        f"bus {bus.name}: {where}, poll every {bus.poll_interval_s:g} s, timeout {bus.timeout_s:g} s, "
        f"{bus.retries} retries, at most {bus.max_read_registers} registers per read"
    )


@click.command("check-config")
@config_option
def check_config(config_path: Path) -> None:
    """Validate a configuration file and print the read plan of every device.

    Exit status 0 if the file is valid; otherwise the reason goes to stderr and the exit
    status is 2.
    """
    _, config = _load(config_path)
    n_devices = sum(len(b.devices) for b in config.buses)
    n_channels = sum(d.n_channels for b in config.buses for d in b.devices)
    click.echo(
        f"{config_path}: OK ({_plural(len(config.buses), 'bus')}, {_plural(n_devices, 'device')}, "
        f"{_plural(n_channels, 'channel')})"
    )
    web = f", web config {config.metrics.web_config}" if config.metrics.web_config else ""
    host = config.metrics.host
    shown_host = f"[{host}]" if ":" in host else host
    click.echo(f"metrics: {shown_host}:{config.metrics.port}/metrics{web}")
    for bus in config.buses:
        click.echo(_bus_line(bus))
        for dev in bus.devices:
            plan = device_plan(dev, bus.max_read_registers, MERGE_GAP, clock=True)
            registers = sum(r.count for r in plan)
            enabled = len(dev.enabled_channels)
            click.echo(
                f"  device {dev.name} (id {dev.device_id}, {dev.encoding}, "
                f"{_plural(dev.n_channels, 'channel')}, {enabled} enabled): "
                f"{_plural(len(plan), 'request')}, {_plural(registers, 'register')} per poll"
            )
            for req in plan:
                click.echo(
                    f"    {req.kind} {req.address}..{req.end} ({_plural(req.count, 'register')}): "
                    f"{', '.join(req.purpose)}"
                )


# ----------------------------------------------------------------------------------------------
# channels: finding a channel


@dataclass(frozen=True)
class _Target:
    bus_index: int
    device_index: int
    bus: BusConfig
    device: DeviceConfig
    channel: ChannelConfig


def _devices(
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
        _fail(f"{config.source}: no device {device_name!r}{hint} (devices: {', '.join(names)})")
    return found


def _find(config: GatewayConfig, name: str, device_name: str | None) -> _Target:
    matches: list[_Target] = []
    for b, d, bus, dev in _devices(config, device_name):
        for ch in dev.channels:
            if ch.name == name:
                matches.append(_Target(b, d, bus, dev, ch))
    if len(matches) > 1:
        devices = ", ".join(t.device.name for t in matches)
        _fail(f"{config.source}: channel {name!r} exists in devices {devices}; choose one with --device NAME")
    if not matches:
        names = [ch.name for _, _, _, dev in _devices(config, device_name) for ch in dev.channels]
        close = difflib.get_close_matches(name, names, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        scope = f" of device {device_name!r}" if device_name else ""
        _fail(f"{config.source}: no channel {name!r}{scope}{hint} (see `tactile-gateway channels list`)")
    return matches[0]


class _Sources:
    """Where each parameter of a device's channels comes from: default, device, calibration, channel."""

    def __init__(self, text: str, bus_index: int, device_index: int, device: DeviceConfig) -> None:
        raw: dict[str, Any] = tomllib.loads(text)["bus"][bus_index]["device"][device_index]
        self.device_keys = list(raw.get("model", {}).get("params", {}))
        self.channel_keys: dict[int, list[str]] = {}
        for entry in raw.get("channel", []):
            self.channel_keys[entry["index"]] = list(entry.get("params", {}))
        self.calibration: dict[str, Any] = {}
        if device.calibration is not None:
            self.calibration = tomllib.loads(device.calibration.read_text(encoding="utf-8")).get(
                "channel", {}
            )

    def of(self, channel: ChannelConfig) -> dict[str, str]:
        sources = dict.fromkeys(parameter_names(), "default")
        sources.update(dict.fromkeys(self.device_keys, "device"))
        sources.update(dict.fromkeys(self.calibration.get(channel.name, {}), "calibration"))
        sources.update(dict.fromkeys(self.channel_keys.get(channel.index, []), "channel"))
        return sources


def _number(value: float) -> str:
    return f"{value:g}" if math.isfinite(value) else ("inf" if value > 0 else "-inf")


# ----------------------------------------------------------------------------------------------
# channels: list and show


@click.group("channels")
def channels() -> None:
    """List, show and edit the channels of a configuration file (edits keep comments)."""


@channels.command("list")
@config_option
@_device_option
def list_cmd(config_path: Path, device_name: str | None) -> None:
    """List the channels of every device (or of --device)."""
    text, config = _load(config_path)
    for b, d, bus, dev in _devices(config, device_name):
        click.echo(
            f"device {dev.name} (bus {bus.name}, id {dev.device_id}, {_plural(dev.n_channels, 'channel')}, "
            f"{dev.columns} columns, pitch {dev.pitch_mm:g} mm)"
        )
        click.echo(
            f"  {'index':>5}  {'name':<12} {'x_mm':>8} {'y_mm':>8}  "
            f"{'enabled':<7}  {'effects':<32}  overrides"
        )
        device_sources = _Sources(text, b, d, dev)
        for ch in dev.channels:
            sources = device_sources.of(ch)
            overrides = ", ".join(
                f"{k} (cal)" if s == "calibration" else k
                for k, s in sources.items()
                if s in ("channel", "calibration")
            )
            click.echo(
                f"  {ch.index:>5}  {ch.name:<12} {_number(ch.x_mm):>8} {_number(ch.y_mm):>8}  "
                f"{'yes' if ch.enabled else 'no':<7}  {','.join(ch.effects):<32}  {overrides or '-'}"
            )


@channels.command("show")
@click.argument("name")
@config_option
@_device_option
def show_cmd(name: str, config_path: Path, device_name: str | None) -> None:
    """Show one channel with its resolved parameters and where each comes from."""
    text, config = _load(config_path)
    target = _find(config, name, device_name)
    ch = target.channel
    click.echo(
        f"channel {ch.name} (index {ch.index}) of device {target.device.name} on bus {target.bus.name}"
    )
    click.echo(f"  x_mm = {_number(ch.x_mm)}")
    click.echo(f"  y_mm = {_number(ch.y_mm)}")
    click.echo(f"  enabled = {'true' if ch.enabled else 'false'}")
    click.echo(f"  effects = {', '.join(ch.effects)}")
    click.echo("  parameters (source: default | device = [bus.device.model.params] | calibration | channel):")
    sources = _Sources(text, target.bus_index, target.device_index, target.device).of(ch)
    for key in parameter_names():
        click.echo(f"    {key:<26} = {_number(getattr(ch.params, key)):<12} ({sources[key]})")


# ----------------------------------------------------------------------------------------------
# channels: editing


def _parse_bool(key: str, text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in _TRUE:
        return True
    if lowered in _FALSE:
        return False
    raise click.BadParameter(f"{key}={text!r}: expected true or false (also yes/no, on/off, 1/0)")


def _parse_number(key: str, text: str) -> Item:
    """A TOML number item; the operator's spelling (``2e5``) is kept when it is valid TOML."""
    try:
        value = tomlkit.parse(f"v = {text.strip()}")["v"]
    except Exception:
        value = None
    if isinstance(value, int | float) and not isinstance(value, bool):
        return tomlkit.item(value)
    try:
        number = float(text)
    except ValueError:
        raise click.BadParameter(f"{key}={text!r}: expected a number") from None
    if math.isnan(number):
        raise click.BadParameter(f"{key}={text!r}: NaN is not allowed")
    return tomlkit.item(number)


@dataclass(frozen=True)
class _Assignment:
    """One KEY=VALUE of ``channels set``: the TOML item to write and the value it must load as."""

    key: str
    item: Item
    expected: str | bool | float | tuple[str, ...]


def _parse_assignment(pair: str) -> _Assignment:
    key, sep, text = pair.partition("=")
    key = key.strip()
    if not sep or not key:
        raise click.BadParameter(f"{pair!r} is not KEY=VALUE")
    allowed = [*_PLAIN_KEYS, *parameter_names()]
    if key not in allowed:
        close = difflib.get_close_matches(key, allowed, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise click.BadParameter(
            f"unknown key {key!r}{hint} "
            f"(allowed: {', '.join(_PLAIN_KEYS)}, or a sensor parameter such as r0_ohm)"
        )
    if key == "name":
        return _Assignment(key, tomlkit.item(text.strip()), text.strip())
    if key == "enabled":
        flag = _parse_bool(key, text)
        return _Assignment(key, tomlkit.item(flag), flag)
    if key == "effects":
        names = [n.strip() for n in text.split(",") if n.strip()]
        try:
            canonical = parse_effects(names)
        except UnknownEffectError as exc:
            raise click.BadParameter(f"effects={text!r}: {exc}") from None
        array = tomlkit.array()
        array.extend(names)
        return _Assignment(key, array, canonical)
    item = _parse_number(key, text)
    return _Assignment(key, item, float(item.unwrap()))


def _edit_document(
    document: tomlkit.TOMLDocument, target: _Target, assignments: Sequence[_Assignment]
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
    entry["params"] = _inline([(key, value.as_string())])


def _apply(entry: Any, assignments: Sequence[_Assignment]) -> None:
    for assignment in assignments:
        if assignment.key in _PLAIN_KEYS:
            entry[assignment.key] = assignment.item
        else:
            _set_param(entry, assignment.key, assignment.item)


def _took_effect(channel: ChannelConfig, assignment: _Assignment) -> bool:
    """Whether the re-parsed channel shows the edit (a safety net against a misplaced edit)."""
    key = assignment.key
    actual = getattr(channel, key) if key in _PLAIN_KEYS else getattr(channel.params, key)
    return bool(actual == assignment.expected)


def _edit(config_path: Path, name: str, device_name: str | None, assignments: Sequence[_Assignment]) -> None:
    text, config = _load(config_path)
    target = _find(config, name, device_name)
    document = tomlkit.parse(text)
    _edit_document(document, target, assignments)
    new_text = tomlkit.dumps(document)
    try:
        edited = parse_config(new_text, source=config_path)
    except ConfigError as exc:
        _fail(f"refused, {config_path} is unchanged: the edit would make the configuration invalid:\n{exc}")
    channel = edited.buses[target.bus_index].devices[target.device_index].channels[target.channel.index]
    wrong = [a.key for a in assignments if not _took_effect(channel, a)]
    if wrong:
        _fail(f"refused, {config_path} is unchanged: the edit of {', '.join(wrong)} did not take effect")
    if new_text == text:
        click.echo(f"{config_path}: channel {channel.name} of device {target.device.name}: unchanged")
        return
    try:
        atomic_write_text(config_path, new_text)
    except OSError as exc:
        _fail(f"{config_path}: cannot write: {exc.strerror or exc}; the file is unchanged")
    changes = ", ".join(f"{a.key} = {a.item.as_string()}" for a in assignments)
    click.echo(
        f"{config_path}: channel {channel.name} (index {channel.index}) "
        f"of device {target.device.name}: {changes}"
    )


@channels.command("set")
@click.argument("name")
@click.argument("assignments", nargs=-1, required=True, metavar="KEY=VALUE...")
@config_option
@_device_option
def set_cmd(name: str, assignments: tuple[str, ...], config_path: Path, device_name: str | None) -> None:
    """Set channel settings: name, x_mm, y_mm, enabled, effects (comma list), or a sensor parameter.

    Sensor parameters (e.g. r0_ohm=190000) go into the channel's params table. The file is
    rewritten only if the result is a valid configuration.
    """
    parsed = [_parse_assignment(pair) for pair in assignments]
    _edit(config_path, name, device_name, parsed)


@channels.command("enable")
@click.argument("name")
@config_option
@_device_option
def enable_cmd(name: str, config_path: Path, device_name: str | None) -> None:
    """Enable a channel (enabled = true)."""
    _edit(config_path, name, device_name, [_Assignment("enabled", tomlkit.item(True), True)])


@channels.command("disable")
@click.argument("name")
@config_option
@_device_option
def disable_cmd(name: str, config_path: Path, device_name: str | None) -> None:
    """Disable a channel (enabled = false): it is not converted or exported."""
    _edit(config_path, name, device_name, [_Assignment("enabled", tomlkit.item(False), False)])
