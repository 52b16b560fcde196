"""What the page's server keeps of a device's past: compact summaries and recent readings.

``DeviceHistory`` holds, for one device, from its good polls (``up``; a failed poll repeats
old values and is not kept):

* **History** (``history_s``, 0..3600 s): one point per poll, the array's total force and
  peak (N), contact area (mm^2), centre of pressure (mm) and each region of interest's
  figures, packed in one float64 array (the regions' names in one tuple shared by the
  points): never per-channel values. At most ``HISTORY_MAX_POINTS`` points: a poll less than
  ``history_s / HISTORY_MAX_POINTS`` after the last point kept is left out (at 300 s, polls
  closer than 15 ms: over 66 a second). Measured (tracemalloc): 221 bytes a point, plus 37
  per region of interest, so at most 4.4 MB a device, plus 0.75 MB per region, whatever the
  poll rate. Served by ``/api/devices/{name}/history`` (``json_point``).
* **Readings for export** (``export_s``, 0..600 s): per poll a ``Reading``, the snapshot's
  own arrays that a record row needs (resistances, forces, statuses, reference forces,
  temperatures: shared, not copied; no static estimate, no derived frame), for
  ``/api/devices/{name}/export.csv``. At most ``EXPORT_MAX_FRAMES`` polls and
  ``EXPORT_MAX_VALUES`` channel readings: about 450 bytes a poll plus 17 a channel reading
  (33 with reference forces and temperatures), so at most 26 MB a device (42 MB): 16
  channels keep 60 s at up to 333 polls a second, a 1,062-taxel hand its last 941 polls.

Points and readings older than their span before the newest poll are dropped as polls come.
The hub (``web.hub``) adds every poll in the server's loop, where the endpoints read: no lock.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Final

import numpy as np

from ..runtime.frame import DECIMALS
from ..runtime.snapshot import DeviceSnapshot, FloatArray, RoiQuantities, StatusArray, finite_or_none

__all__ = ["EXPORT_MAX_FRAMES", "EXPORT_MAX_VALUES", "HISTORY_MAX_POINTS", "DeviceHistory", "HistoryPoint"]

HISTORY_MAX_S: Final = 3600.0
EXPORT_MAX_S: Final = 600.0
#: the most summaries kept of one device over ``history_s``
HISTORY_MAX_POINTS: Final = 20_000
#: the most polls of one device kept for export
EXPORT_MAX_FRAMES: Final = 20_000
#: the most channel readings (polls x channels) of one device kept for export
EXPORT_MAX_VALUES: Final = 1_000_000


@dataclass(frozen=True, slots=True)
class Reading:
    """What a record row needs of one poll (the snapshot's arrays, shared, not copied)."""

    timestamp_s: float
    last_success_timestamp_s: float | None
    device_time_s: float | None
    resistance_ohm: FloatArray
    force_n: FloatArray
    status: StatusArray
    reference_force_n: FloatArray
    temperature_c: FloatArray | None


@dataclass(frozen=True, slots=True)
class HistoryPoint:
    """One good poll in a few numbers: host time (Unix s), total force and peak (N; peak None
    when nothing is in contact), contact area (mm^2), centre of pressure (mm) and the regions
    of interest."""

    t: float
    force_n: float
    peak_n: float | None
    area_mm2: float
    cop_mm: tuple[float, float] | None
    rois: tuple[RoiQuantities, ...]


def _five(
    force_n: float, peak_n: float | None, area_mm2: float, cop_mm: tuple[float, float] | None
) -> tuple[float, float, float, float, float]:
    """Force, peak, area, centre of pressure x and y as floats (NaN for none)."""
    nan = math.nan
    cop = cop_mm if cop_mm is not None else (nan, nan)
    return (force_n, nan if peak_n is None else peak_n, area_mm2, cop[0], cop[1])


def _none(value: float) -> float | None:
    return None if math.isnan(value) else value


def _point(v: FloatArray, keys: tuple[tuple[str, tuple[int, ...]], ...]) -> HistoryPoint:
    values: list[float] = v.tolist()
    cop = None if math.isnan(values[4]) else (values[4], values[5])
    rois = []
    for k, (name, channels) in enumerate(keys):
        f, p, a, x, y = values[6 + 5 * k : 11 + 5 * k]
        rois.append(RoiQuantities(name, channels, f, p, a, None if math.isnan(x) else (x, y)))
    return HistoryPoint(values[0], values[1], _none(values[2]), values[3], cop, tuple(rois))


def _r(value: float | None) -> float | None:
    return finite_or_none(value, DECIMALS)


class DeviceHistory:
    """One device's history and export buffer (module docstring); spans in s, 0: off."""

    def __init__(self, history_s: float, export_s: float) -> None:
        if not 0.0 <= history_s <= HISTORY_MAX_S:
            raise ValueError(f"history_s: {history_s!r} is out of range; allowed: 0..{HISTORY_MAX_S:g} s")
        if not 0.0 <= export_s <= EXPORT_MAX_S:
            raise ValueError(f"export_s: {export_s!r} is out of range; allowed: 0..{EXPORT_MAX_S:g} s")
        self.history_s = float(history_s)
        self.export_s = float(export_s)
        self._min_step_s = self.history_s / HISTORY_MAX_POINTS
        #: per point: [t, total, peak, area, cop x, cop y, then per region the last five] (NaN:
        #: none) and the regions' names and channels (one tuple shared by the points)
        self._points: deque[tuple[FloatArray, tuple[tuple[str, tuple[int, ...]], ...]]] = deque(
            maxlen=HISTORY_MAX_POINTS + 1
        )
        self._roi_keys: tuple[tuple[str, tuple[int, ...]], ...] = ()
        self._readings: deque[Reading] = deque(maxlen=EXPORT_MAX_FRAMES)
        self._template: DeviceSnapshot | None = None  # the device's layout for ``snapshots``

    def add(self, snap: DeviceSnapshot) -> None:
        """One poll of the device (a failed one is not kept)."""
        if not snap.up:
            return
        t = float(snap.timestamp_s)
        if self.history_s > 0 and (not self._points or t >= self._points[-1][0][0] + self._min_step_s):
            keys = tuple((r.name, r.channels) for r in snap.rois)
            if keys != self._roi_keys:
                self._roi_keys = keys  # one tuple shared by every point until a reload
            figures = [t, *_five(snap.total_force_n, snap.peak_force_n, snap.contact_area_mm2,
                                 snap.center_of_pressure_mm)]  # fmt: skip
            for r in snap.rois:
                figures.extend(_five(r.force_n, r.peak_n, r.area_mm2, r.cop_mm))
            self._points.append((np.array(figures, dtype=np.float64), self._roi_keys))
            while self._points and self._points[0][0][0] < t - self.history_s:
                self._points.popleft()
        if self.export_s > 0:
            if self._template is None or snap.channel_names != self._template.channel_names:
                # a reload changed the device: start again
                frames = min(EXPORT_MAX_FRAMES, max(1, EXPORT_MAX_VALUES // max(1, snap.n_channels)))
                self._readings = deque(maxlen=frames)
            self._template = snap
            reading = Reading(
                t, snap.last_success_timestamp_s, snap.device_time_s, snap.resistance_ohm,
                snap.force_n, snap.status, snap.reference_force_n, snap.temperature_c,
            )  # fmt: skip
            self._readings.append(reading)
            while self._readings and self._readings[0].timestamp_s < t - self.export_s:
                self._readings.popleft()

    def points(self, seconds: float) -> list[HistoryPoint]:
        """The points of the last ``seconds`` before the newest one (oldest first)."""
        if not self._points:
            return []
        start = self._points[-1][0][0] - seconds
        return [_point(v, keys) for v, keys in self._points if v[0] >= start]

    def export(self, from_s: float, to_s: float) -> list[Reading]:
        """The kept polls with host times in [``from_s``, ``to_s``] (Unix s), oldest first."""
        return [r for r in self._readings if from_s <= r.timestamp_s <= to_s]

    def snapshots(self, readings: list[Reading]) -> list[DeviceSnapshot]:
        """``readings`` as the device's snapshots (up, slim: no static estimate, no regions),
        for the recorder (any thread: nothing of the history is read but the layout)."""
        template = self._template
        if template is None:
            return []
        slim = replace(
            template, static_estimate=None, dead=None, status_words=(), rois=(), up=True, error=None
        )
        return [
            replace(slim, timestamp_s=r.timestamp_s, last_success_timestamp_s=r.last_success_timestamp_s,
                    device_time_s=r.device_time_s, resistance_ohm=r.resistance_ohm, force_n=r.force_n,
                    status=r.status, reference_force_n=r.reference_force_n, temperature_c=r.temperature_c)
            for r in readings
        ]  # fmt: skip

    def export_frames(self) -> int:
        return len(self._readings)

    def newest_s(self) -> float | None:
        """The host time of the newest poll kept for export (Unix s), None if none is."""
        return float(self._readings[-1].timestamp_s) if self._readings else None

    @staticmethod
    def json_point(p: HistoryPoint) -> dict[str, Any]:
        """A point as ``/api/devices/{name}/history`` gives it (6 decimals, null for absent)."""
        cop = p.cop_mm
        return {
            "t": _r(p.t),
            "force_n": _r(p.force_n),
            "peak_n": _r(p.peak_n),
            "area_mm2": _r(p.area_mm2),
            "cop_x_mm": None if cop is None else _r(cop[0]),
            "cop_y_mm": None if cop is None else _r(cop[1]),
            "rois": {
                r.name: {
                    "force_n": _r(r.force_n),
                    "peak_n": _r(r.peak_n),
                    "area_mm2": _r(r.area_mm2),
                    "cop_x_mm": None if r.cop_mm is None else _r(r.cop_mm[0]),
                    "cop_y_mm": None if r.cop_mm is None else _r(r.cop_mm[1]),
                }
                for r in p.rois
            },
        }
