"""The page and the API on the gateway's HTTP server (aiohttp routes, all read-only).

``WebPage(hub).install(app)`` adds:

* ``/`` and ``/static/{file}``: the live pressure-map page (static files shipped in the
  package; strict Content-Security-Policy, no inline script or style);
* ``/api/devices``: every device with its layout, units, status labels and stream counters;
* ``/api/devices/{name}``: one device's layout; ``/api/devices/{name}/frame``: its latest
  frame;
* ``/api/devices/{name}/stream``: server-sent events, **every** poll of the device (``id``
  is the sequence number; a client that falls behind loses the oldest frames, sees a gap and
  each frame carries ``dropped``, its count of lost frames; the hub counts them per device);
* ``/api/live[?device=NAME...]``: server-sent events for the page, the newest frame of each
  device at most ``max_fps`` times a second (newest frame wins, no queue);
* ``/api/devices/{name}/history?seconds=S``: the hub's summaries of the device's last S
  seconds of polls (``web.history``; 404 when the hub keeps none);
* ``/api/devices/{name}/export.csv?from_s=A&to_s=B``: the readings the hub keeps between two
  host times (Unix s; default the last 10 s) as a record (``docs/record-format.md``), written
  by the ``export_csv`` it is given (the recorder's writer; 404 without one).

An event stream holds a connection for as long as it runs (the server keeps a share of its
connections for ``/metrics``); a write that a client does not take within
``write_timeout_s`` (it stopped reading: the socket's buffers are full) ends that stream and
closes its connection, counted in ``stalled_total``. An event stream's socket keeps at most
``STREAM_SEND_BUFFER_BYTES`` in the kernel (the kernel would otherwise grow it to megabytes
for a client that does not read): a stalled reader is found after that much, whatever the
frame rate, and holds no more memory.

The hub is attached to the server's loop while the application runs (``on_startup``) and
every stream is ended when it stops (``on_shutdown``), so a stop never waits on a client.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import socket
import time
from collections.abc import Callable, Iterable, Sequence
from importlib import resources
from typing import Any

from aiohttp import web

from ..runtime.snapshot import DeviceSnapshot
from .frames import DeviceDescription, encode_frame, layout_json, with_dropped
from .hub import FrameHub

#: The page's policy: nothing but its own files and its own API; no inline anything.
CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)
STATIC_FILES: dict[str, str] = {
    "index.html": "text/html; charset=utf-8",
    "app.js": "text/javascript; charset=utf-8",
    "regions.js": "text/javascript; charset=utf-8",
    "view.js": "text/javascript; charset=utf-8",
    "timeline.js": "text/javascript; charset=utf-8",
    "tools.js": "text/javascript; charset=utf-8",
    "style.css": "text/css; charset=utf-8",
}
KEEPALIVE_S = 15.0
#: polls reach the clients at most once in this (s); a frame waits at most this long, and only
#: when polls come faster (see ``_Paced``)
DRAIN_INTERVAL_S = 0.002
#: a stream's write not taken by the client within this ends the stream (a stalled reader)
WRITE_TIMEOUT_S = 10.0
#: the span an export gives without ``from_s`` (s before ``to_s``)
EXPORT_DEFAULT_S = 10.0
#: ``export_csv(device, snapshots)``: the record (CSV text) of a device's polls, oldest first
ExportCsv = Callable[[str, Sequence[DeviceSnapshot]], str]
#: an event stream's kernel send buffer (bytes; the kernel doubles it for its bookkeeping):
#: over a second of frames of a 64-channel array at 100 polls/s, far below the megabytes
#: the kernel's autotuning would let a stalled client hold
STREAM_SEND_BUFFER_BYTES = 128 * 1024
_SSE_HEADERS = {"Content-Type": "text/event-stream", "Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
_ENDED = (ConnectionError, RuntimeError)  # the client went away mid-write


class _Paced:
    """Runs the hub's hand-over (``FrameHub.drain``) on the server's loop at most once in
    ``interval_s``: a poll that comes later than that after the last hand-over is handed
    over at once; polls that come faster wait for the next one, together.

    Each hand-over wakes the loop, every stream client and their writes; at hundreds of
    polls a second doing it for each poll costs the poll loop a share of the interpreter.
    The hub asks again only after a hand-over has run, so polls in between cost nothing here."""

    def __init__(self, loop: asyncio.AbstractEventLoop, interval_s: float) -> None:
        self._loop = loop
        self.interval_s = interval_s
        self._last_s = -math.inf

    def schedule(self, drain: Callable[[], None]) -> None:
        """From any thread: run ``drain`` on the loop, now or at the interval's end."""
        self._loop.call_soon_threadsafe(self._due, drain)

    def _due(self, drain: Callable[[], None]) -> None:
        wait_s = self._last_s + self.interval_s - self._loop.time()
        if wait_s > 0:
            self._loop.call_later(wait_s, self._run, drain)
        else:
            self._run(drain)

    def _run(self, drain: Callable[[], None]) -> None:
        self._last_s = self._loop.time()
        drain()


