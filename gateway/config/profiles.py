"""Device profiles: a file that names a device's register map, clock, front end, layout and
the checks that tell it is the right device.

A device table says ``profile = "acme-at6x6"`` (a profile shipped in
``gateway/config/profiles/``) or ``profile = "boards/myboard.toml"`` (a file, relative to
the configuration file), and overrides what differs: its own keys win, and in the tables
``registers``, ``clock``, ``front_end``, ``layout`` and ``checks`` key by key (a
``front_end`` of another ``kind`` replaces the profile's whole table). ``docs/profiles.md``
says how to write one.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, Final

from ..errors import ConfigError
from .readout import DIVIDER_KEYS, LAYOUT_KEYS
from .tables import Context, Table, parse_toml, read_text_file, show_path, suggest
from .wire import CHECK_KEYS, FRAME_KEYS, REGISTER_KEYS

__all__ = ["MERGED_TABLES", "PROFILE_KEYS", "builtin_profiles", "load_profile", "merge_profile"]

#: Keys a profile may set (a device's name, id, channel entries and calibration are its own).
PROFILE_KEYS: Final = (
    "description",
    "encoding",
    "channels",
    "columns",
    "pitch_mm",
    "registers",
    "clock",
    "front_end",
    "divider",
    "layout",
    "checks",
    "model",
    "frame",
    "setup",
    "actions",
    "region",
    "address_unit",
    "value_stride",
    "status_word",
    "rails",
)
#: Tables merged key by key with the device's own (``setup``, ``region`` and ``status_word``
#: are arrays: the device's own replaces the profile's; ``actions`` merge by name).
MERGED_TABLES: Final = ("registers", "clock", "front_end", "layout", "checks", "model", "frame", "actions")
_SUFFIX: Final = ".toml"
#: The profile's tables whose keys do not depend on a kind: an unknown key in one of them (e.g.
#: ``clock = ...`` written after ``[registers]``, so TOML puts it in that table) is named with
#: the profile's file, not the configuration that names the profile.
_FIXED_KEY_TABLES: Final = (
    ("registers", REGISTER_KEYS, "[registers]"),
    ("layout", LAYOUT_KEYS, "[layout]"),
    ("checks", CHECK_KEYS, "[checks]"),
    ("divider", DIVIDER_KEYS, "[divider]"),
    ("model", ("effects", "params"), "[model]"),
    ("frame", FRAME_KEYS, "[frame]"),
)


def builtin_profiles() -> dict[str, str]:
    """Shipped profiles by name, with their one-line description."""
    out: dict[str, str] = {}
    folder = resources.files(__package__) / "profiles"
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if entry.name.endswith(_SUFFIX):
            text = entry.read_text(encoding="utf-8")
            description = ""
            for line in text.splitlines():
                if line.startswith("description"):
                    description = line.partition("=")[2].strip().strip('"')
                    break
            out[entry.name[: -len(_SUFFIX)]] = description
    return out


def load_profile(ctx: Context, key_path: str, reference: str) -> tuple[str, dict[str, Any]]:
    """The profile a device names: (its label for messages, its table). A name without a
    slash or ``.toml`` is a shipped profile; anything else a file relative to the
    configuration. ``ConfigError`` names ``key_path`` and lists the shipped profiles."""
    if "/" not in reference and not reference.endswith(_SUFFIX):
        shipped = builtin_profiles()
        if reference not in shipped:
            names = ", ".join(shipped)
            raise ctx.error(
                key_path,
                f"no profile {reference!r}{suggest(reference, shipped)} (shipped profiles: {names}; "
                "or the path of a profile file ending in .toml)",
            )
        text = (resources.files(__package__) / "profiles" / f"{reference}{_SUFFIX}").read_text(
            encoding="utf-8"
        )
        label = f"profile {reference!r}"
        profile_ctx = Context(Path(f"<profile {reference}>"))
    else:
        file = ctx.resolve(reference)
        if not file.exists():
            raise ctx.error(key_path, f"{show_path(file)} does not exist (device profile)")
        try:  # a regular file of bounded size: /dev/zero is refused unread
            text = read_text_file(file, "device profile")
        except ConfigError as exc:
            raise ctx.error(key_path, f"cannot read the device profile: {exc}") from None
        label = f"profile {str(file)!r}"
        profile_ctx = Context(file)
    data = parse_toml(profile_ctx, text, "device profile")
    table = Table(profile_ctx, data, "", PROFILE_KEYS)  # unknown keys, named in the profile's own file
    for key, allowed, header in _FIXED_KEY_TABLES:
        table.table(key, allowed, header)
    return label, data


def merge_profile(profile: dict[str, Any], device: dict[str, Any]) -> dict[str, Any]:
    """The device table with the profile's keys under its own (see the module docstring)."""
    merged: dict[str, Any] = {k: v for k, v in profile.items() if k != "description"}
    # the device's own spelling of a setting replaces the profile's other spelling of it
    if "divider" in device:
        merged.pop("front_end", None)
    if "front_end" in device:
        merged.pop("divider", None)
    layout = merged.get("layout")
    if isinstance(layout, dict):
        merged["layout"] = {k: v for k, v in layout.items() if k not in device}
    for key in ("columns", "pitch_mm"):
        if isinstance(device.get("layout"), dict) and key in device["layout"]:
            merged.pop(key, None)
    for key, value in device.items():
        if key == "profile":
            continue
        base = merged.get(key)
        if key in MERGED_TABLES and isinstance(base, dict) and isinstance(value, dict):
            if key == "front_end" and value.get("kind", base.get("kind")) != base.get("kind"):
                merged[key] = dict(value)
            else:
                merged[key] = {**base, **value}
        else:
            merged[key] = value
    return merged
