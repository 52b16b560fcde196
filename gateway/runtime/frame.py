"""The one typed frame of a device poll, as the page, the stream and MQTT publish it.

A ``Frame`` is what leaves the gateway of one ``DeviceSnapshot``: every value already in
its published form, a float rounded to ``DECIMALS`` (6) decimals or None where absent or not
finite (``snapshot.finite_or_none``, the one NaN policy), per channel in the order of the
enabled channels. It is built once per snapshot (``frame_of``, by whichever thread needs it
first: ``DeviceSnapshot.derived``) and shared; the encodings are views of it: ``web.frames`` (the page's
and the stream's JSON: ``t``, ``cop_mm``, status codes, with the hub's sequence number and
the device's counters) and ``mqtt.payload`` (``docs/mqtt.md``'s JSON and binary layout:
``host_time_s``, ``center_of_pressure_mm``, status labels, with the publisher's sequence).

Six decimals: 1 µN, 1 µΩ, 1 µs, 1 µm² and 1 nm are far below what a tactile channel or a
clock resolves, and no binary float noise (``15.620000000000001``) reaches a client. Rounding
to decimals, not to significant digits, keeps the Unix time to the microsecond.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final, TypedDict

import numpy as np
import orjson

from .snapshot import ChannelStatus, DeviceSnapshot, RoiQuantities, finite_or_none

__all__ = ["DECIMALS", "Frame", "RoiJson", "compact_json", "frame_of", "roi_json", "rounded_roi"]

#: Decimals of every published float.
DECIMALS: Final = 6

_STATUSES: Final = tuple(ChannelStatus)


def _rounded(x: float) -> float:
    return round(float(x), DECIMALS)


@dataclass(frozen=True, eq=True)
class Frame:
    """One poll of one device as published (immutable; absent values None, never NaN).

    Per-channel tuples have one entry per enabled channel, named by ``channel_names``.
    """

    device: str
    up: bool  # False: the poll failed (every channel stale, values the last ones)
    error: str | None  # why the poll failed
    host_time_s: float  # wall clock of the poll (Unix time)
    device_time_s: float | None  # device clock at the last good poll
    last_success_time_s: float | None  # wall clock of the last good poll (Unix time)
    poll_interval_s: float
    channel_names: tuple[str, ...]
    force_n: tuple[float | None, ...]  # drift-corrected force
    force_static_n: tuple[float | None, ...]  # static inversion (no creep state)
    resistance_ohm: tuple[float | None, ...]
    status: tuple[ChannelStatus, ...]
    total_force_n: float
    center_of_pressure_mm: tuple[float, float] | None  # (x, y); None: nothing in contact
    contact_area_mm2: float
    channels_in_contact: int
    peak_channel: str | None
    peak_force_n: float | None
    #: the regions of interest (``snapshot.RoiQuantities``, rounded), in configuration order
    rois: tuple[RoiQuantities, ...] = ()

    @classmethod
    def of(cls, snap: DeviceSnapshot) -> Frame:
        """The frame of ``snap``, built anew (``frame_of`` builds it once and shares it)."""
        cop = snap.center_of_pressure_mm
        n = len(snap.channel_names)
        # one rounding pass over the three per-channel arrays: each numpy call of the pass
        # costs about as much for 64 values as for 192
        stacked = np.concatenate((snap.force_n, snap.force_static_n, snap.resistance_ohm), dtype=np.float64)
        values = finite_or_none(stacked, DECIMALS)
        return cls(
            device=snap.device,
            up=bool(snap.up),
            error=snap.error,
            host_time_s=_rounded(snap.timestamp_s),
            device_time_s=finite_or_none(snap.device_time_s, DECIMALS),
            last_success_time_s=finite_or_none(snap.last_success_timestamp_s, DECIMALS),
            poll_interval_s=_rounded(snap.poll_interval_s),
            channel_names=tuple(snap.channel_names),
            force_n=tuple(values[:n]),
            force_static_n=tuple(values[n : 2 * n]),
            resistance_ohm=tuple(values[2 * n :]),
            status=tuple(map(_STATUSES.__getitem__, snap.status.tolist())),
            total_force_n=_rounded(snap.total_force_n),
            center_of_pressure_mm=None if cop is None else (_rounded(cop[0]), _rounded(cop[1])),
            contact_area_mm2=_rounded(snap.contact_area_mm2),
            channels_in_contact=int(snap.channels_in_contact),
            peak_channel=snap.peak_channel,
            peak_force_n=finite_or_none(snap.peak_force_n, DECIMALS),
            rois=tuple(map(rounded_roi, snap.rois)),
        )


def rounded_roi(r: RoiQuantities) -> RoiQuantities:
    """A region of interest's quantities as published: rounded to ``DECIMALS``."""
    cop = None if r.cop_mm is None else (_rounded(r.cop_mm[0]), _rounded(r.cop_mm[1]))
    return RoiQuantities(
        r.name, r.channels, _rounded(r.force_n), _rounded(r.peak_n), _rounded(r.area_mm2), cop
    )


class RoiJson(TypedDict):
    """One region of interest in a frame: its name, its channels (their ``index`` in the
    layout's ``channels``), and over those in contact the sum of force and the peak (N; 0
    when none is), the contact area (mm^2) and the centre of pressure (mm; null when none
    is in contact)."""

    name: str
    channels: list[int]
    force_n: float
    peak_n: float
    area_mm2: float
    cop_x_mm: float | None
    cop_y_mm: float | None


def roi_json(r: RoiQuantities) -> RoiJson:
    """A region of interest (already rounded: ``rounded_roi``) as a frame's JSON (the page's
    and MQTT's)."""
    cop = r.cop_mm
    return {
        "name": r.name,
        "channels": list(r.channels),
        "force_n": r.force_n,
        "peak_n": r.peak_n,
        "area_mm2": r.area_mm2,
        "cop_x_mm": None if cop is None else cop[0],
        "cop_y_mm": None if cop is None else cop[1],
    }


def frame_of(snap: DeviceSnapshot) -> Frame:
    """The one ``Frame`` of ``snap``: built by the first thread that asks, then shared."""
    return snap.derived(Frame.of)


def compact_json(value: Any) -> bytes:
    """The compact UTF-8 JSON of a frame's encoding (no spaces; the same text as
    ``json.dumps(value, separators=(",", ":"))`` but for exponents, ``5e-5`` for ``5e-05``, and
    non-ASCII characters, written as themselves): orjson, a tenth of the standard library's
    cost, which matters at a thousand frames a second. Frames hold no NaN (``Frame`` has
    None), so none is written."""
    return orjson.dumps(value)
