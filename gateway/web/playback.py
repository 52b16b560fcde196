"""Playback: the live page over the frames of a recorded file (``tactile-gateway view``).

The web layer does not read records (that is analysis): the command replays the record
through the runtime's processor and hands the resulting ``DeviceSnapshot``s here, one per
device sample in time order (or those ``thin`` keeps of them, with the record's count).
``playback_frames`` encodes them as the live page's frames (``page_frames``: the values of
``frames.frame_json`` of each snapshot, the same shape, so ``app.js`` draws them with the same
code, rounded over all frames at once), each with one more member,
``reference_total_force_n``: the sum of the record's reference forces at that sample (N;
``null`` when the record has no ``force_n`` column), and for a record with a reference,
``reference_force_n``: each channel's reference force (N; ``null`` where it has none), so
the page shows the error per channel.

``PlaybackPage(playback).install(app)`` serves:

* ``/`` and ``/static/{file}``: the same page as the live gateway (the same files and
  Content-Security-Policy);
* ``/api/devices`` and ``/api/devices/{name}``: the recorded device's layout, as live, with
  ``playback`` set (the page switches to its playback controls on it);
* ``/api/playback``: every frame at once, with the record's time span (s);
* ``/api/devices/{name}/export.csv?from_s=A&to_s=B``: the record's own rows with times from A
  to B (s, the frames' ``t``; default the whole record) in the record format, written by the
  ``export_csv`` the command gives (404 without one).

A record of more than ``MAX_FRAMES`` device samples is thinned to every k-th sample (the
last one kept), so the page never receives more than that many frames.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NotRequired

import numpy as np
from aiohttp import web

from ..runtime.counters import DeviceCounters
from ..runtime.frame import DECIMALS, compact_json, rounded_roi
from ..runtime.snapshot import DeviceSnapshot, finite_or_none
from .app import PageFiles, query_number
from .frames import DeviceDescription, PageFrame, layout_json, roi_json

#: The most frames a playback sends to the page (about 12 MB of JSON for 16 channels).
MAX_FRAMES = 20_000


class PlaybackFrame(PageFrame):
    """A live page's frame with the record's reference total force (N; None: no reference)."""

    reference_total_force_n: float | None
    reference_force_n: NotRequired[list[float | None]]


@dataclass(frozen=True)
class Playback:
    """A record's frames as the page reads them: the device's layout (``layout_json``), the
    frames in time order, the record's time span (s) and whether it has a reference force."""

    layout: dict[str, Any]
    frames: list[PlaybackFrame]
    start_s: float
    end_s: float
    has_reference: bool
    source: str = ""
    samples_total: int = 0  # device samples in the record (``len(frames)`` unless thinned)
    info: dict[str, Any] = field(default_factory=dict)
    #: ``export_csv(from_s, to_s)``: the record's rows between two times as CSV text
    export_csv: Callable[[float, float], str] | None = None


def thin(n_samples: int, max_frames: int = MAX_FRAMES) -> list[int]:
    """The indices of the samples kept: all up to ``max_frames``, else every k-th and the last."""
    if n_samples <= max_frames:
        return list(range(n_samples))
    step = math.ceil(n_samples / max_frames)
    keep = list(range(0, n_samples, step))
    if keep[-1] != n_samples - 1:
        keep[-1] = n_samples - 1  # keep the count at most max_frames and the end in view
    return keep


def reference_total_n(snap: DeviceSnapshot) -> float | None:
    """The sum of the finite reference forces of a sample (N), or None if it has none."""
    values = [float(v) for v in snap.reference_force_n if math.isfinite(float(v))]
    return math.fsum(values) if values else None


def page_frames(snapshots: Sequence[DeviceSnapshot], *, has_reference: bool) -> list[PlaybackFrame]:
    """The page's frames of ``snapshots`` (one device: the same channels), numbered from 1:
    ``frame_json`` of each (no counters) with its reference total, equal value for value,
    each per-channel quantity rounded once over all the snapshots (a record has up to
    ``MAX_FRAMES`` of them: one by one, the frames would cost several times the replay)."""
    if not snapshots:
        return []
    n = snapshots[0].n_channels
    flat = finite_or_none(np.stack([s.force_n for s in snapshots]).astype(np.float64), DECIMALS)
    refs = (
        finite_or_none(np.stack([s.reference_force_n for s in snapshots]).astype(np.float64), DECIMALS)
        if has_reference
        else None
    )
    statuses = np.stack([s.status for s in snapshots]).astype(np.int64).tolist()
    counters = DeviceCounters()
    read_errors = sum(counters.read_errors_total.values())
    out: list[PlaybackFrame] = []
    for seq, (snap, status) in enumerate(zip(snapshots, statuses, strict=True), start=1):
        cop = snap.center_of_pressure_mm
        lo = (seq - 1) * n
        reference = finite_or_none(reference_total_n(snap), DECIMALS) if has_reference else None
        frame: PlaybackFrame = {
            "device": snap.device,
            "seq": seq,
            "t": round(float(snap.timestamp_s), DECIMALS),
            "device_time_s": finite_or_none(snap.device_time_s, DECIMALS),
            "last_success_t": finite_or_none(snap.last_success_timestamp_s, DECIMALS),
            "up": bool(snap.up),
            "error": snap.error,
            "force_n": flat[lo : lo + n],
            "status": status,
            "total_force_n": round(float(snap.total_force_n), DECIMALS),
            "cop_mm": None if cop is None else [round(float(c), DECIMALS) for c in cop],
            "contact_area_mm2": round(float(snap.contact_area_mm2), DECIMALS),
            "channels_in_contact": int(snap.channels_in_contact),
            "peak_channel": snap.peak_channel,
            "peak_force_n": finite_or_none(snap.peak_force_n, DECIMALS),
            "poll_interval_s": round(float(snap.poll_interval_s), DECIMALS),
            "polls_total": counters.polls_total,
            "reads_total": counters.reads_total,
            "read_errors_total": read_errors,
            "rois": [roi_json(rounded_roi(r)) for r in snap.rois],
            "reference_total_force_n": reference,
        }  # fmt: skip
        if refs is not None:
            frame["reference_force_n"] = refs[lo : lo + n]
        out.append(frame)
    return out


