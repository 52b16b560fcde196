"""The HTTP server of the gateway: ``/metrics`` (and the page, when one is installed), served
by aiohttp from a thread of its own, with optional TLS and basic auth.

``MetricsServer`` binds ``host:port`` when it is built (so a taken port is an ``OSError``
right away and ``port`` is known for port 0), then runs an aiohttp application on its own
event loop in the thread ``tactile-metrics``: the poller's loop never waits for a client. A
``WebConfig`` (``web_config.load_web_config``) adds TLS (handshakes run in that loop, so a
slow client cannot block others) and HTTP basic auth, which guards every path. The headers
of the web config go on every response. ``/metrics`` is built in a worker thread of that
loop and sent as ``prometheus_client.generate_latest`` gives it, byte for byte.

An ``install`` callable (``gateway.web.WebPage.install``) adds routes to the application,
e.g. the live pressure-map page; without one ``/`` is a link to ``/metrics``.

Hostile or clumsy clients are bounded: at most ``max_connections`` connections are served at
once. At that limit a new connection makes room by closing the oldest connection that has no
request in progress (one still sending its request head, or an idle keep-alive one), so slow
heads cannot starve a scraper, whose head comes at once; only when every connection has a
request in progress does a new one get a 503 and is closed (a warning is logged once when the
limit is reached, and a line when it is left); a connection that has not sent a complete
request head within ``header_timeout_s`` (and an idle keep-alive connection after as long) is
closed, and so is a TLS handshake not done by then. Connections cost no threads: the server
has one thread for its loop, two workers (``/metrics``, the page's blocking work) and one
for bcrypt, so a flood of wrong passwords keeps at most one core busy. bcrypt checks are
queued per client address and taken from the addresses in turn (``auth_queue.FairChecks``):
at most ``auth_queue`` wait or run at once, and beyond that only an address with no check
waiting is admitted (up to ``AUTH_HARD_LIMIT`` in all); a request that would be one more is
answered 503 with ``Retry-After`` at once. So a flood from any number of connections of a
few addresses never refuses a scraper from another address, which waits behind at most one
check per flooding address. A scraper whose credentials were verified before is answered
without waiting for that queue at all.

Requests to anything but ``/metrics`` (the page and its server-sent event streams, which
last) are served at most ``page_slots`` at once (``max_connections`` less a
``RESERVED_SHARE``); one more is answered 503 with ``Retry-After`` and its connection closed,
so stalled or endless stream clients never take the connections ``/metrics`` needs.

A malformed request (a request line or header over 8 KiB, too many headers, Content-Length
with Transfer-Encoding, TLS on the plain port...) is answered 400 by aiohttp and counted by
cause in ``tactile_http_bad_requests_total``; the log gets one line per cause at most every
``BAD_REQUEST_LOG_INTERVAL_S`` (with the count of those not logged), never a traceback.
Refusals are counted in ``tactile_http_refused_total`` by reason.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import socket
import threading
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from aiohttp import web
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from ..runtime.priority import yield_to_poll_loop
from .auth_queue import FairChecks
from .http_log import BAD_REQUEST_LOG_INTERVAL_S, REFUSED_REASONS, HttpCounters, RequestLog, bad_request_cause
from .web_config import BasicAuth, WebConfig

log = logging.getLogger(__name__)

__all__ = [
    "BAD_REQUEST_LOG_INTERVAL_S",
    "REFUSED_REASONS",
    "HttpCounters",
    "MetricsServer",
    "RequestLog",
    "bad_request_cause",
    "busy",
]

Install = Callable[[web.Application], None]
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]

_TEXT = "text/plain; charset=utf-8"
_INDEX = b'<html><body><h1>tactile-gateway</h1><a href="/metrics">metrics</a></body></html>\n'
#: how long a stop waits for open responses (long-lived streams are ended first)
SHUTDOWN_TIMEOUT_S = 2.0
#: connections served at once (well under the usual 1024 open files); more get a 503 and are closed
MAX_CONNECTIONS = 512
#: a request head (or a TLS handshake) must arrive within this; idle keep-alive is closed after it
HEADER_TIMEOUT_S = 10.0
#: worker threads of the server's loop (``/metrics`` bodies, blocking work of the page)
WORKERS = 2
#: bcrypt checks running or waiting at once, served first come first served; one more is
#: answered 503 with Retry-After. A connection has one request at a time, so under a flood
#: of fewer connections a scraper waits behind at most that many checks, and behind 32 at
#: most 32 x 0.3 s (``web_config.MAX_BCRYPT_COST``), inside a 10 s scrape timeout
AUTH_QUEUE = 32
#: checks waiting or running at once, counting those of addresses admitted past a full
#: ``AUTH_QUEUE`` (each with no other check waiting): a lock-out needs this many less
#: ``AUTH_QUEUE`` distinct flooding addresses
AUTH_HARD_LIMIT = 128
#: the share of ``max_connections`` long-lived (server-sent events) responses may not take
RESERVED_SHARE = 0.25
#: how long a refused connection is drained before it is closed
_REFUSED_LINGER_S = 1.0
_BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\n"
    b"Content-Length: 21\r\nRetry-After: 5\r\nConnection: close\r\nServer: tactile-gateway\r\n\r\n"
    b"too many connections\n"
)


def _text(status: int, body: bytes, extra: dict[str, str] | None = None) -> web.Response:
    return web.Response(status=status, body=body, headers={"Content-Type": _TEXT, **(extra or {})})


def busy(body: bytes) -> web.Response:
    """A 503 with ``Retry-After`` that closes its connection (the slot is free at once)."""
    resp = _text(503, body, {"Retry-After": "1"})
    resp.force_close()
    return resp


class _Limited(asyncio.Protocol):
    """One connection: handed to aiohttp's protocol if the server admits it; else a 503, the
    write side shut and what the client sends discarded (closing with unread data would reset
    the connection before the client reads the 503) for at most ``_REFUSED_LINGER_S``."""

    __slots__ = ("_factory", "_inner", "_linger", "_owner", "_transport")

    def __init__(self, owner: MetricsServer, factory: Callable[[], asyncio.Protocol]) -> None:
        self._owner = owner
        self._factory = factory
        self._inner: asyncio.Protocol | None = None
        self._linger: asyncio.TimerHandle | None = None
        self._transport: asyncio.BaseTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if not self._owner._admit(transport):
            assert isinstance(transport, asyncio.WriteTransport)
            self._owner.counters.refuse("connections")
            try:
                transport.write(_BUSY)
                if transport.can_write_eof():
                    transport.write_eof()
                    self._linger = asyncio.get_running_loop().call_later(_REFUSED_LINGER_S, transport.close)
                else:
                    transport.close()
            except Exception:  # the client is gone already
                transport.abort()
            return
        self._transport = transport
        self._inner = self._factory()
        self._inner.connection_made(transport)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._linger is not None:
            self._linger.cancel()
            self._linger = None
        inner, self._inner = self._inner, None
        if inner is not None:
            self._owner._release(self._transport)
            inner.connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._inner is not None:
            self._inner.data_received(data)

    def eof_received(self) -> bool | None:
        # refused: False closes the transport
        return self._inner.eof_received() if self._inner is not None else False

    def pause_writing(self) -> None:
        if self._inner is not None:
            self._inner.pause_writing()

    def resume_writing(self) -> None:
        if self._inner is not None:
            self._inner.resume_writing()


class MetricsServer:
    """Serves ``registry`` on ``http(s)://host:port/metrics`` from a background thread."""

    def __init__(
        self,
        registry: CollectorRegistry,
        host: str = "127.0.0.1",
        port: int = 9830,
        web_config: WebConfig | None = None,
        install: Install | None = None,
        *,
        max_connections: int = MAX_CONNECTIONS,
        header_timeout_s: float = HEADER_TIMEOUT_S,
        auth_queue: int = AUTH_QUEUE,
        yield_to_polling: bool = False,
    ) -> None:
        self.registry = registry
        #: the server's thread yields the CPU to the poll loop (a fast bus: ``runtime.priority``)
        self.yield_to_polling = yield_to_polling
        self.max_connections = max_connections
        self.header_timeout_s = header_timeout_s
        self.auth_queue = auth_queue
        #: the bcrypt checks queued or running (made on the server's loop, with its thread)
        self._auth_checks: FairChecks | None = None
        #: the request tasks awaiting a check (the server's loop only)
        self._auth_waiting: set[asyncio.Task[Any]] = set()
        self.counters = HttpCounters()
        self._request_log = RequestLog(self.counters)
        #: requests to anything but /metrics (the page, its event streams) served at once; the
        #: rest of the connections are kept for /metrics
        self.page_slots = max(1, max_connections - max(1, int(max_connections * RESERVED_SHARE)))
        self._page_busy = 0  # such requests being served (the server's loop only)
        self._open = 0  # admitted connections (touched on the server's loop only)
        #: admitted connections with no request in progress (mid-head, or idle keep-alive),
        #: oldest first: the first closed at the limit (the server's loop only)
        self._idle: dict[asyncio.BaseTransport, None] = {}
        self._refused = 0
        self._at_limit = False
        self.web_config = web_config or WebConfig()
        self._auth = BasicAuth(self.web_config.basic_auth_users) if self.web_config.basic_auth_users else None
        self._install = install
        self._ssl = self.web_config.ssl_context()
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
            sock.listen(128)
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        self._sock = sock
        self._address = sock.getsockname()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._auth_pool: ThreadPoolExecutor | None = None
        self._registered = False  # self.counters in the registry (while serving)

    @property
    def auth_pending(self) -> int:
        """bcrypt checks waiting or running now."""
        return self._auth_checks.pending if self._auth_checks is not None else 0

    @property
    def open_connections(self) -> int:
        """Connections being served now."""
        return self._open

    @property
    def host(self) -> str:
        return str(self._address[0])

    @property
    def port(self) -> int:
        return int(self._address[1])

    @property
    def base_url(self) -> str:
        """``http(s)://host:port`` (no path)."""
        scheme = "https" if self.web_config.tls else "http"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{scheme}://{host}:{self.port}"

    @property
    def url(self) -> str:
        return self.base_url + "/metrics"

    @property
    def page_url(self) -> str | None:
        """The address of the page, or None when no page is installed."""
        return self.base_url + "/" if self._install is not None else None

    # ------------------------------------------------------------------ the application
    def _app(self) -> web.Application:
        app = web.Application(middlewares=[self._guard])
        app.router.add_get("/metrics", self._metrics)
        if self._install is not None:
            self._install(app)
        else:
            app.router.add_get("/", self._index)
        app.on_response_prepare.append(self._headers)
        return app

    @web.middleware
    async def _guard(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """A request in progress: its connection is not closed to make room at the limit."""
        transport = request.transport
        if transport is None:
            return await self._guarded(request, handler)
        self._idle.pop(transport, None)
        try:
            return await self._guarded(request, handler)
        finally:
            if not transport.is_closing():
                self._idle[transport] = None  # idle keep-alive again, the newest

    async def _guarded(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """Basic auth on every path; our plain 404 and 405 for paths we do not serve."""
        if self._auth is not None:
            header = request.headers.get("Authorization")
            # a verified pair is cached (cheap); bcrypt costs up to ~0.3 s: one thread of its own
            ok = self._auth.cached(header)
            if not ok:
                checks, address = self._auth_checks, request.remote or ""
                assert checks is not None  # made with the loop
                if not checks.admits(address):  # refuse at once rather than queue
                    self.counters.refuse("auth_queue")
                    return busy(b"too many logins being checked\n")
                auth, task = self._auth, asyncio.current_task()
                if task is not None:
                    self._auth_waiting.add(task)
                try:
                    ok = await checks.check(address, functools.partial(auth.check, header))
                except Exception as exc:  # never expected; a client must not be able to fill the log
                    log.debug("basic auth check failed: %r", exc)
                    ok = False
                finally:
                    self._auth_waiting.discard(task)
            if not ok:
                return _text(401, b"Unauthorized\n", {"WWW-Authenticate": 'Basic realm="tactile-gateway"'})
        if request.method not in ("GET", "HEAD"):
            return _text(405, b"Method not allowed\n", {"Allow": "GET, HEAD"})
        if request.path == "/metrics":
            return await self._handle(request, handler)
        if self._page_busy >= self.page_slots:  # event streams last: keep a share for /metrics
            self.counters.refuse("streams")
            return busy(b"too many page and stream requests\n")
        self._page_busy += 1
        try:
            return await self._handle(request, handler)
        finally:
            self._page_busy -= 1

    @staticmethod
    async def _handle(request: web.Request, handler: Handler) -> web.StreamResponse:
        try:
            return await handler(request)
        except web.HTTPNotFound:
            return _text(404, b"Not found\n")
        except web.HTTPMethodNotAllowed:
            return _text(405, b"Method not allowed\n", {"Allow": "GET, HEAD"})

    async def _headers(self, request: web.Request, response: web.StreamResponse) -> None:
        response.headers["Server"] = "tactile-gateway"
        for k, v in self.web_config.headers.items():
            response.headers[k] = v

    async def _metrics(self, request: web.Request) -> web.Response:
        try:
            render = getattr(self.registry, "render", None)  # a SnapshotRegistry writes its own text
            loop = asyncio.get_running_loop()
            if render is not None:
                body = await loop.run_in_executor(None, render)
            else:
                body = await loop.run_in_executor(None, generate_latest, self.registry)
        except Exception:
            log.exception("building the metrics failed")
            return _text(500, b"metrics collection failed\n")
        return web.Response(body=body, headers={"Content-Type": CONTENT_TYPE_LATEST})

    async def _index(self, request: web.Request) -> web.Response:
        return web.Response(body=_INDEX, headers={"Content-Type": "text/html; charset=utf-8"})

    # ------------------------------------------------------------------ connections
    def _admit(self, transport: asyncio.BaseTransport) -> bool:
        if self._open >= self.max_connections and self._idle:
            # slow or idle clients must not hold every slot: the oldest without a request in
            # progress makes room (a scraper's request head comes at once, then it is busy)
            oldest = next(iter(self._idle))
            del self._idle[oldest]
            self.counters.refuse("idle_closed")
            if isinstance(oldest, asyncio.WriteTransport):
                oldest.abort()  # its connection_lost releases the slot
            else:
                oldest.close()
        elif self._open >= self.max_connections:
            self._refused += 1
            if not self._at_limit:
                self._at_limit = True
                log.warning(
                    "metrics server: %d connections open, the limit; refusing new ones (503) until "
                    "some close (a client that sends no request for %g s is closed)",
                    self._open,
                    self.header_timeout_s,
                )
            return False
        self._open += 1
        self._idle[transport] = None
        return True

    def _release(self, transport: asyncio.BaseTransport | None) -> None:
        self._open -= 1
        if transport is not None:
            self._idle.pop(transport, None)
        if self._at_limit and self._open <= self.max_connections // 2:
            self._at_limit = False
            log.info(
                "metrics server: %d connections open, accepting again (%d refused at the limit)",
                self._open,
                self._refused,
            )
            self._refused = 0

    # ------------------------------------------------------------------ the thread
    async def _serve(self, ready: threading.Event, failure: list[BaseException]) -> None:
        self._stopping = asyncio.Event()
        # keepalive_timeout: aiohttp closes a connection waiting for a (complete) request head
        # that long after it opened or after its last response
        runner = web.AppRunner(self._app(), access_log=None, handle_signals=False,
                               shutdown_timeout=SHUTDOWN_TIMEOUT_S,
                               keepalive_timeout=self.header_timeout_s,
                               logger=self._request_log)  # fmt: skip
        listener: asyncio.AbstractServer | None = None
        try:
            await runner.setup()
            factory = runner.server
            assert factory is not None
            listener = await asyncio.get_running_loop().create_server(
                lambda: _Limited(self, factory),
                sock=self._sock,
                backlog=128,
                ssl=self._ssl,
                ssl_handshake_timeout=self.header_timeout_s if self._ssl is not None else None,
            )
        except BaseException as exc:
            failure.append(exc)
            ready.set()
            if listener is not None:
                listener.close()
            await runner.cleanup()
            return
        ready.set()
        try:
            await self._stopping.wait()
        finally:
            listener.close()
            await self._cancel_auth_checks()
            await runner.cleanup()

    async def _cancel_auth_checks(self) -> None:
        """Cancel the bcrypt checks queued or running and wait for the requests awaiting them
        to end. A request whose client has gone is no longer one of the connections the
        runner's clean-up waits for; left pending, its task would be destroyed with the loop."""
        waiting = list(self._auth_waiting)
        if self._auth_checks is not None:
            self._auth_checks.cancel_all()
        if waiting:
            await asyncio.wait(waiting)

    def _run(self, ready: threading.Event, failure: list[BaseException]) -> None:
        if self.yield_to_polling:
            yield_to_poll_loop()
        loop = self._loop
        assert loop is not None
        loop.set_default_executor(ThreadPoolExecutor(WORKERS, thread_name_prefix="tactile-metrics-worker"))
        self._auth_pool = ThreadPoolExecutor(1, thread_name_prefix="tactile-metrics-auth")
        hard_limit = max(self.auth_queue, AUTH_HARD_LIMIT)
        self._auth_checks = FairChecks(self._auth_pool, self.auth_queue, hard_limit)
        try:
            loop.run_until_complete(self._serve(ready, failure))
            loop.run_until_complete(loop.shutdown_default_executor())
        finally:
            self._auth_pool.shutdown(wait=True, cancel_futures=True)
            loop.close()

    def start(self) -> MetricsServer:
        if self._thread is None:
            ready = threading.Event()
            failure: list[BaseException] = []
            self._loop = asyncio.new_event_loop()
            self._thread = threading.Thread(
                target=self._run, args=(ready, failure), name="tactile-metrics", daemon=True
            )
            self._thread.start()
            ready.wait()
            if failure:
                self.stop()
                raise failure[0]
            self.registry.register(self.counters)
            self._registered = True
            log.info("serving metrics on %s", self.url)
        return self

    def stop(self) -> None:
        """Stop serving and close the socket; joins the server thread."""
        thread, loop = self._thread, self._loop
        if thread is not None and loop is not None:
            stopping = self._stopping
            if stopping is not None and not loop.is_closed():
                with contextlib.suppress(RuntimeError):  # the loop has already closed
                    loop.call_soon_threadsafe(stopping.set)
            thread.join(timeout=SHUTDOWN_TIMEOUT_S + 5.0)
        self._thread = None
        self._loop = None
        self._sock.close()
        if self._registered:
            self._registered = False
            with contextlib.suppress(KeyError):
                self.registry.unregister(self.counters)

    def __enter__(self) -> MetricsServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
