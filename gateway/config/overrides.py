"""A calibrated channel's values against the configuration's own: contradictions and overrides.

A channel with a ``[channel.<name>]`` table in its device's calibration file is read with what
the calibration was fitted with: the table's sensor parameters and the file's ``[meta]
effects`` (a file without them: the device's effects; a line, lookup or curve channel keeps
its entry's own ``effects``, which take no part in it). A configuration key that gives the
same channel another value contradicts the calibration:

* a parameter of the channel entry's ``params`` (``bus[0].device[0].channel[0].params.r0_ohm``)
  or of ``[bus.device.model.params]`` that the calibration sets to another value;
* the channel entry's ``effects`` or ``[bus.device.model] effects``, when they differ from the
  calibration's effects (only on a channel the physical model reads: a line, lookup or curve
  takes no effects).

Each is a ``Contradiction``; one the configuration does not say it means is a
``CalibrationConflictError`` (a ``ConfigError``) that names both values. A configuration says it
means one with ``override = ["r0_ohm", "effects"]`` in the channel's entry (its own ``params``
key or ``effects`` win) or ``override_calibration = [...]`` in ``[bus.device.model]`` (the
device's win on every calibrated channel that does not set the key itself); then the config's
value is read, and ``check-config`` lists it. A key the channel sets itself is the channel's,
not the device's: the device's value takes no part in that channel.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from ..errors import ConfigError
from ..keys import suggest
from ..model.params import parameter_names
from .tables import Context, join_key, show_value, type_name

__all__ = [
    "DEVICE_OVERRIDE_KEY",
    "EFFECTS",
    "OVERRIDE_KEY",
    "CalibrationConflictError",
    "ChannelValues",
    "Contradiction",
    "Resolved",
    "parse_override_list",
    "resolve_channel",
]

#: The key of a ``[[bus.device.channel]]`` entry that lists what it overrides.
OVERRIDE_KEY: Final = "override"
#: The key of ``[bus.device.model]`` that lists what the device's values override.
DEVICE_OVERRIDE_KEY: Final = "override_calibration"
#: The name of the effects list in an override list (the rest are sensor parameters).
EFFECTS: Final = "effects"
#: At most this many contradictions are listed in one message (then: "... and N more").
_SHOWN: Final = 12

Value = float | tuple[str, ...]


def show(value: Value) -> str:
    """A value as TOML writes it: a float exactly (``repr``), an effects list as an array."""
    if isinstance(value, tuple):
        return "[" + ", ".join(f'"{name}"' for name in value) + "]"
    return repr(float(value)) if math.isfinite(value) else ("inf" if value > 0 else "-inf")


@dataclass(frozen=True)
class Contradiction:
    """A configuration key (``where``, ``config_value``) that gives calibrated channel
    ``channel`` (index ``index``) another ``key`` (a sensor parameter or ``effects``) than its
    calibration ``calibration`` does (``calibrated_value``). ``level`` is ``channel`` (the
    channel's entry) or ``device`` (``[bus.device.model]``); ``overridden``: the configuration
    says its value wins (``override`` / ``override_calibration``), and it is the one read."""

    channel: str
    index: int
    key: str
    level: str
    where: str
    config_value: Value
    calibrated_value: Value
    calibration: Path
    overridden: bool

    @property
    def calibrated_where(self) -> str:
        """Where the calibration says it: its ``[channel.<name>]`` table or its ``[meta]``."""
        table = "[meta]" if self.key == EFFECTS else f"[{join_key('channel', self.channel)}]"
        return f"{self.calibration} {table} {self.key}"

    def describe(self) -> str:
        """One line: the channel, the config's value and where, the calibration's and where."""
        return (
            f"channel {self.channel}: {self.where} = {show(self.config_value)} in the config, "
            f"{show(self.calibrated_value)} in the calibration ({self.calibrated_where})"
        )


class CalibrationConflictError(ConfigError):
    """Configuration keys contradict a device's calibration (``contradictions``, none of them
    overridden); the message names every one with both values."""

    def __init__(self, message: str, contradictions: Sequence[Contradiction]) -> None:
        super().__init__(message)
        self.contradictions = tuple(contradictions)


def conflict_error(
    ctx: Context, device_path: str, found: Sequence[Contradiction]
) -> CalibrationConflictError:
    """The error for ``found`` (contradictions of one device that the config does not override)."""
    lines = [f"  {c.describe()}" for c in found[:_SHOWN]]
    if len(found) > _SHOWN:
        lines.append(f"  ... and {len(found) - _SHOWN} more")
    head = (
        f"{len(found)} key{'s' if len(found) != 1 else ''} of the config contradict"
        f"{'s' if len(found) == 1 else ''} the calibration (a calibrated channel is read with what "
        "the calibration was fitted with):"
    )
    ways = []
    for level, key, where in (
        ("channel", OVERRIDE_KEY, "the channel's [[bus.device.channel]] entry"),
        ("device", DEVICE_OVERRIDE_KEY, "[bus.device.model]"),
    ):
        keys = sorted({c.key for c in found if c.level == level})
        if keys:
            ways.append(f"{key} = {show(tuple(keys))} in {where}")
    hint = (
        "drop these keys (`tactile-gateway calibrate --out CAL.toml --install CONFIG --device NAME "
        f"--replace-overrides` drops them), or say that the config wins: {' and '.join(ways)} "
        "(docs/configuration.md)"
    )
    message = str(ctx.error(join_key(device_path, "calibration"), "\n".join([head, *lines, hint])))
    return CalibrationConflictError(message, found)


def parse_override_list(ctx: Context, path: str, value: object, own: Sequence[str]) -> frozenset[str]:
    """An override list at ``path``: an array of sensor parameter names and ``effects``, each a
    key its own table sets (``own``: those keys); ``ConfigError`` naming the entry otherwise."""
    allowed = (*parameter_names(), EFFECTS)
    if not isinstance(value, list):
        raise ctx.error(
            path,
            f"expected an array of sensor parameter names and/or {EFFECTS!r} (the keys whose "
            f"config value wins over the calibration's), got {type_name(value)} {show_value(value)}",
        )
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise ctx.error(
                f"{path}[{i}]",
                f"expected a parameter name or {EFFECTS!r}, got {type_name(item)} {show_value(item)}",
            )
        if item not in allowed:
            raise ctx.error(
                f"{path}[{i}]",
                f"{item!r} is not a sensor parameter or {EFFECTS!r}{suggest(item, allowed)}",
            )
        if item not in own:
            sets = ", ".join(own) if own else "none"
            raise ctx.error(
                f"{path}[{i}]",
                f"{item!r} is not set here, so there is nothing to override (set here: {sets}); "
                "an override names a key of the same table",
            )
    return frozenset(value)


@dataclass(frozen=True)
class ChannelValues:
    """What the configuration says of one channel, level by level: the device's parameters and
    effects (``device_effects_at`` None: the default, not a key of the config) with what they
    override, and the channel entry's (``channel_effects`` None: not given)."""

    device_params: Mapping[str, float]
    device_params_at: str
    device_effects: tuple[str, ...]
    device_effects_at: str | None
    device_override: frozenset[str]
    channel_params: Mapping[str, float]
    channel_params_at: str
    channel_effects: tuple[str, ...] | None
    channel_effects_at: str
    channel_override: frozenset[str]