def playback_frames(
    snapshots: Sequence[DeviceSnapshot],
    *,
    has_reference: bool,
    scale_max_n: float = 5.0,
    config: DeviceDescription | None = None,
    source: str = "",
    max_frames: int = MAX_FRAMES,
    samples_total: int | None = None,
) -> Playback:
    """The frames of ``snapshots`` (one device, time order) for the page. ``samples_total``:
    the record's device samples when ``snapshots`` are already those ``thin`` keeps of them
    (default: ``len(snapshots)``). ``ValueError`` for no snapshot at all (an empty record has
    nothing to show)."""
    if not snapshots:
        raise ValueError("no device sample to play back")
    names = {s.device for s in snapshots}
    if len(names) != 1:
        raise ValueError(f"one device per playback, got {sorted(names)}")
    frames = page_frames(
        [snapshots[k] for k in thin(len(snapshots), max_frames)], has_reference=has_reference
    )
    first, last = snapshots[0].timestamp_s, snapshots[-1].timestamp_s
    layout = layout_json(snapshots[0], scale_max_n, config)
    total = len(snapshots) if samples_total is None else samples_total
    return Playback(layout, frames, float(first), float(last), has_reference, source, total)


def _json(data: Any) -> web.Response:
    body = json.dumps(data, separators=(",", ":"), allow_nan=False).encode()
    return web.Response(body=body, headers={"Content-Type": "application/json"})


class PlaybackPage:
    """The page and a read-only API over one ``Playback``."""

    def __init__(self, playback: Playback) -> None:
        self.playback = playback
        p = playback
        self._summary = {
            "source": p.source,
            "start_s": finite_or_none(p.start_s, DECIMALS),
            "end_s": finite_or_none(p.end_s, DECIMALS),
            "n_frames": len(p.frames),
            "samples_total": p.samples_total,
            "has_reference": p.has_reference,
            **p.info,
        }
        entry = dict(p.layout)
        entry.update(up=True, seq=len(p.frames), stream_frames_dropped_total=0, playback=True)
        self._entry = entry
        body = {**self._summary, "device": p.layout["name"], "frames": p.frames}
        self._frames_body = compact_json(body)  # frames hold None, never NaN
        self.files = PageFiles()

    def install(self, app: web.Application) -> None:
        r = app.router
        self.files.install(app)
        r.add_get("/api/devices", self._devices)
        r.add_get("/api/devices/{name}", self._device)
        r.add_get("/api/playback", self._frames)
        r.add_get("/api/devices/{name}/export.csv", self._export)

    async def _devices(self, request: web.Request) -> web.Response:
        return _json({
            "devices": [self._entry],
            "clients": {"stream": 0, "page": 0},
            "playback": self._summary,
        })  # fmt: skip

    async def _device(self, request: web.Request) -> web.Response:
        if request.match_info["name"] != self._entry["name"]:
            raise web.HTTPNotFound()
        return _json(self._entry)

    async def _export(self, request: web.Request) -> web.Response:
        p = self.playback
        if request.match_info["name"] != self._entry["name"] or p.export_csv is None:
            raise web.HTTPNotFound()
        to_s = query_number(request, "to_s", p.end_s, "a time of the record in s")
        from_s = query_number(request, "from_s", p.start_s, "a time of the record in s")
        if from_s > to_s:
            raise web.HTTPBadRequest(
                text=f"from_s ({from_s:g}) is after to_s ({to_s:g}); allowed: from_s <= to_s\n"
            )
        text = await asyncio.get_running_loop().run_in_executor(None, p.export_csv, from_s, to_s)
        name = self._entry["name"]
        return web.Response(
            body=text.encode(),
            headers={"Content-Type": "text/csv; charset=utf-8",
                     "Content-Disposition": f'attachment; filename="{name}.csv"'},
        )  # fmt: skip

    async def _frames(self, request: web.Request) -> web.Response:
        return web.Response(body=self._frames_body, headers={"Content-Type": "application/json"})
