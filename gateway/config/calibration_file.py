"""A calibration file on its own, read exactly as the gateway reads a device's ``calibration``.

``tactile-gateway apply`` replays a record through the runtime with a calibration file and no
gateway configuration. It needs the channels the file configures and a device whose channels
get their parameters, unloaded baselines and line or lookup tables from the file; both come
from the functions ``[[bus.device]] calibration = "..."`` goes through
(``device._load_calibration``, ``device.parse_device``), nothing here reads a value itself.

The device (``calibrated_device``) reports float32 resistances (ohm) and fault bitmaps, and
names a 64-bit device clock, so that a caller can pass each sample's time as the device's
(``runtime.clock.time_step`` then steps by it).
"""

from __future__ import annotations

import os
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any, Final

from ..errors import ConfigError
from ..model.conversion import CONVERSION_KINDS
from ..model.effects import PAPER_EFFECTS
from .device import _load_calibration, parse_device
from .schema import MAX_CHANNELS, DeviceConfig
from .tables import _NAME_RE, _NAME_RULE, Context, parse_toml, read_text_file

__all__ = [
    "CALIBRATED_DEVICE_CLOCK_TICK_S",
    "calibrated_device",
    "calibration_channels",
    "calibration_effects",
]

#: The tick of ``calibrated_device``'s clock: a nanosecond counter (64 bit, so no wrap).
CALIBRATED_DEVICE_CLOCK_TICK_S: Final = 1e-9
#: Where ``calibrated_device`` says its blocks are (only the layout's checks read them).
_CLOCK_ADDRESS, _STATUS_ADDRESS, _FLOAT_ADDRESS = 2, 16, 100
#: The key the calibration file is named at in ``parse_device``'s messages (a device table at
#: the root: its ``calibration`` key).
_KEY = "calibration"


def _absolute(file: Path) -> Path:
    """The path as the gateway resolves a device's ``calibration`` (absolute, not resolved)."""
    return Path(os.path.abspath(file))


def _note(file: Path) -> str:
    """What ``_load_calibration`` and ``parse_device`` append to a calibration file's message:
    the device configuration that named it, of which there is none here."""
    return f" (calibration file of {_KEY} in {file})"


def _data(file: Path) -> dict[str, Any]:
    """The file's TOML (``ConfigError`` naming the file when it is missing or is not TOML)."""
    if not file.exists():
        raise ConfigError(f"{file}: no such file (calibration file)")
    if file.is_dir():
        raise ConfigError(f"{file}: is a directory, not a calibration file")
    return parse_toml(Context(file), read_text_file(file, "calibration file"), "calibration")


def _device(
    file: Path, listed: Sequence[str], enabled: Collection[str], name: str, effects: Sequence[str]
) -> DeviceConfig:
    """The ``[[bus.device]]`` table naming ``file``, through ``parse_device``."""
    if len(listed) > MAX_CHANNELS:
        raise ConfigError(f"{file}: {len(listed)} channels; a device has at most {MAX_CHANNELS}")
    for channel in listed:
        if not _NAME_RE.fullmatch(channel):
            raise ConfigError(
                f"{file}: channel {channel!r}: a device channel name is {_NAME_RULE}; "
                "the gateway cannot read this table"
            )
    table: dict[str, Any] = {
        "name": name,
        "device_id": 1,
        "encoding": "float32",
        "channels": len(listed),
        "registers": {"float_address": _FLOAT_ADDRESS, "status_address": _STATUS_ADDRESS},
        "clock": {"address": _CLOCK_ADDRESS, "registers": 4, "tick_s": CALIBRATED_DEVICE_CLOCK_TICK_S},
        "calibration": str(file),
        "model": {"effects": list(effects)},
        "channel": [{"index": i, "name": c, "enabled": c in enabled} for i, c in enumerate(listed)],
    }
    try:
        # a root-level table: messages name the calibration file and its [channel.<name>]
        return parse_device(Context(file), "", table)
    except ConfigError as exc:
        raise ConfigError(str(exc).removesuffix(_note(file))) from None


def calibration_channels(file: Path) -> tuple[str, ...]:
    """The channel names ``file`` has a table for (``[channel.<name>]``, ``[line.<name>]``,
    ``[lookup.<name>]``), in the order they first appear, after the gateway's own checks of
    every table (``ConfigError`` naming the file and key, as the gateway's)."""
    file = _absolute(file)
    data = _data(file)
    names: dict[str, None] = {}
    for kind in ("channel", *CONVERSION_KINDS):
        tables = data.get(kind, {})
        if isinstance(tables, dict):
            names.update(dict.fromkeys(tables))
    try:  # the tables' own checks, then what parse_device checks of them (lines, merged ranges)
        _load_calibration(Context(file), _KEY, file, list(names))
    except ConfigError as exc:
        raise ConfigError(str(exc).removesuffix(_note(file))) from None
    if names:
        _device(file, list(names), names, "calibration", PAPER_EFFECTS)
    return tuple(names)


def calibration_effects(file: Path) -> tuple[str, ...] | None:
    """The effects the calibration was fitted with (``[meta] effects``, written by
    ``calibrate``), or None when the file does not say. The gateway does not read them: a
    device's effects are its ``[bus.device.model] effects`` (default: the paper's)."""
    meta = _data(_absolute(file)).get("meta")
    effects = meta.get("effects") if isinstance(meta, dict) else None
    if isinstance(effects, list) and all(isinstance(e, str) for e in effects):
        return tuple(effects)
    return None


def calibrated_device(
    file: Path,
    channels: Sequence[str],
    *,
    others: Collection[str] = (),
    name: str = "record",
    effects: Sequence[str] = PAPER_EFFECTS,
) -> DeviceConfig:
    """A float32 (ohm) device whose enabled channels are ``channels`` (in this order, indices
    0, 1, ...), read with calibration ``file`` exactly as a ``[[bus.device]]`` that names it:
    each channel's parameters are the defaults merged with its ``[channel.<name>]`` table, its
    baseline the table's ``baseline_ohm``, its conversion its ``[line]`` / ``[lookup]`` table.

    ``others`` are further channels the file has tables for: they are in the device, disabled
    (the gateway refuses a calibration table that names no channel of the device). The device
    reports its fault bitmaps and names a 64-bit clock of ``CALIBRATED_DEVICE_CLOCK_TICK_S``.
    """
    file = _absolute(file)
    if not channels:
        raise ConfigError(f"{file}: no channel to read with this calibration")
    if len(set(channels)) != len(channels):
        raise ConfigError(f"{file}: a channel is named twice in {list(channels)}")
    listed = [*channels, *(c for c in others if c not in channels)]
    return _device(file, listed, set(channels), name, effects)
