"""Installing a calibration file in a device's configuration (``calibrate --install``).

``install_calibration`` sets ``calibration = "CAL.toml"`` on one ``[[bus.device]]`` of a gateway
configuration (the path relative to the configuration's folder, as the gateway resolves it)
with the comment-keeping editor (``editor``): the edited text is validated with
``parse_config`` before it is written, and the write is atomic; a refusal leaves the file byte
for byte as it was.

Keys of the configuration that contradict the calibration (``overrides``: a channel's or the
device's parameter or effects that the calibration sets otherwise) make the install a
refusal that lists them, unless ``replace_overrides``: then they are dropped from the file. A
device-level key also sets the channels the calibration does not cover; it is dropped only if
that leaves every one of them as it was (its value is the default, or no such channel), and
the install is refused otherwise.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomlkit
from tomlkit.items import InlineTable

from ..errors import ConfigError
from ..model.params import parameter_names
from .calibration_file import load_calibration
from .calibration_format import CALIBRATION_TABLES, CalibrationFile
from .editor import find_devices, parse_edited, read_config_text, write_config
from .overrides import (
    DEVICE_OVERRIDE_KEY,
    EFFECTS,
    OVERRIDE_KEY,
    CalibrationConflictError,
    Contradiction,
    conflict_error,
    show,
)
from .parser import parse_config
from .schema import DeviceConfig
from .tables import Context

__all__ = ["Installed", "check_install_target", "install_calibration"]

_KEY = "calibration"
#: Rounds of dropping contradicting keys: a channel's key dropped uncovers at most the device's.
_ROUNDS = 3


@dataclass(frozen=True)
class Installed:
    """What ``install_calibration`` did: ``device`` of ``config`` now names ``calibration`` (as
    written, relative to the configuration), in place of ``previous`` (None: none); ``dropped``
    are the contradicting keys removed; ``changed`` False when the file already said so."""

    config: Path
    device: str
    calibration: str
    previous: str | None
    dropped: tuple[Contradiction, ...]
    changed: bool

    def lines(self) -> list[str]:
        """What ``calibrate --install`` prints."""
        if not self.changed:
            return [f'{self.config}: device {self.device}: calibration = "{self.calibration}" (unchanged)']
        was = "none" if self.previous is None else f'"{self.previous}"'
        out = [f'{self.config}: device {self.device}: calibration = "{self.calibration}" (was: {was})']
        seen: set[str] = set()
        for c in self.dropped:
            if c.where not in seen:
                seen.add(c.where)
                out.append(
                    f"{self.config}: dropped {c.where} = {show(c.config_value)} "
                    f"(channel {c.channel}: the calibration's is {show(c.calibrated_value)})"
                )
        return out


def _refused(config_path: Path, why: str) -> ConfigError:
    return ConfigError(f"refused, {config_path} is unchanged: {why}")


def _check_gateway_config(config_path: Path, text: str) -> None:
    """``ConfigError`` unless ``text`` is TOML with ``[[bus]]`` tables: a gateway configuration."""
    try:
        data = tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as exc:
        raise _refused(config_path, f"not a gateway configuration (not TOML: {exc})") from None
    if "bus" not in data:
        what = (
            "a calibration file"
            if data and all(key in CALIBRATION_TABLES for key in data)
            else "not a gateway configuration"
        )
        raise _refused(config_path, f"{what} (no [[bus]] table); --install names the gateway's configuration")


def check_install_target(config_path: Path, device_name: str | None) -> tuple[str, int, int, DeviceConfig]:
    """The configuration's text and the device a calibration would be installed in, as (text,
    bus index, device index, device): ``ConfigError`` if the file is not a valid gateway
    configuration or has no such device (``device_name`` None: its only device)."""
    text = read_config_text(config_path)
    _check_gateway_config(config_path, text)
    try:
        config = parse_config(text, source=config_path)
    except ConfigError as exc:
        raise _refused(config_path, f"it is not a valid gateway configuration:\n{exc}") from None
    found = find_devices(config, device_name)
    if len(found) != 1:
        names = ", ".join(dev.name for _, dev in config.devices())
        raise ConfigError(f"{config_path}: {len(found)} devices ({names}): choose one with --device NAME")
    ((b, d, _, device),) = found
    return text, b, d, device


def _relative(calibration: Path, config_path: Path) -> str:
    """The calibration's path as the configuration names it: relative to its folder."""
    folder = os.path.dirname(os.path.abspath(config_path))
    try:
        return Path(os.path.relpath(os.path.abspath(calibration), folder)).as_posix()
    except ValueError:  # another drive (Windows): no relative path
        return Path(os.path.abspath(calibration)).as_posix()


def _entry(device: Any, index: int) -> Any:
    for entry in device.get("channel", []):
        if entry.get("index") == index:
            return entry
    return None


