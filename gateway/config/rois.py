"""Regions of interest: ``[[bus.device.roi]]`` and the ``Roi`` value; channel selections.

A region of interest is a named set of a device's channels whose force the gateway sums
every poll (sum, peak, contact area and centre of pressure over its channels, as over the
whole array: ``runtime.rois``). It is named (the channel-name rule, unique within the
device) and lists its ``channels``: channel names, indices, index ranges ``"A-B"`` and, on a
device made of regions, a region's or a group's name (each of its taxels), the same
selections as ``tare --channels`` (``select_channels``, the one parser of them).

    [[bus.device.roi]]
    name = "heel"
    channels = ["0-3", "ch05"]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from ..errors import ConfigError
from .regions import Region
from .tables import REQUIRED, Context, Table

__all__ = ["MAX_ROIS", "ROI_KEYS", "Roi", "parse_rois", "select_channels"]

ROI_KEYS: Final = ("name", "channels")
#: The most regions of interest of one device (each costs a sum over its channels per poll).
MAX_ROIS: Final = 64


@dataclass(frozen=True)
class Roi:
    """One region of interest: its name and its device channel indices (ascending, unique,
    at least one)."""

    name: str
    channels: tuple[int, ...]

    def __post_init__(self) -> None:
        if not self.channels:
            raise ConfigError(f"region of interest {self.name!r}: channels: empty; allowed: one or more")
        if any(c < 0 for c in self.channels) or list(self.channels) != sorted(set(self.channels)):
            raise ConfigError(
                f"region of interest {self.name!r}: channels: {list(self.channels)}; "
                "allowed: channel indices >= 0, ascending, each once"
            )


def select_channels(
    entries: Sequence[str],
    channel_names: Sequence[str],
    regions: Sequence[Region],
    device: str,
    what: str = "--channels",
    spec: str | None = None,
) -> list[int]:
    """Channel indices (ascending) of ``entries``: channel names, indices 0..N-1, ranges ``A-B``
    of indices and, on a device made of regions, a region's name (``palm``) or a group's
    (``index``: each of its regions); ``ValueError`` naming the entry that is none of them and
    what is allowed (``what`` names the option or key, ``spec`` the whole text given)."""
    names = {name: k for k, name in enumerate(channel_names)}
    spans: dict[str, list[int]] = {}
    for region in regions:
        taxels = range(region.first_channel, region.first_channel + region.n_channels)
        spans.setdefault(region.name, []).extend(taxels)
        if region.group and region.group != region.name:
            spans.setdefault(region.group, []).extend(taxels)
    last = len(channel_names) - 1
    by_region = " or region and group names (e.g. palm)" if regions else ""
    allowed = f"allowed: channel names (e.g. {channel_names[0]}), indices 0-{last} or ranges A-B{by_region}"
    out: set[int] = set()
    for raw in entries:
        entry = raw.strip()
        if not entry:
            shown = f" {spec!r}" if spec is not None else ""
            raise ValueError(f"{what}{shown}: an empty entry; {allowed}")
        if entry in names:
            out.add(names[entry])
            continue
        if entry in spans:
            out.update(spans[entry])
            continue
        low, dash, high = entry.partition("-")
        try:
            a = int(low)
            b = int(high) if dash else a
        except ValueError:
            raise ValueError(f"{what}: no channel {entry!r} in device {device}; {allowed}") from None
        if not 0 <= a <= b <= last:
            raise ValueError(f"{what}: {entry!r} is out of range; {allowed}")
        out.update(range(a, b + 1))
    return sorted(out)


def parse_rois(
    ctx: Context, device: Table, device_name: str, channel_names: Sequence[str], regions: Sequence[Region]
) -> tuple[Roi, ...]:
    """``[[bus.device.roi]]`` of the device table ``device`` (its channels named
    ``channel_names``, in index order); () when it has none."""
    items = device.tables("roi", "[[bus.device.roi]]")
    if len(items) > MAX_ROIS:
        raise device.error("roi", f"{len(items)} regions of interest; allowed: 0..{MAX_ROIS} per device")
    out: list[Roi] = []
    seen: dict[str, str] = {}
    for rpath, item in items:
        table = Table(ctx, item, rpath, ROI_KEYS)
        name = table.name("name")
        if name in seen:
            raise table.error(
                "name", f"duplicate region of interest {name!r} (also {seen[name]}); names are unique"
            )
        seen[name] = table.at("name")
        expected = 'a non-empty list of channel names, indices or ranges "A-B" (strings or integers)'
        raw = table._get("channels", REQUIRED, expected)
        if (
            not isinstance(raw, list)
            or not raw
            or not all(isinstance(v, str) or (isinstance(v, int) and not isinstance(v, bool)) for v in raw)
        ):
            raise table._wrong_type("channels", raw, expected)
        try:
            chosen = select_channels([str(v) for v in raw], channel_names, regions, device_name, "channels")
        except ValueError as exc:
            raise table.error("channels", str(exc).removeprefix("channels: ")) from None
        out.append(Roi(name, tuple(chosen)))
    return tuple(out)
