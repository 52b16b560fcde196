"""The /metrics HTTP server: a registry served from a thread, with optional TLS and basic auth.

``MetricsServer`` serves ``http(s)://host:port/metrics`` with ``http.server`` threads; a
``WebConfig`` (``web_config.load_web_config``) adds TLS (the handshake runs in the handler
thread, so a slow client cannot block accept) and HTTP basic auth.
"""

from __future__ import annotations

import logging
import socket
import ssl
import sys
import threading
from collections.abc import Mapping
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from .web_config import BasicAuth, WebConfig

log = logging.getLogger(__name__)


class _Server(ThreadingHTTPServer):
    # handler threads are joined by server_close (each is bounded by the handler timeout)
    daemon_threads = False
    block_on_close = True
    allow_reuse_address = True
    ssl_context: ssl.SSLContext | None = None

    def handle_error(self, request: Any, client_address: Any) -> None:
        exc = sys.exc_info()[1]
        if isinstance(exc, ssl.SSLError | ConnectionError | TimeoutError):
            # failed handshakes, plain HTTP on a TLS port, clients that hang up
            log.debug("http %s: %s", client_address[0], exc)
        else:
            log.error("http %s: error while serving", client_address[0], exc_info=exc)

    def get_request(self) -> tuple[socket.socket, Any]:
        sock, addr = super().get_request()
        if self.ssl_context is not None:
            # the handshake runs in the handler thread, so a slow client cannot block accept
            sock = self.ssl_context.wrap_socket(sock, server_side=True, do_handshake_on_connect=False)
        return sock, addr


class MetricsServer:
    """Serves ``registry`` on ``http(s)://host:port/metrics`` from a background thread."""

    def __init__(
        self,
        registry: CollectorRegistry,
        host: str = "127.0.0.1",
        port: int = 9830,
        web_config: WebConfig | None = None,
    ) -> None:
        self.registry = registry
        self.web_config = web_config or WebConfig()
        self._auth = BasicAuth(self.web_config.basic_auth_users) if self.web_config.basic_auth_users else None
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        server_cls = type("_BoundServer", (_Server,), {"address_family": family})
        self._httpd: _Server = server_cls((host, port), self._handler_class())
        self._httpd.ssl_context = self.web_config.ssl_context()
        self._thread: threading.Thread | None = None

    @property
    def host(self) -> str:
        return str(self._httpd.server_address[0])

    @property
    def port(self) -> int:
        return int(self._httpd.server_address[1])

    @property
    def url(self) -> str:
        scheme = "https" if self.web_config.tls else "http"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{scheme}://{host}:{self.port}/metrics"

    def _handler_class(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "tactile-gateway"
            timeout = 10.0

            def log_message(self, format: str, *args: Any) -> None:
                log.debug("http %s - " + format, self.client_address[0], *args)

            def _send(self, code: int, body: bytes, content_type: str, extra: Mapping[str, str] = {}) -> None:
                self.send_response(code)
                self.send_header("Content-Type", content_type)
                self.send_header("Content-Length", str(len(body)))
                for k, v in {**server.web_config.headers, **extra}.items():
                    self.send_header(k, v)
                self.end_headers()
                if self.command != "HEAD":
                    self.wfile.write(body)

            def do_GET(self) -> None:
                if server._auth is not None and not server._auth.check(self.headers.get("Authorization")):
                    self._send(
                        401,
                        b"Unauthorized\n",
                        "text/plain; charset=utf-8",
                        {"WWW-Authenticate": 'Basic realm="tactile-gateway"'},
                    )
                    return
                path = self.path.split("?", 1)[0]
                if path == "/metrics":
                    try:
                        body = generate_latest(server.registry)
                    except Exception:
                        log.exception("building the metrics failed")
                        self._send(500, b"metrics collection failed\n", "text/plain; charset=utf-8")
                        return
                    self._send(200, body, CONTENT_TYPE_LATEST)
                elif path == "/":
                    page = (
                        b'<html><body><h1>tactile-gateway</h1><a href="/metrics">metrics</a></body></html>\n'
                    )
                    self._send(200, page, "text/html; charset=utf-8")
                else:
                    self._send(404, b"Not found\n", "text/plain; charset=utf-8")

            do_HEAD = do_GET

        return Handler

    def start(self) -> MetricsServer:
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._httpd.serve_forever,
                kwargs={"poll_interval": 0.2},
                name="tactile-metrics",
                daemon=True,
            )
            self._thread.start()
            log.info("serving metrics on %s", self.url)
        return self

    def stop(self) -> None:
        """Stop serving and close the socket; joins the server thread."""
        if self._thread is not None:
            self._httpd.shutdown()
            self._thread.join(timeout=5.0)
            self._thread = None
        self._httpd.server_close()

    def __enter__(self) -> MetricsServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
