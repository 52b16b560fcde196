"""The HTTP server's counters and request log: malformed requests by cause, refusals by
reason (``tactile_http_bad_requests_total``, ``tactile_http_refused_total``), and the logger
aiohttp's handlers get, which logs a client's malformed request as one line per cause at most
every ``BAD_REQUEST_LOG_INTERVAL_S``, never a traceback."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from aiohttp.http_exceptions import (
    BadHttpMethod,
    BadStatusLine,
    HttpProcessingError,
    InvalidHeader,
    InvalidURLError,
    LineTooLong,
)
from prometheus_client.core import CounterMetricFamily, Metric

log = logging.getLogger("gateway.metrics.server")

#: a malformed request's cause is logged at most once per this (the rest are counted)
BAD_REQUEST_LOG_INTERVAL_S = 60.0
#: the reasons of ``tactile_http_refused_total``
REFUSED_REASONS = ("connections", "streams", "auth_queue", "idle_closed")


def bad_request_cause(exc: BaseException) -> str:
    """A short, bounded label for why aiohttp refused a request."""
    message = getattr(exc, "message", "") or ""
    if isinstance(exc, BadHttpMethod):
        return "tls_on_plain_http" if "HTTPS" in message else "bad_method"
    if isinstance(exc, LineTooLong):
        return "line_too_long"
    if isinstance(exc, InvalidURLError):
        return "bad_url"
    if isinstance(exc, BadStatusLine):
        return "bad_request_line"
    if isinstance(exc, InvalidHeader):
        return "bad_header"
    if "Too many headers" in message:
        return "too_many_headers"
    if "Transfer-Encoding" in message and "Content-Length" in message:
        return "content_length_and_transfer_encoding"
    return "bad_request"


class HttpCounters:
    """The server's counters and their collector: malformed requests by cause, refusals by
    reason. Counted on the server's loop, read by a scrape from a worker thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.bad_requests: dict[str, int] = {}
        self.refused: dict[str, int] = dict.fromkeys(REFUSED_REASONS, 0)

    def bad_request(self, cause: str) -> None:
        with self._lock:
            self.bad_requests[cause] = self.bad_requests.get(cause, 0) + 1

    def refuse(self, reason: str) -> None:
        with self._lock:
            self.refused[reason] += 1

    def collect(self) -> Iterator[Metric]:
        with self._lock:
            bad, refused = dict(self.bad_requests), dict(self.refused)
        family = CounterMetricFamily(
            "tactile_http_bad_requests",
            "Malformed requests the HTTP server answered 400 (or closed), by cause",
            labels=["cause"],
        )
        for cause in sorted(bad):
            family.add_metric([cause], bad[cause])
        yield family
        family = CounterMetricFamily(
            "tactile_http_refused",
            "Requests or connections the HTTP server refused with a 503, by reason (connections: "
            "the connection limit; streams: the share of the page and its event streams; "
            "auth_queue: the bcrypt queue; idle_closed: a connection with no request in progress, "
            "the oldest, closed at the connection limit to admit a new one)",
            labels=["reason"],
        )
        for reason in REFUSED_REASONS:
            family.add_metric([reason], refused[reason])
        yield family


class RequestLog:
    """The logger aiohttp's request handlers get: a malformed request (a client's fault) is
    counted and logged as one line per cause at most every ``interval_s`` (with the count of
    those not logged since), never with a traceback; anything else goes to aiohttp's logger."""

    def __init__(
        self,
        counters: HttpCounters,
        interval_s: float = BAD_REQUEST_LOG_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._counters = counters
        self._interval_s = interval_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self._unlogged: dict[str, int] = {}
        self._inner = logging.getLogger("aiohttp.server")

    def _client_error(self, kw: dict[str, Any]) -> HttpProcessingError | None:
        exc = kw.get("exc_info")
        return exc if isinstance(exc, HttpProcessingError) else None

    def _count(self, exc: HttpProcessingError, args: tuple[Any, ...]) -> None:
        cause = bad_request_cause(exc)
        self._counters.bad_request(cause)
        now = self._clock()
        last = self._last.get(cause)
        if last is not None and now - last < self._interval_s:
            self._unlogged[cause] = self._unlogged.get(cause, 0) + 1
            return
        self._last[cause] = now
        unlogged = self._unlogged.pop(cause, 0)
        remote = args[1] if len(args) > 1 else "?"
        detail = " ".join(str(exc.message).split())[:120]
        log.warning(
            "HTTP server: malformed request (%s) from %s answered %d: %s%s; this cause is logged "
            "at most every %g s (tactile_http_bad_requests_total counts each)",
            cause,
            remote,
            exc.code,
            detail,
            f" ({unlogged} more since the last line)" if unlogged else "",
            self._interval_s,
        )

    def exception(self, *args: Any, **kw: Any) -> None:
        exc = self._client_error(kw)
        if exc is not None:
            self._count(exc, args)
        else:
            self._inner.exception(*args, **kw)

    def debug(self, *args: Any, **kw: Any) -> None:
        exc = self._client_error(kw)
        if exc is not None:
            self._count(exc, args)
        else:
            self._inner.debug(*args, **kw)

    def __getattr__(self, name: str) -> Any:  # warning, info, isEnabledFor, ...
        return getattr(self._inner, name)