def _drop(device: Any, found: Sequence[Contradiction], config_path: Path) -> None:
    """Remove the keys of ``found`` from the device table of the document (each once)."""
    done: set[str] = set()
    for c in found:
        if c.where in done:
            continue
        done.add(c.where)
        owner = _entry(device, c.index) if c.level == "channel" else device.get("model")
        container = owner if c.key == EFFECTS or owner is None else owner.get("params")
        if container is None or c.key not in container:
            raise ConfigError(
                f"{c.where} is not in {config_path} (it comes from the device's profile), so it cannot "
                f"be dropped: say that the config wins ({OVERRIDE_KEY} / {DEVICE_OVERRIDE_KEY}), or change "
                "the profile"
            )
        del container[c.key]
        if c.key != EFFECTS and not container and isinstance(container, InlineTable):
            del owner["params"]


def _drop_all(document: Any, b: int, d: int, config_path: Path) -> list[Contradiction]:
    """Drop every key of device ``d`` of bus ``b`` of the document that contradicts its
    calibration, round by round (a channel's key dropped can uncover the device's), and return
    them; ``ConfigError`` for a configuration invalid for another reason, and (a
    ``CalibrationConflictError`` of the keys found) for a key the file does not hold."""
    table = document["bus"][b]["device"][d]
    found: list[Contradiction] = []
    for _ in range(_ROUNDS):
        try:
            parse_config(tomlkit.dumps(document), source=config_path)
            return found
        except CalibrationConflictError as exc:
            found.extend(exc.contradictions)
            try:
                _drop(table, exc.contradictions, config_path)
            except ConfigError as why:
                raise CalibrationConflictError(str(why), found) from None
        except ConfigError as exc:
            raise _refused(
                config_path, f"with this calibration the configuration is invalid:\n{exc}"
            ) from None
    raise _refused(config_path, f"keys still contradict the calibration after {_ROUNDS} rounds of dropping")


def _uncalibrated(text: str, config_path: Path, b: int, d: int) -> DeviceConfig:
    """The device as ``text`` gives it without a calibration."""
    document = tomlkit.parse(text)
    table: Any = document["bus"][b]["device"][d]
    if _KEY in table:
        del table[_KEY]
    return parse_edited(config_path, tomlkit.dumps(document)).buses[b].devices[d]


def _check_others(before: str, after: str, config_path: Path, b: int, d: int, cal: CalibrationFile) -> None:
    """Refuse if dropping the keys changes what the calibration does not set: a parameter of a
    channel its ``[channel.<name>]`` table does not give, the effects of a channel it has no
    table for (or of every channel, when it names no effects)."""
    old, new = _uncalibrated(before, config_path, b, d), _uncalibrated(after, config_path, b, d)
    for was, now in zip(old.channels, new.channels, strict=True):
        table = cal.channels.get(was.name)
        calibrated = set() if table is None else set(table.params)
        changed = [
            key
            for key in parameter_names()
            if key not in calibrated and getattr(was.params, key) != getattr(now.params, key)
        ]
        if was.effects != now.effects and (table is None or cal.effects is None):
            changed.append(EFFECTS)
        if changed:
            raise _refused(
                config_path,
                f"dropping the device's {', '.join(changed)} would change channel {was.name}, for which "
                "the calibration does not set it: move the device's value to the entries of the channels "
                f"it is for, or say that it wins over the calibration ({DEVICE_OVERRIDE_KEY} in "
                "[bus.device.model])",
            )


def install_calibration(
    config_path: Path, calibration: Path, device_name: str | None, *, replace_overrides: bool = False
) -> Installed:
    """Name ``calibration`` in device ``device_name`` of the configuration ``config_path``
    (None: its only device), keeping every comment, and write it atomically; or raise
    ``ConfigError`` and leave the file as it was: not a gateway configuration, no such device,
    a calibration the device refuses, keys that contradict it (without ``replace_overrides``;
    the message lists them with both values) or a failed write."""
    text, b, d, device = check_install_target(config_path, device_name)
    value = _relative(calibration, config_path)
    document = tomlkit.parse(text)
    table: Any = document["bus"][b]["device"][d]
    previous = table.get(_KEY)
    previous = None if previous is None else str(previous)
    if _KEY in table or isinstance(table, InlineTable):
        table[_KEY] = value
    else:
        table.add(_KEY, value)  # tomlkit puts a plain key before the device's sub-tables
    try:
        dropped = _drop_all(tomlkit.parse(tomlkit.dumps(document)), b, d, config_path)
    except CalibrationConflictError as exc:  # a key the file cannot drop (the profile's)
        dropped, why = list(exc.contradictions), f"\n{exc}"
    else:
        why = ""
    if dropped and not replace_overrides:
        listed = conflict_error(Context(config_path), f"bus[{b}].device[{d}]", dropped)
        raise _refused(config_path, f"{listed}{why}")
    if dropped:
        if why:
            raise _refused(config_path, why.strip())
        _drop_all(document, b, d, config_path)
    new_text = tomlkit.dumps(document)
    if dropped:
        _check_others(text, new_text, config_path, b, d, load_calibration(Path(os.path.abspath(calibration))))
    if new_text == text:
        return Installed(config_path, device.name, value, previous, (), False)
    write_config(config_path, new_text)
    return Installed(config_path, device.name, value, previous, tuple(dropped), True)