@dataclass(frozen=True)
class Resolved:
    """A channel's parameters (before the check of the whole set) and effects, and every
    contradiction between the configuration and its calibration (overridden or not)."""

    params: dict[str, float]
    effects: tuple[str, ...]
    contradictions: tuple[Contradiction, ...]


def resolve_channel(
    name: str,
    index: int,
    config: ChannelValues,
    calibrated: Mapping[str, float] | None,
    calibrated_effects: tuple[str, ...] | None,
    calibration: Path,
    physics: bool,
) -> Resolved:
    """The parameters and effects channel ``name`` is read with. ``calibrated``: its
    ``[channel.<name>]`` table's parameters (None: no table, the config's values are read as
    they are); ``calibrated_effects``: the file's ``[meta] effects`` (None: not given);
    ``physics``: the physical model reads the channel (no line, lookup or curve)."""
    merged = dict(config.device_params)
    effects = config.device_effects if config.channel_effects is None else config.channel_effects
    if calibrated is None:
        merged.update(config.channel_params)
        return Resolved(merged, effects, ())
    found: list[Contradiction] = []

    def contradiction(key: str, level: str, where: str, ours: Value, theirs: Value, wins: bool) -> None:
        found.append(Contradiction(name, index, key, level, where, ours, theirs, calibration, wins))

    for key, value in calibrated.items():
        device_value = config.device_params.get(key)
        if key in config.channel_params or device_value is None or device_value == value:
            merged[key] = value
            continue
        wins = key in config.device_override
        where = join_key(config.device_params_at, key)
        contradiction(key, "device", where, device_value, value, wins)
        merged[key] = device_value if wins else value
    for key, value in config.channel_params.items():
        if key in calibrated and calibrated[key] != value:
            where = join_key(config.channel_params_at, key)
            contradiction(key, "channel", where, value, calibrated[key], key in config.channel_override)
        merged[key] = value

    if calibrated_effects is not None:
        ours: tuple[str, ...] | None = None
        if config.channel_effects is not None:
            ours, level, where = config.channel_effects, "channel", config.channel_effects_at
            wins = EFFECTS in config.channel_override
        elif config.device_effects_at is not None:
            ours, level, where = config.device_effects, "device", config.device_effects_at
            wins = EFFECTS in config.device_override
        effects = calibrated_effects
        if ours is not None and ours != calibrated_effects:
            if physics:
                contradiction(EFFECTS, level, where, ours, calibrated_effects, wins)
                effects = ours if wins else calibrated_effects
            elif level == "channel":
                effects = ours  # a line, lookup or curve takes no effects: the entry's stay as written
    return Resolved(merged, effects, tuple(found))