class _Wake:
    """An event-stream client's wake-up: the hub sets it when a frame is offered (``set``),
    and a timer sets it with ``keepalive_due`` once nothing was written for ``keepalive_s``.

    The timer is one a client, re-armed only when it fires: a frame costs no timer or task
    (``asyncio.wait_for`` costs both, about 30 us a frame a client, which at hundreds of
    polls a second the poll loop pays in the interpreter's lock)."""

    def __init__(self, keepalive_s: float) -> None:
        self._loop = asyncio.get_running_loop()
        self._event = asyncio.Event()
        self.keepalive_s = keepalive_s
        self.keepalive_due = False
        self._last_write_s = self._loop.time()
        self._timer = self._loop.call_later(keepalive_s, self._tick)
        self._reminder: asyncio.TimerHandle | None = None

    def set(self) -> None:
        self._event.set()

    def remind(self, delay_s: float) -> None:
        """Be woken in ``delay_s`` at the latest (one timer: an earlier one stands)."""
        when_s = self._loop.time() + delay_s
        if self._reminder is not None:
            if self._reminder.when() <= when_s:
                return
            self._reminder.cancel()
        self._reminder = self._loop.call_at(when_s, self._remind_now)

    def _remind_now(self) -> None:
        self._reminder = None
        self._event.set()

    def wrote(self) -> None:
        """A write went out: the keepalive's clock starts again, and a reminder is spent."""
        self._last_write_s = self._loop.time()
        self.keepalive_due = False
        if self._reminder is not None:
            self._reminder.cancel()
            self._reminder = None

    async def wait(self) -> None:
        """Until a frame is offered, the stream is closed or a keepalive is due."""
        await self._event.wait()
        self._event.clear()

    def _tick(self) -> None:
        idle_s = self._loop.time() - self._last_write_s
        if idle_s >= self.keepalive_s:
            self.keepalive_due = True
            self._event.set()
            idle_s = 0.0
        self._timer = self._loop.call_later(self.keepalive_s - idle_s, self._tick)

    def close(self) -> None:
        self._timer.cancel()
        if self._reminder is not None:
            self._reminder.cancel()


def _json(data: Any, status: int = 200) -> web.Response:
    body = json.dumps(data, separators=(",", ":"), allow_nan=False).encode()
    return web.Response(status=status, body=body, headers={"Content-Type": "application/json"})


def query_number(request: web.Request, key: str, default: float, allowed: str) -> float:
    """The finite number ``key`` of the query, or ``default``; 400 naming it otherwise."""
    raw = request.query.get(key)
    if raw is None:
        return float(default)
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise web.HTTPBadRequest(text=f"{key}: {raw[:40]!r} is not a number; allowed: {allowed}\n")
    return value


class PageFiles:
    """The page's static files (``STATIC_FILES``, read once) at ``/`` and ``/static/...``, and
    the security headers of every response but ``/metrics`` (the live page and playback)."""

    def __init__(self) -> None:
        self._files = {name: resources.files(__package__).joinpath("static", name).read_bytes()
                       for name in STATIC_FILES}  # fmt: skip

    def install(self, app: web.Application) -> None:
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{file}", self._static)
        app.on_response_prepare.append(self._policy)

    async def _policy(self, request: web.Request, response: web.StreamResponse) -> None:
        if request.path != "/metrics":
            response.headers["Content-Security-Policy"] = CSP
            response.headers["X-Content-Type-Options"] = "nosniff"
            response.headers.setdefault("Referrer-Policy", "no-referrer")

    def _file(self, name: str) -> web.Response:
        return web.Response(body=self._files[name], headers={"Content-Type": STATIC_FILES[name],
                                                             "Cache-Control": "no-cache"})  # fmt: skip

    async def _index(self, request: web.Request) -> web.Response:
        return self._file("index.html")

    async def _static(self, request: web.Request) -> web.Response:
        name = request.match_info["file"]
        if name not in STATIC_FILES:
            raise web.HTTPNotFound()
        return self._file(name)


