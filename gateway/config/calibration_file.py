"""The calibration file for the rest of the gateway: read it, recognise it, read a record with it.

The file's format (``CalibrationFile``, its ``to_toml``, the checks of every table) is
``calibration_format``'s; ``load_calibration`` here reads a file with the configuration's own
check of sensor parameters (``device``'s), as ``[[bus.device]] calibration = "..."`` does, and
``check_calibration_file`` says whether a file is one (``calibrate --out`` replaces nothing
else).

``tactile-gateway apply`` replays a record through the runtime with a calibration file and no
gateway configuration. It needs the channels the file configures and a device whose channels
get their parameters, effects (``[meta] effects``), unloaded baselines and line or lookup tables
from the file; both come from the functions ``[[bus.device]] calibration = "..."`` goes through
(``load_calibration``, ``device.parse_device``), nothing here reads a value itself.

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
from .calibration_format import (
    CALIBRATED_RANGE_KEYS,
    CALIBRATION_TABLES,
    END,
    CalibrationFile,
    ChannelCalibration,
    ConversionTable,
    read_calibration,
    read_toml,
    replace_table,
    set_table_values,
)
from .device import _parse_param_overrides, parse_device
from .schema import MAX_CHANNELS, DeviceConfig
from .tables import _NAME_RE, _NAME_RULE, Context

__all__ = [
    "CALIBRATED_DEVICE_CLOCK_TICK_S",
    "CALIBRATED_RANGE_KEYS",
    "CALIBRATION_TABLES",
    "END",
    "CalibrationFile",
    "ChannelCalibration",
    "ConversionTable",
    "calibrated_device",
    "calibration_channels",
    "calibration_effects",
    "check_calibration_file",
    "load_calibration",
    "replace_table",
    "set_table_values",
]

#: The tick of ``calibrated_device``'s clock: a nanosecond counter (64 bit, so no wrap).
CALIBRATED_DEVICE_CLOCK_TICK_S: Final = 1e-9
#: Where ``calibrated_device`` says its blocks are (only the layout's checks read them).
_CLOCK_ADDRESS, _STATUS_ADDRESS, _FLOAT_ADDRESS = 2, 16, 100
#: The key the calibration file is named at in ``parse_device``'s messages (a device table at
#: the root: its ``calibration`` key).
_KEY = "calibration"


def load_calibration(
    path: Path, channel_names: Sequence[str] | None = None, *, named_at: tuple[Context, str] | None = None
) -> CalibrationFile:
    """The calibration file at ``path``, read and checked as the gateway reads a device's
    ``calibration`` (``calibration_format.read_calibration`` with the configuration's check of
    sensor parameters): every table must name one of ``channel_names`` (None: any name).
    ``ConfigError`` names the file and the key path (and, with ``named_at``, what named it)."""
    return read_calibration(path, channel_names, _parse_param_overrides, named_at=named_at)


def check_calibration_file(path: Path) -> CalibrationFile:
    """The calibration file at ``path`` if it is one: TOML with at least one table, every
    top-level table a calibration file's (``CALIBRATION_TABLES``: a gateway configuration is
    not one), read by ``load_calibration``; ``ConfigError`` saying why not otherwise."""
    data = read_toml(path)
    if not data:
        raise ConfigError(f"{path}: an empty TOML file")
    others = [key for key in data if key not in CALIBRATION_TABLES]
    if others:
        raise ConfigError(
            f"{path}: {', '.join(others)}: not a table of a calibration file "
            f"(those are {', '.join(CALIBRATION_TABLES)})"
        )
    return read_calibration(path, None, _parse_param_overrides, data=data)


def _absolute(file: Path) -> Path:
    """The path as the gateway resolves a device's ``calibration`` (absolute, not resolved)."""
    return Path(os.path.abspath(file))


def _note(file: Path) -> str:
    """What ``load_calibration`` and ``parse_device`` append to a calibration file's message:
    the device configuration that named it, of which there is none here."""
    return f" (calibration file of {_KEY} in {file})"


def _device(
    file: Path, listed: Sequence[str], enabled: Collection[str], name: str, effects: Sequence[str] | None
) -> DeviceConfig:
    """The ``[[bus.device]]`` table naming ``file``, through ``parse_device``; with ``effects``
    its ``[bus.device.model] effects`` (None: the default, so that a calibrated channel takes
    the calibration's, as in a device that names none)."""
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
        **({} if effects is None else {"model": {"effects": list(effects)}}),
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
    names = load_calibration(file).channel_names()  # the tables' own checks
    if names:  # then what parse_device checks of them (lines, merged ranges)
        _device(file, list(names), set(names), "calibration", None)
    return names


def calibration_effects(file: Path) -> tuple[str, ...] | None:
    """The effects the calibration was fitted with (``[meta] effects``, written by
    ``calibrate``), or None when the file does not say. The gateway reads a calibrated channel
    (one with a ``[channel.<name>]`` table, read by the physical model) with them; a file
    without them leaves the device's effects (``[bus.device.model] effects``)."""
    return load_calibration(_absolute(file)).effects


def calibrated_device(
    file: Path,
    channels: Sequence[str],
    *,
    others: Collection[str] = (),
    name: str = "record",
    effects: Sequence[str] | None = None,
) -> DeviceConfig:
    """A float32 (ohm) device whose enabled channels are ``channels`` (in this order, indices
    0, 1, ...), read with calibration ``file`` exactly as a ``[[bus.device]]`` that names it:
    each channel's parameters are the defaults merged with its ``[channel.<name>]`` table, its
    effects the file's ``[meta] effects`` (a file without them, and a channel without a table:
    ``effects``, default the paper's), its baseline the table's ``baseline_ohm``, its
    conversion its ``[line]`` / ``[lookup]`` table. ``effects`` that differ from the file's are
    the device's ``[bus.device.model] effects`` contradicting it: ``ConfigError``.

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
