"""``tactile-gateway action NAME``: run one of a device's named actions (``[bus.device.actions]``:
a device zero, its undo, a mode switch) once; nothing is written that the action does not name."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import NoReturn

import click

from ..config import BusConfig, DeviceConfig, load_config
from ..config.editor import find_devices
from ..errors import ConfigError, DeviceError
from ..runtime.actions import action_writes, run_action
from .common import config_option

__all__ = ["action_cmd", "run_device_action"]


def _fail(command: str, message: str, code: int = 2) -> NoReturn:
    click.echo(f"{command}: {message}", err=True)
    raise SystemExit(code)


def one_device(command: str, config_path: Path, device_name: str | None) -> tuple[BusConfig, DeviceConfig]:
    """The bus and device a command acts on: the one named, or the file's only device."""
    try:
        config = load_config(config_path)
        found = find_devices(config, device_name)
    except ConfigError as exc:
        _fail(command, str(exc))
    if len(found) > 1:
        names = ", ".join(dev.name for _, _, _, dev in found)
        _fail(command, f"{config_path} has several devices ({names}); choose one with --device NAME")
    _, _, bus, device = found[0]
    return bus, device


def run_device_action(command: str, bus: BusConfig, device: DeviceConfig, name: str) -> None:
    """Run the action and say what was written; exit 2 for an unknown action, 1 when the
    device cannot be reached or refuses a write."""
    try:
        action_writes(device, name)
    except ConfigError as exc:
        _fail(command, str(exc))
    try:
        writes = asyncio.run(run_action(bus, device, name))
    except DeviceError as exc:
        _fail(command, f"device {device.name}: action {name!r}: {exc}", 1)
    for w in writes:
        click.echo(f"device {device.name}: {w.describe()}: done")


@click.command("action")
@config_option
@click.option("--device", "device_name", default=None, help="The device (default: the only one).")
@click.argument("name")
def action_cmd(config_path: Path, device_name: str | None, name: str) -> None:
    """Run the device's action NAME (from [bus.device.actions]) once, e.g. ``zero``."""
    bus, device = one_device("action", config_path, device_name)
    run_device_action("action", bus, device, name)