class WebPage:
    """The pressure-map page and its API over a ``FrameHub``."""

    def __init__(
        self,
        hub: FrameHub,
        *,
        max_fps: float = 30.0,
        scale_max_n: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
        write_timeout_s: float = WRITE_TIMEOUT_S,
        keepalive_s: float = KEEPALIVE_S,
        drain_interval_s: float = DRAIN_INTERVAL_S,
        device_configs: Callable[[], Iterable[DeviceDescription]] | None = None,
        what_is_on: Callable[[str], list[str]] | None = None,
        export_csv: ExportCsv | None = None,
    ) -> None:
        self.hub = hub
        #: writes an export in the record format (``analysis.recorder.export_record``)
        self.export_csv = export_csv
        #: a device's "what is on" lines (values, force, drift correction and its clock,
        #: parameters, assumptions, writes), as check-config prints them
        self.what_is_on = what_is_on
        #: the devices' configurations as now in force (a reload changes them), for what the
        #: frames do not carry: disabled channels and the layout's cell area
        self.device_configs = device_configs
        self.write_timeout_s = write_timeout_s
        #: an idle event stream gets a comment line after this long without a write (s)
        self.keepalive_s = keepalive_s
        #: the hub hands polls to the clients at most once in this (s): see ``_Paced``
        self.drain_interval_s = drain_interval_s
        #: streams ended because their client stopped reading
        self.stalled_total = 0
        self.max_fps = max_fps
        self.scale_max_n = scale_max_n
        self._clock = clock
        self.files = PageFiles()

    def install(self, app: web.Application) -> None:
        r = app.router
        self.files.install(app)
        r.add_get("/api/devices", self._devices)
        r.add_get("/api/devices/{name}", self._device)
        r.add_get("/api/devices/{name}/frame", self._frame)
        r.add_get("/api/devices/{name}/stream", self._stream)
        r.add_get("/api/live", self._live)
        r.add_get("/api/devices/{name}/history", self._history)
        r.add_get("/api/devices/{name}/export.csv", self._export)
        app.on_startup.append(self._attach)
        app.on_shutdown.append(self._close)
        app.on_cleanup.append(self._detach)

    # ------------------------------------------------------------------ lifecycle
    async def _attach(self, app: web.Application) -> None:
        self.hub.attach(_Paced(asyncio.get_running_loop(), self.drain_interval_s).schedule)

    async def _close(self, app: web.Application) -> None:
        self.hub.close_all()

    async def _detach(self, app: web.Application) -> None:
        self.hub.detach()

    # ------------------------------------------------------------------ API
    def _describe(self, name: str) -> dict[str, Any] | None:
        entry = self.hub.latest(name)
        if entry is None:
            return None
        config = None
        if self.device_configs is not None:
            config = next((c for c in self.device_configs() if c.name == name), None)
        out = layout_json(entry.snapshot, self.scale_max_n, config)
        out.update(
            up=entry.snapshot.up if entry.seq else None,  # None: no poll of it has completed yet
            seq=entry.seq,
            stream_frames_dropped_total=self.hub.dropped_total.get(name, 0),
            what_is_on=self.what_is_on(name) if self.what_is_on is not None else [],
            history_s=self.hub.history_s,
            export_s=self.hub.export_s if self.export_csv is not None else 0.0,
        )
        return out

    async def _devices(self, request: web.Request) -> web.Response:
        names = [e.snapshot.device for e in self.hub.devices()]
        streams, pages = self.hub.clients()
        return _json({
            "devices": [d for n in names if (d := self._describe(n)) is not None],
            "clients": {"stream": streams, "page": pages},
            "max_fps": self.max_fps,
        })  # fmt: skip

    async def _device(self, request: web.Request) -> web.Response:
        described = self._describe(request.match_info["name"])
        if described is None:
            raise web.HTTPNotFound()
        return _json(described)

    async def _frame(self, request: web.Request) -> web.Response:
        entry = self.hub.latest(request.match_info["name"])
        if entry is None:
            raise web.HTTPNotFound()
        if entry.seq == 0:  # no poll of it has completed yet: no frame, and not an outage
            retry = str(max(1, math.ceil(entry.snapshot.poll_interval_s)))
            raise web.HTTPServiceUnavailable(text="no poll of this device has completed yet\n",
                                             headers={"Retry-After": retry})  # fmt: skip
        body = encode_frame(entry.snapshot, entry.seq, entry.counters)
        return web.Response(body=body, headers={"Content-Type": "application/json"})

    async def _history(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        past = self.hub.history(name)
        if past is None or past.history_s <= 0:
            if self.hub.latest(name) is None:
                raise web.HTTPNotFound(text=f"no device {name!r}\n")
            raise web.HTTPNotFound(text="this gateway keeps no history ([web] history_s = 0)\n")
        seconds = query_number(request, "seconds", past.history_s, f"0 < seconds <= {past.history_s:g}")
        if seconds <= 0.0:
            raise web.HTTPBadRequest(text=f"seconds: {seconds!r} is out of range; allowed: 0 < seconds\n")
        points = past.points(min(seconds, past.history_s))
        return _json({"device": name, "history_s": past.history_s,
                      "points": [past.json_point(p) for p in points]})  # fmt: skip

    async def _export(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        past = self.hub.history(name)
        if self.export_csv is None or past is None or past.export_s <= 0:
            if self.hub.latest(name) is None:
                raise web.HTTPNotFound(text=f"no device {name!r}\n")
            raise web.HTTPNotFound(text="this gateway keeps no readings to export ([web] export_s = 0)\n")
        newest = past.newest_s()
        to_s = query_number(
            request, "to_s", newest if newest is not None else time.time(), "a Unix time in s"
        )
        from_s = query_number(request, "from_s", to_s - EXPORT_DEFAULT_S, "a Unix time in s")
        if from_s > to_s:
            raise web.HTTPBadRequest(
                text=f"from_s ({from_s:g}) is after to_s ({to_s:g}); allowed: from_s <= to_s\n"
            )
        # a worker thread writes it (up to a million readings): the loop keeps serving streams
        loop = asyncio.get_running_loop()
        chosen, write = past.export(from_s, to_s), self.export_csv
        text = await loop.run_in_executor(None, lambda: write(name, past.snapshots(chosen)))
        return web.Response(
            body=text.encode(),
            headers={"Content-Type": "text/csv; charset=utf-8",
                     "Content-Disposition": f'attachment; filename="{name}.csv"'},
        )  # fmt: skip

    async def _open_events(self, resp: web.StreamResponse, request: web.Request) -> None:
        sock = request.transport.get_extra_info("socket") if request.transport is not None else None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STREAM_SEND_BUFFER_BYTES)
        await resp.prepare(request)
        await self._write(resp, request, b"retry: 1000\n\n")

    async def _write(self, resp: web.StreamResponse, request: web.Request, chunk: bytes) -> None:
        """Write, or end the stream (``ConnectionError``) if the client does not take it in time.

        A chunk that fits in the transport's buffer below its high-water mark cannot hold the
        writer up (aiohttp waits only while the transport is paused, above that mark), so it is
        written without a timer: at hundreds of frames a second a timer a write costs the poll
        loop its share of the interpreter."""
        transport = request.transport
        if transport is not None and not transport.is_closing():
            high_water = transport.get_write_buffer_limits()[1]
            if transport.get_write_buffer_size() + len(chunk) <= high_water:
                await resp.write(chunk)
                return
        try:
            async with asyncio.timeout(self.write_timeout_s):
                await resp.write(chunk)
        except TimeoutError:
            self.stalled_total += 1
            if request.transport is not None:
                request.transport.abort()
            raise ConnectionAbortedError("the client stopped reading") from None

    async def _stream(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        if self.hub.latest(name) is None:
            raise web.HTTPNotFound()
        wake = _Wake(self.keepalive_s)
        q = self.hub.open_stream(name, wake.set)
        resp = web.StreamResponse(headers=_SSE_HEADERS)
        try:
            await self._open_events(resp, request)
            wake.wrote()
            while not q.closed:
                await wake.wait()
                frames = q.take()
                if frames:
                    chunk = b"".join(b"id: %d\nevent: frame\ndata: %s\n\n" % (seq, with_dropped(f, q.dropped))
                                     for seq, f in frames)  # fmt: skip
                elif wake.keepalive_due:
                    chunk = b": keepalive\n\n"
                else:
                    continue
                await self._write(resp, request, chunk)
                wake.wrote()
        except _ENDED:
            pass
        finally:
            wake.close()
            self.hub.close_stream(q)
        return resp

    async def _live(self, request: web.Request) -> web.StreamResponse:
        wanted = frozenset(request.query.getall("device", [])) or None
        wake = _Wake(self.keepalive_s)

        def offered() -> None:
            """A frame is offered (or the page closed): wake the sender if it may send now,
            else have it woken when it may (one timer; frames offered meanwhile replace it)."""
            wait = p.wait_s(self._clock())
            if p.closed or wait is None or wait <= 0.0:
                wake.set()
            else:
                wake.remind(wait)

        p = self.hub.open_page(wanted, self.max_fps, offered)
        for entry in self.hub.devices():  # draw at once, then follow
            if entry.seq:  # a device whose first poll has not completed has no frame yet
                p.offer(entry.snapshot.device, encode_frame(entry.snapshot, entry.seq, entry.counters))
        resp = web.StreamResponse(headers=_SSE_HEADERS)
        try:
            await self._open_events(resp, request)
            wake.wrote()
            while not p.closed:
                await wake.wait()
                wait = p.wait_s(self._clock())
                if wait is None:
                    if wake.keepalive_due:
                        await self._write(resp, request, b": keepalive\n\n")
                        wake.wrote()
                    continue
                if wait > 0.0:  # woken before it may send (a keepalive's tick)
                    wake.remind(wait)
                    continue
                frames = p.take(self._clock())
                await self._write(resp, request, b"".join(b"event: frame\ndata: %s\n\n" % f for f in frames))
                wake.wrote()
        except _ENDED:
            pass
        finally:
            wake.close()
            self.hub.close_page(p)
        return resp
