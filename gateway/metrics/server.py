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
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
from collections.abc import Awaitable, Callable

from aiohttp import web
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from .web_config import BasicAuth, WebConfig

log = logging.getLogger(__name__)

Install = Callable[[web.Application], None]
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]

_TEXT = "text/plain; charset=utf-8"
_INDEX = b'<html><body><h1>tactile-gateway</h1><a href="/metrics">metrics</a></body></html>\n'
#: how long a stop waits for open responses (long-lived streams are ended first)
SHUTDOWN_TIMEOUT_S = 2.0


def _text(status: int, body: bytes, extra: dict[str, str] | None = None) -> web.Response:
    return web.Response(status=status, body=body, headers={"Content-Type": _TEXT, **(extra or {})})


class MetricsServer:
    """Serves ``registry`` on ``http(s)://host:port/metrics`` from a background thread."""

    def __init__(
        self,
        registry: CollectorRegistry,
        host: str = "127.0.0.1",
        port: int = 9830,
        web_config: WebConfig | None = None,
        install: Install | None = None,
    ) -> None:
        self.registry = registry
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
        """Basic auth on every path; our plain 404 and 405 for paths we do not serve."""
        if self._auth is not None:
            header = request.headers.get("Authorization")
            # bcrypt costs milliseconds: checked off the loop (verified pairs are cached)
            ok = await asyncio.get_running_loop().run_in_executor(None, self._auth.check, header)
            if not ok:
                return _text(401, b"Unauthorized\n", {"WWW-Authenticate": 'Basic realm="tactile-gateway"'})
        if request.method not in ("GET", "HEAD"):
            return _text(405, b"Method not allowed\n", {"Allow": "GET, HEAD"})
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
            body = await asyncio.get_running_loop().run_in_executor(None, generate_latest, self.registry)
        except Exception:
            log.exception("building the metrics failed")
            return _text(500, b"metrics collection failed\n")
        return web.Response(body=body, headers={"Content-Type": CONTENT_TYPE_LATEST})

    async def _index(self, request: web.Request) -> web.Response:
        return web.Response(body=_INDEX, headers={"Content-Type": "text/html; charset=utf-8"})

    # ------------------------------------------------------------------ the thread
    async def _serve(self, ready: threading.Event, failure: list[BaseException]) -> None:
        self._stopping = asyncio.Event()
        runner = web.AppRunner(self._app(), access_log=None, handle_signals=False,
                               shutdown_timeout=SHUTDOWN_TIMEOUT_S)  # fmt: skip
        try:
            await runner.setup()
            site = web.SockSite(runner, self._sock, ssl_context=self._ssl)
            await site.start()
        except BaseException as exc:
            failure.append(exc)
            ready.set()
            await runner.cleanup()
            return
        ready.set()
        try:
            await self._stopping.wait()
        finally:
            await runner.cleanup()

    def _run(self, ready: threading.Event, failure: list[BaseException]) -> None:
        loop = self._loop
        assert loop is not None
        try:
            loop.run_until_complete(self._serve(ready, failure))
            loop.run_until_complete(loop.shutdown_default_executor())
        finally:
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

    def __enter__(self) -> MetricsServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
