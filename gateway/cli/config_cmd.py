"""``tactile-gateway check-config`` and ``tactile-gateway channels ...``.

``check-config`` validates a configuration file and prints the read plan of every device.
``channels`` lists, shows and edits per-channel settings in place, through the
comment-keeping editor of ``gateway.config.editor`` (an edit that would make the
configuration invalid is refused and leaves the file untouched).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import click

from ..config import BusConfig, BusKind, DeviceConfig, Encoding, GatewayConfig, SerialClient, parse_config
from ..config.device import device_overrides
from ..config.editor import (
    Assignment,
    ChannelTarget,
    ParameterSources,
    edit_channel,
    find_channel,
    find_devices,
    flag_assignment,
    parse_assignment,
    read_config_text,
)
from ..config.mqtt import MqttConfig
from ..config.overrides import DEVICE_OVERRIDE_KEY, OVERRIDE_KEY, Contradiction, show
from ..config.tables import Context
from ..errors import ConfigError
from ..metrics.web_config import load_web_config
from ..modbus.plan import MERGE_GAP, device_plan
from ..model import RatioFrontEnd, parameter_names
from ..runtime.summary import device_summary
from .common import config_option

__all__ = ["channels", "check_config"]

#: Exit status of an invalid configuration or a refused edit (as for click usage errors).
EXIT_INVALID = 2


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


def _load(path: Path) -> tuple[str, GatewayConfig]:
    try:
        text = read_config_text(path)
        return text, parse_config(text, source=path)
    except ConfigError as exc:
        _fail(str(exc))


def _plural(n: int, word: str) -> str:
    if n == 1:
        return f"{n} {word}"
    return f"{n} {word}es" if word.endswith(("s", "x")) else f"{n} {word}s"


def _grid(dev: DeviceConfig) -> list[str]:
    """The channels drawn where the gateway places them: channel indices by drawn row (row 0
    at the top), '.' where no channel sits; only for grids up to 32 columns."""
    layout = dev.layout
    if layout.columns > 32:
        return [f"    ({layout.columns} columns: too wide to draw)"]
    cells: dict[tuple[int, int], str] = {}
    off: list[str] = []
    for ch in dev.channels:
        col = round(ch.x_mm / layout.pitch_x_mm)
        row = round(ch.y_mm / layout.pitch_y_mm)
        exact = math.isclose(col * layout.pitch_x_mm, ch.x_mm, abs_tol=1e-6) and math.isclose(
            row * layout.pitch_y_mm, ch.y_mm, abs_tol=1e-6
        )
        if exact and 0 <= row < layout.rows and 0 <= col < layout.columns and (row, col) not in cells:
            cells[(row, col)] = str(ch.index) if ch.enabled else f"({ch.index})"
        else:
            off.append(
                f"    channel {ch.index} ({ch.name}) at x = {ch.x_mm:g} mm, y = {ch.y_mm:g} mm: off the grid"
            )
    width = max([len(v) for v in cells.values()] + [1])
    lines = [
        "    " + " ".join(cells.get((row, col), ".").rjust(width) for col in range(layout.columns))
        for row in range(layout.rows)
    ]
    return lines + off


def _device_lines(dev: DeviceConfig) -> list[str]:
    """What the gateway will assume of a device: where its settings come from, the clock, the
    checks at connect, the read-out circuit, the zero baselines and the layout."""
    out = [f"    {line}" for line in device_summary(dev)]
    if dev.profile:
        out.append(f"    map, front end and layout from {dev.profile}, with the device table's overrides")
    clock = dev.registers.clock
    if clock is None:
        out.append("    clock: the host's monotonic clock (the map names no device clock)")
    else:
        bits = 16 * clock.registers
        out.append(
            f"    clock: {clock.table} {clock.address}..{clock.address + clock.registers - 1}, "
            f"{bits}-bit counter of {clock.unit}; the host clock takes over if it stalls or goes back"
        )
    for check in dev.checks.registers:
        out.append(
            f"    check at connect: {check.what} = {check.value} (0x{check.value:04X}) "
            f"in {check.table} register {check.address}"
        )
    for key, value in dev.checks.identification:
        out.append(f"    check at connect: identification {key} = {value!r} (FC 43/14)")
    if dev.encoding is Encoding.ADC:
        out.append(f"    front end: {dev.front_end.describe()}")
    out.append(
        f"    calibration: {dev.calibration}"
        if dev.calibration is not None
        else "    calibration: none (the parameters of this file and the defaults)"
    )
    tared = [ch for ch in dev.channels if ch.baseline_ohm is not None]
    device_zero = any(name == "zero" for name, _ in dev.registers.actions)
    if dev.encoding is Encoding.OUTPUT:
        out.append(
            "    zero: the device's own"
            + (" (`tare --device-zero` runs its zero action)" if device_zero else "")
        )
    elif tared:
        values = [ch.baseline_ohm for ch in tared if ch.baseline_ohm is not None]
        unit = "R_ref" if dev.encoding is Encoding.ADC and isinstance(dev.front_end, RatioFrontEnd) else "ohm"
        out.append(
            f"    zero: {len(tared)} channel(s) with an unloaded baseline, "
            f"{min(values):.4g}..{max(values):.4g} {unit} (read at the baseline: 0 N, no contact)"
        )
    else:
        if not device_zero:
            hint = "see `tare`"
        elif dev.encoding is Encoding.ADC:
            # a device-zeroed point reads 0 counts, which the divider takes for an open sensor
            hint = "see `tare`; not `tare --device-zero`: a zeroed point reads 0 counts, taken for open"
        else:
            hint = "see `tare`, or `tare --device-zero` for the device's own"
        out.append(f"    zero: no baselines (an unloaded channel must read the model's own R(0 N); {hint})")
    if dev.regions:
        out.append("    layout: by region (below); each channel where its region is drawn, in mm")
        return out
    out.append(f"    layout: {dev.layout.describe()}; channel indices as drawn:")
    out.extend(_grid(dev))
    return out


def _region_lines(dev: DeviceConfig, requests: int) -> list[str]:
    """A device made of regions: how many requests a frame takes, and each region."""
    if not dev.regions:
        return []
    out = [f"    {_plural(len(dev.regions), 'region')}, a frame takes {_plural(requests, 'request')}:"]
    out.extend(f"      {region.describe()}" for region in dev.regions)
    if dev.dead_after_s > 0.0:
        out.append(
            f"    dead taxels: one frozen for {dev.dead_after_s:g} s while its region moves reads error "
            f"(`poll-once --for {2 * dev.dead_after_s:g}` lists them by region)"
        )
    return out


def _readout_lines(dev: DeviceConfig) -> list[str]:
    """What the rails mean, the status words read with every poll, and the regions of interest
    whose sums every frame carries."""
    out = []
    if dev.rails == "readings":
        out.append(
            "    rails: readings (the open rail is no current at rest: no contact, 0 N; the short rail "
            "reads saturated)"
        )
    for word in dev.status_words:
        parts = [f"{len(word.bits)} bits"] if word.bits else []
        parts += [f"{len(word.errors)} error bits"] if word.errors else []
        parts += [f"{len(word.codes)} codes"] if word.codes else []
        meaning = ", ".join(parts) if parts else "its value"
        out.append(f"    status word {word.name}: {word.table} {word.address} ({meaning})")
    names = {ch.index: ch.name for ch in dev.channels}  # every index a region may name
    for roi in dev.rois:
        first, last = names[roi.channels[0]], names[roi.channels[-1]]
        span = first if first == last else f"{first} .. {last}"
        out.append(f"    region of interest {roi.name}: {_plural(len(roi.channels), 'channel')} ({span})")
    return out


# ----------------------------------------------------------------------------------------------
# check-config


def _bus_line(bus: BusConfig) -> str:
    if bus.kind is BusKind.RTU:
        framing = "the gateway's own RTU framing" if bus.serial_client is SerialClient.DIRECT else "pymodbus"
        where = f"rtu {bus.serial_port} {bus.baudrate} {bus.bytesize}{bus.parity}{bus.stopbits} ({framing})"
    else:
        where = f"{bus.kind} {bus.endpoint}"
    every = "poll back to back" if bus.poll_interval_s == 0 else f"poll every {bus.poll_interval_s:g} s"
    return (
        f"bus {bus.name}: {where}, {every}, timeout {bus.timeout_s:g} s, "
        f"{bus.retries} retries, at most {bus.max_read_registers} registers per read"
    )


def _host_port(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _mqtt_line(mqtt: MqttConfig | None) -> str:
    """Where frames are published, without the credentials (not the user name, not the
    password file)."""
    if mqtt is None:
        return "mqtt: off (no [mqtt] section)"
    tls = ""
    if mqtt.tls is not None:
        tls = " over TLS" + ("" if mqtt.tls.verify else " (certificate not verified)")
    login = (
        ", with a user name and password"
        if mqtt.password_file
        else (", with a user name" if mqtt.username else "")
    )
    rate = "every poll" if mqtt.max_rate_hz == 0 else f"at most {mqtt.max_rate_hz:g} frames/s per device"
    return (
        f"mqtt: {_host_port(mqtt.host, mqtt.port)}{tls}, MQTT {mqtt.protocol}, client id {mqtt.client_id}"
        f"{login}; {mqtt.encoding} frames ({rate}, qos {mqtt.qos}) on {mqtt.topic('<device>', 'frame')}, "
        f"status on {mqtt.topic('status')}"
    )


def _overrides(text: str, config_path: Path, b: int, d: int) -> tuple[Contradiction, ...]:
    """The keys of device ``d`` of bus ``b`` that override its calibration, as the file says."""
    device = tomllib.loads(text.removeprefix("\ufeff"))["bus"][b]["device"][d]
    return device_overrides(Context(config_path), f"bus[{b}].device[{d}]", device)


def _override_lines(found: Sequence[Contradiction]) -> list[str]:
    """``check-config``'s list of a calibrated device's overrides: channel, key, both values."""
    if not found:
        return [
            "    calibration overrides: none (every calibrated channel is read with the calibration's values)"
        ]
    out = [
        f"    calibration overrides ({len(found)}; the config's value is read, as {OVERRIDE_KEY} / "
        f"{DEVICE_OVERRIDE_KEY} say):"
    ]
    for c in found:
        out.append(
            f"      {c.channel}: {c.key} = {show(c.config_value)} ({c.where}) over the calibrated "
            f"{show(c.calibrated_value)} ({c.calibrated_where})"
        )
    return out


@click.command("check-config")
@config_option
def check_config(config_path: Path) -> None:
    """Validate a configuration file and print the read plan of every device, and the keys
    that override a device's calibration.

    Exit status 0 if the file is valid; otherwise the reason goes to stderr and the exit
    status is 2.
    """
    text, config = _load(config_path)
    if config.metrics.web_config is not None:
        # what `run` loads, the same way (TLS key and certificate into an SSL context included)
        try:
            load_web_config(config.metrics.web_config)
        except ConfigError as exc:
            _fail(str(exc))
    n_devices = sum(len(b.devices) for b in config.buses)
    n_channels = sum(d.n_channels for b in config.buses for d in b.devices)
    click.echo(
        f"{config_path}: OK ({_plural(len(config.buses), 'bus')}, {_plural(n_devices, 'device')}, "
        f"{_plural(n_channels, 'channel')})"
    )
    web = f", web config {config.metrics.web_config}" if config.metrics.web_config else ""
    click.echo(f"metrics: {_host_port(config.metrics.host, config.metrics.port)}/metrics{web}")
    click.echo(_mqtt_line(config.mqtt))
    for b, bus in enumerate(config.buses):
        click.echo(_bus_line(bus))
        for d, dev in enumerate(bus.devices):
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
            for line in [*_region_lines(dev, len(plan)), *_readout_lines(dev), *_device_lines(dev)]:
                click.echo(line)
            if dev.calibration is not None:
                for line in _override_lines(_overrides(text, config_path, b, d)):
                    click.echo(line)


# ----------------------------------------------------------------------------------------------
# channels: finding a channel


def _find_devices(
    config: GatewayConfig, device_name: str | None
) -> list[tuple[int, int, BusConfig, DeviceConfig]]:
    try:
        return find_devices(config, device_name)
    except ConfigError as exc:
        _fail(str(exc))


def _find_channel(config: GatewayConfig, name: str, device_name: str | None) -> ChannelTarget:
    try:
        return find_channel(config, name, device_name)
    except ConfigError as exc:
        _fail(str(exc))


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
    for b, d, bus, dev in _find_devices(config, device_name):
        click.echo(
            f"device {dev.name} (bus {bus.name}, id {dev.device_id}, {_plural(dev.n_channels, 'channel')}, "
            f"{dev.columns} columns, pitch {dev.pitch_mm:g} mm)"
        )
        click.echo(
            f"  {'index':>5}  {'name':<12} {'x_mm':>8} {'y_mm':>8}  "
            f"{'enabled':<7}  {'effects':<32}  overrides"
        )
        device_sources = ParameterSources(text, b, d, dev)
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
    target = _find_channel(config, name, device_name)
    ch = target.channel
    click.echo(
        f"channel {ch.name} (index {ch.index}) of device {target.device.name} on bus {target.bus.name}"
    )
    click.echo(f"  x_mm = {_number(ch.x_mm)}")
    click.echo(f"  y_mm = {_number(ch.y_mm)}")
    click.echo(f"  enabled = {'true' if ch.enabled else 'false'}")
    click.echo(f"  effects = {', '.join(ch.effects)}")
    click.echo("  parameters (source: default | device = [bus.device.model.params] | calibration | channel):")
    sources = ParameterSources(text, target.bus_index, target.device_index, target.device).of(ch)
    for key in parameter_names():
        click.echo(f"    {key:<26} = {_number(getattr(ch.params, key)):<12} ({sources[key]})")


# ----------------------------------------------------------------------------------------------
# channels: editing


def _edit(config_path: Path, name: str, device_name: str | None, assignments: Sequence[Assignment]) -> None:
    try:
        result = edit_channel(config_path, name, device_name, assignments)
    except ConfigError as exc:
        _fail(str(exc))
    channel, device = result.channel, result.target.device
    if not result.changed:
        click.echo(f"{config_path}: channel {channel.name} of device {device.name}: unchanged")
        return
    where = f"channel {channel.name} (index {channel.index}) of device {device.name}"
    click.echo(f"{config_path}: {where}: {result.changes}")


@channels.command("set")
@click.argument("name")
@click.argument("assignments", nargs=-1, required=True, metavar="KEY=VALUE...")
@config_option
@_device_option
def set_cmd(name: str, assignments: tuple[str, ...], config_path: Path, device_name: str | None) -> None:
    """Set channel settings: name, x_mm, y_mm, enabled, effects (comma list), override (comma
    list), or a sensor parameter.

    Sensor parameters (e.g. r0_ohm=190000) go into the channel's params table. On a calibrated
    channel a value other than the calibration's is refused unless the entry overrides it
    (override=r0_ohm: the entry's list, replaced). The file is rewritten only if the result is
    a valid configuration.
    """
    try:
        parsed = [parse_assignment(pair) for pair in assignments]
    except ConfigError as exc:
        raise click.BadParameter(str(exc)) from None
    _edit(config_path, name, device_name, parsed)


@channels.command("enable")
@click.argument("name")
@config_option
@_device_option
def enable_cmd(name: str, config_path: Path, device_name: str | None) -> None:
    """Enable a channel (enabled = true)."""
    _edit(config_path, name, device_name, [flag_assignment(True)])


@channels.command("disable")
@click.argument("name")
@config_option
@_device_option
def disable_cmd(name: str, config_path: Path, device_name: str | None) -> None:
    """Disable a channel (enabled = false): it is not converted or exported."""
    _edit(config_path, name, device_name, [flag_assignment(False)])
