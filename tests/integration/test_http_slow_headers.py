"""Issue 33 §7, over real sockets on loopback: clients that send request heads slowly (and
reopen when closed) once held every connection slot, so ``/metrics`` answered 503. At the
connection limit the server now closes the oldest connection that has no request in
progress, so a scraper, whose request head comes at once, is served."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import aiohttp
import pytest
from prometheus_client import CollectorRegistry
from prometheus_client.parser import text_string_to_metric_families
from waiting import until

from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.runtime.poller import SnapshotHolder

LIMIT = 16
#: a request head that never ends (the blank line never comes)
SLOW_HEAD = b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: 1\r\n"


@pytest.fixture
def sockets() -> Iterator[list[socket.socket]]:
    socks: list[socket.socket] = []
    yield socks
    for s in socks:
        s.close()


def _refused(body: bytes) -> dict[str, float]:
    return {
        s.labels["reason"]: s.value
        for family in text_string_to_metric_families(body.decode())
        for s in family.samples
        if s.name == "tactile_http_refused_total"
    }


async def test_slow_request_heads_at_the_connection_limit_do_not_starve_metrics(
    sockets: list[socket.socket],
) -> None:
    registry = make_registry(SnapshotHolder().get, CollectorRegistry())
    server = MetricsServer(registry, "127.0.0.1", 0, max_connections=LIMIT, header_timeout_s=60.0)
    with server:
        for _ in range(3 * LIMIT):  # three times the limit, every one mid-head
            s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
            s.sendall(SLOW_HEAD)
            sockets.append(s)
        await until(lambda: server.open_connections >= LIMIT, 20, "the limit reached")
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(force_close=True)) as http:
            statuses = []
            for _ in range(10):
                for _ in range(LIMIT):  # the slow clients reopen as fast as they are closed
                    s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
                    s.sendall(SLOW_HEAD)
                    sockets.append(s)
                async with http.get(server.url) as resp:
                    body = await resp.read()
                    statuses.append(resp.status)
            assert statuses == [200] * 10, statuses
        # the slow ones were closed to make room, and counted
        assert _refused(body)["idle_closed"] >= LIMIT
        assert server.open_connections <= LIMIT + 1
