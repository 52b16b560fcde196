"""The JSON the page and programs read: a device's layout, and one frame per poll.

``layout_json`` describes a device once (channel names and positions in mm, units, the
status codes' labels); ``encode_frame`` turns one ``DeviceSnapshot`` into the bytes of one
frame (forces in N and status codes per channel in layout order, the array quantities, the
device's health counters). A frame is a view of the snapshot's one ``Frame``
(``runtime.frame``, shared with MQTT): a value that is not a finite number is ``null``, never
NaN (``finite_or_none``, the one NaN policy), so every frame is strict JSON. Frames are
encoded once per poll and shared by every client.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from typing import Any, NotRequired, Protocol, TypedDict

from ..runtime.counters import DeviceCounters
from ..runtime.frame import DECIMALS, Frame, RoiJson, compact_json, frame_of, roi_json
from ..runtime.snapshot import STATUS_LABELS, DeviceSnapshot, StatusWordReading, finite_or_none
from .region_layout import RegionDescription, groups_json, regions_json

#: Units of every quantity in the API, as listed with each device.
UNITS: dict[str, str] = {
    "force": "N",
    "position": "mm",
    "area": "mm^2",
    "time": "s",
}


class PageFrame(TypedDict):
    """One frame as the page and the stream read it (``docs/web.md``), in this order: times
    in s (``t`` the host's Unix time), forces in N, ``cop_mm`` the centre of pressure (x, y)
    in mm, ``status`` the ``ChannelStatus`` codes (the layout's ``status_labels`` name them)."""

    device: str
    seq: int
    t: float
    device_time_s: float | None
    last_success_t: float | None
    up: bool
    error: str | None
    force_n: list[float | None]
    status: list[int]
    total_force_n: float
    cop_mm: list[float] | None
    contact_area_mm2: float
    channels_in_contact: int
    peak_channel: str | None
    peak_force_n: float | None
    poll_interval_s: float
    polls_total: int
    reads_total: int
    read_errors_total: int
    #: the regions of interest (``[[bus.device.roi]]``), in configuration order; [] for none
    rois: list[RoiJson]
    #: the device's named status words at this poll (``status_word_json``), when it has any
    device_status: NotRequired[list[dict[str, Any]]]


def status_word_json(word: StatusWordReading) -> dict[str, Any]:
    """One status word read: its name, register value (None: not read), code label (an
    enumerated word), whether it is in error, and each named bit (set, an error bit)."""
    return {
        "name": word.name,
        "value": word.value,
        "code": word.code,
        "error": word.error,
        "bits": [{"bit": b, "label": label, "on": on, "error": err} for b, label, on, err in word.bits],
    }


def cell_area_from_positions(x_mm: Iterable[float], y_mm: Iterable[float]) -> float | None:
    """A grid's cell area (mm^2) from its channels' positions: the smallest spacing along x
    times the smallest along y (one of them alone for a single row or column), or None for
    a single channel. It is ``layout.cell_area_mm2`` when no row or column is wholly off."""

    def step(values: Iterable[float]) -> float | None:
        v = sorted({round(float(a), 6) for a in values if math.isfinite(float(a))})
        gaps = [b - a for a, b in itertools.pairwise(v) if b - a > 1e-9]
        return min(gaps) if gaps else None

    sx, sy = step(x_mm), step(y_mm)
    if sx is None and sy is None:
        return None
    return float((sx or sy or 0.0) * (sy or sx or 0.0))


class ChannelDescription(Protocol):
    """What the page needs of a configured channel (``config.ChannelConfig`` is one)."""

    @property
    def index(self) -> int: ...
    @property
    def name(self) -> str: ...
    @property
    def x_mm(self) -> float: ...
    @property
    def y_mm(self) -> float: ...
    @property
    def enabled(self) -> bool: ...


class LayoutDescription(Protocol):
    @property
    def cell_area_mm2(self) -> float: ...


class DeviceDescription(Protocol):
    """What the page needs of a device's configuration (``config.DeviceConfig`` is one: the
    web layer names no configuration type, so that it imports only the runtime)."""

    @property
    def name(self) -> str: ...
    @property
    def layout(self) -> LayoutDescription: ...
    @property
    def channels(self) -> Sequence[ChannelDescription]: ...
    @property
    def regions(self) -> Sequence[RegionDescription]: ...


def layout_json(
    dev: DeviceSnapshot, scale_max_n: float, config: DeviceDescription | None = None
) -> dict[str, Any]:
    """The static description of a device: channels, positions (mm, y grows downward as
    drawn), units, the status labels by code, the page's default colour scale (N), the area
    of one cell (mm^2: the layout's ``pitch_x_mm * pitch_y_mm``; the page's pressure is force
    over it) and the channels turned off in the configuration (``enabled = false``: they are
    never polled, so frames do not carry them; ``null`` when the page was not given the
    configuration), and for a device made of regions its ``regions`` and ``groups``
    (``region_layout``; empty lists for one grid, or without the configuration)."""
    if config is not None:
        area: float | None = config.layout.cell_area_mm2
        disabled: list[dict[str, Any]] | None = [
            {
                "index": ch.index,
                "name": ch.name,
                "x_mm": finite_or_none(ch.x_mm, DECIMALS),
                "y_mm": finite_or_none(ch.y_mm, DECIMALS),
            }
            for ch in config.channels
            if not ch.enabled
        ]
    else:
        area, disabled = cell_area_from_positions(dev.x_mm, dev.y_mm), None
    return {
        "name": dev.device,
        "bus": dev.bus,
        "poll_interval_s": finite_or_none(dev.poll_interval_s, DECIMALS),
        "units": {**UNITS, "pressure": "kPa"},
        "status_labels": list(STATUS_LABELS),
        "scale_n": [0.0, float(scale_max_n)],
        "cell_area_mm2": finite_or_none(area, DECIMALS),
        "channels": [
            {"index": int(index), "name": name, "x_mm": x, "y_mm": y}
            for index, name, x, y in zip(
                dev.channel_index.tolist(),
                dev.channel_names,
                finite_or_none(dev.x_mm, DECIMALS),
                finite_or_none(dev.y_mm, DECIMALS),
                strict=True,
            )
        ],
        "disabled_channels": disabled,
        "regions": regions_json(config.regions) if config is not None else [],
        "groups": groups_json(config.regions) if config is not None else [],
    }


def frame_json(source: DeviceSnapshot | Frame, seq: int, counters: DeviceCounters | None) -> PageFrame:
    """One poll of one device as the page's JSON-ready mapping (see ``encode_frame``): a view
    of the snapshot's shared ``Frame`` with the hub's ``seq`` and the device's counters."""
    f = frame_of(source) if isinstance(source, DeviceSnapshot) else source
    cop = f.center_of_pressure_mm
    c = counters or DeviceCounters()
    out: PageFrame = {
        "device": f.device,
        "seq": seq,
        "t": f.host_time_s,
        "device_time_s": f.device_time_s,
        "last_success_t": f.last_success_time_s,
        "up": f.up,
        "error": f.error,
        "force_n": list(f.force_n),
        "status": list(f.status),  # IntEnum members: ints to every JSON encoder
        "total_force_n": f.total_force_n,
        "cop_mm": None if cop is None else [cop[0], cop[1]],
        "contact_area_mm2": f.contact_area_mm2,
        "channels_in_contact": f.channels_in_contact,
        "peak_channel": f.peak_channel,
        "peak_force_n": f.peak_force_n,
        "poll_interval_s": f.poll_interval_s,
        "polls_total": c.polls_total,
        "reads_total": c.reads_total,
        "read_errors_total": sum(c.read_errors_total.values()),
        "rois": [roi_json(r) for r in f.rois],
    }
    if isinstance(source, DeviceSnapshot) and source.status_words:
        out["device_status"] = [status_word_json(w) for w in source.status_words]
    return out


def encode_frame(source: DeviceSnapshot | Frame, seq: int, counters: DeviceCounters | None) -> bytes:
    """The compact UTF-8 JSON of one frame: an object starting with ``{"device":``."""
    return compact_json(frame_json(source, seq, counters))


def with_dropped(frame: bytes, dropped: int) -> bytes:
    """``frame`` with a leading ``"dropped": n`` member (frames this client has lost so far),
    without decoding it again."""
    return b'{"dropped":%d,%s' % (dropped, frame[1:])
