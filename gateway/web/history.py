"""What the page's server keeps of a device's past: compact summaries and recent readings.

``DeviceHistory`` holds, for one device, from its good polls (``up``; a failed poll repeats
old values and is not kept):

* **History** (``history_s``, 0..3600 s): one ``HistoryPoint`` per poll, the array's total
  force and peak (N), contact area (mm^2), centre of pressure (mm) and each region of
  interest's figures: a few numbers, never per-channel values. At most
  ``HISTORY_MAX_POINTS`` points: a poll less than ``history_s / HISTORY_MAX_POINTS`` after
  the last point kept is left out (at 300 s, polls closer than 15 ms: over 66 a second), so a
  device costs at most 20,000 points (about 200 bytes each, plus about 150 per region of
  interest: 4 MB, 7 MB with 10 regions) whatever its poll rate. Served by
  ``/api/devices/{name}/history`` (``json_point``).
* **Readings for export** (``export_s``, 0..600 s): each poll's snapshot, slimmed to what a
  record row needs (resistances, forces, statuses, reference forces, temperatures: no static
  estimate, no derived frame), for ``/api/devices/{name}/export.csv``. At most
  ``EXPORT_MAX_FRAMES`` polls and ``EXPORT_MAX_VALUES`` channel readings (17 to 33 bytes each:
  at most 34 MB a device, 66 MB with reference forces and temperatures): 16 channels keep
  60 s at up to 333 polls a second, a 1,062-taxel hand its last 941 polls.

Points and readings older than their span before the newest poll are dropped as polls come.
The hub (``web.hub``) adds every poll in the server's loop, where the endpoints read: no lock.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Final

from ..runtime.frame import DECIMALS
from ..runtime.snapshot import DeviceSnapshot, RoiQuantities, finite_or_none

__all__ = ["EXPORT_MAX_FRAMES", "EXPORT_MAX_VALUES", "HISTORY_MAX_POINTS", "DeviceHistory", "HistoryPoint"]

HISTORY_MAX_S: Final = 3600.0
EXPORT_MAX_S: Final = 600.0
#: the most summaries kept of one device over ``history_s``
HISTORY_MAX_POINTS: Final = 20_000
#: the most polls of one device kept for export
EXPORT_MAX_FRAMES: Final = 20_000
#: the most channel readings (polls x channels) of one device kept for export
EXPORT_MAX_VALUES: Final = 1_000_000


@dataclass(frozen=True)
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
        self._points: deque[HistoryPoint] = deque(maxlen=HISTORY_MAX_POINTS + 1)
        self._readings: deque[DeviceSnapshot] = deque(maxlen=EXPORT_MAX_FRAMES)
        self._n_channels = 0

    def add(self, snap: DeviceSnapshot) -> None:
        """One poll of the device (a failed one is not kept)."""
        if not snap.up:
            return
        t = float(snap.timestamp_s)
        if self.history_s > 0 and (not self._points or t >= self._points[-1].t + self._min_step_s):
            figures = (snap.total_force_n, snap.peak_force_n, snap.contact_area_mm2)
            self._points.append(HistoryPoint(t, *figures, snap.center_of_pressure_mm, snap.rois))
            while self._points and self._points[0].t < t - self.history_s:
                self._points.popleft()
        if self.export_s > 0:
            if snap.n_channels != self._n_channels:  # a reload changed the device: start again
                self._n_channels = snap.n_channels
                frames = min(EXPORT_MAX_FRAMES, max(1, EXPORT_MAX_VALUES // max(1, snap.n_channels)))
                self._readings = deque(maxlen=frames)
            slim = replace(snap, static_estimate=None, dead=None, status_words=(), rois=())
            self._readings.append(slim)
            while self._readings and self._readings[0].timestamp_s < t - self.export_s:
                self._readings.popleft()

    def points(self, seconds: float) -> list[HistoryPoint]:
        """The points of the last ``seconds`` before the newest one (oldest first)."""
        if not self._points:
            return []
        start = self._points[-1].t - seconds
        return [p for p in self._points if p.t >= start]

    def export(self, from_s: float, to_s: float) -> list[DeviceSnapshot]:
        """The kept polls with host times in [``from_s``, ``to_s``] (Unix s), oldest first."""
        return [s for s in self._readings if from_s <= s.timestamp_s <= to_s]

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
