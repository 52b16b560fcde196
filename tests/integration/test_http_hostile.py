"""Issue 24, hostile user, items 4-6, over real sockets on loopback: malformed requests are
counted and logged once per cause (no traceback flood), stalled event-stream clients neither
take the connections ``/metrics`` needs nor stay forever, and a flood of wrong passwords is
refused at once beyond a short bcrypt queue while verified scrapers pass."""

from __future__ import annotations

import asyncio
import base64
import dataclasses
import gc
import logging
import socket
import threading
from collections.abc import Iterator

import aiohttp
import bcrypt
import pytest
from prometheus_client import CollectorRegistry
from prometheus_client.parser import text_string_to_metric_families
from web_fixtures import first_poll, gateway_with_page, until

from gateway.metrics import server as server_module
from gateway.metrics.collector import make_registry
from gateway.metrics.server import AUTH_QUEUE, MetricsServer
from gateway.metrics.web_config import WebConfig
from gateway.runtime.poller import SnapshotHolder
from gateway.runtime.snapshot import GatewaySnapshot


def _exchange(port: int, data: bytes) -> bytes:
    """Send raw bytes, return all the server answers until it closes."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(data)
        chunks = []
        try:
            while chunk := s.recv(65536):
                chunks.append(chunk)
        except ConnectionResetError:
            pass
        return b"".join(chunks)


def _samples(body: bytes, name: str, label: str) -> dict[str, float]:
    return {
        s.labels[label]: s.value
        for family in text_string_to_metric_families(body.decode())
        for s in family.samples
        if s.name == name
    }


@pytest.fixture
def sockets() -> Iterator[list[socket.socket]]:
    socks: list[socket.socket] = []
    yield socks
    for s in socks:
        s.close()


# ---------------------------------------------------------------------------------- item 4: log flood
_MALFORMED = {
    "line_too_long": b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\nHost: x\r\n\r\n",
    "too_many_headers": b"GET / HTTP/1.1\r\n" + b"".join(b"X-%d: y\r\n" % i for i in range(5000)) + b"\r\n",
    "content_length_and_transfer_encoding": (
        b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n"
    ),
    "tls_on_plain_http": bytes.fromhex("16030100a5010000a10303") + b"\0" * 100,
}
_LONG_AUTH = b"GET /metrics HTTP/1.1\r\nHost: x\r\nAuthorization: Basic " + b"QUFB" * 2300 + b"\r\n\r\n"


def test_malformed_requests_are_counted_and_logged_once_per_cause(caplog: pytest.LogCaptureFixture) -> None:
    registry = make_registry(SnapshotHolder().get, CollectorRegistry())
    caplog.set_level(logging.DEBUG)
    repeats = 25
    with MetricsServer(registry, "127.0.0.1", 0) as server:
        caplog.clear()
        for _ in range(repeats):
            for data in (*_MALFORMED.values(), _LONG_AUTH):
                assert _exchange(server.port, data)[:13] in (b"HTTP/1.0 400 ", b"HTTP/1.1 400 ")
        logged = [r for r in caplog.records if r.levelno > logging.DEBUG]
        body = _exchange(server.port, b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
    # 125 malformed requests: one line for each of the 4 causes, no traceback
    assert not [r for r in logged if r.exc_info], [r.getMessage() for r in logged if r.exc_info]
    causes = sorted(c for r in logged for c in _MALFORMED if f"({c})" in r.getMessage())
    assert causes == sorted(_MALFORMED), [r.getMessage() for r in logged]
    assert len(logged) == len(_MALFORMED), [r.getMessage() for r in logged]
    counted = _samples(body.partition(b"\r\n\r\n")[2], "tactile_http_bad_requests_total", "cause")
    expected = dict.fromkeys(_MALFORMED, float(repeats))
    expected["line_too_long"] += repeats  # the long Authorization header is a header line over 8 KiB
    assert counted == expected


# ---------------------------------------------------------------------------------- item 5: stalled streams
async def test_stalled_stream_clients_leave_metrics_its_share_of_connections(
    sockets: list[socket.socket],
) -> None:
    async with gateway_with_page(max_connections=20) as gw:
        await first_poll(gw)
        server = gw.server
        assert server.page_slots == 15
        for _ in range(20):  # event-stream clients that never read
            s = socket.create_connection(("127.0.0.1", server.port), timeout=5)
            s.sendall(b"GET /api/devices/arr/stream HTTP/1.1\r\nHost: x\r\n\r\n")
            sockets.append(s)

        refused: list[bytes] = []

        def collect_refused() -> bool:
            for s in sockets:
                s.setblocking(False)
                try:
                    data = s.recv(4096)
                except (BlockingIOError, ConnectionError):
                    continue
                if data.startswith(b"HTTP/1.1 503 "):
                    refused.append(data)
            return gw.hub.clients()[0] + len(refused) == 20

        await until(collect_refused, 20, "every stream client streaming or refused")
        assert gw.hub.clients()[0] == 15 and len(refused) == 5
        assert all(b"Retry-After: " in r for r in refused)
        async with aiohttp.ClientSession() as http:
            for _ in range(3):
                async with http.get(server.url) as resp:
                    assert resp.status == 200
                    body = await resp.read()
        assert _samples(body, "tactile_http_refused_total", "reason")["streams"] == 5


async def test_a_stream_client_that_stops_reading_is_cut_off(sockets: list[socket.socket]) -> None:
    async with gateway_with_page(write_timeout_s=0.5) as gw:
        # a polled snapshot to copy: copies of the placeholder listed before the first poll
        # completes would make no frames (found by the stress run: never cut in 30 s)
        polled = await first_poll(gw)
        dev = polled.snapshot
        counters = {} if polled.counters is None else {"arr": polled.counters}
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # a small window: buffers fill soon
        sockets.append(s)
        s.connect(("127.0.0.1", gw.server.port))
        s.sendall(b"GET /api/devices/arr/stream HTTP/1.1\r\nHost: x\r\n\r\n")
        await until(lambda: gw.hub.clients()[0] == 1, 10, "the stream client")
        pushed = 0

        def flood_until_cut() -> bool:
            # polls faster than any poller: the stream's writes outgrow what the client takes
            nonlocal pushed
            for _ in range(200):
                pushed += 1
                fresh = dataclasses.replace(dev, timestamp_s=dev.timestamp_s + pushed)
                gw.hub.on_snapshot(GatewaySnapshot.build({"arr": fresh}, counters, pushed))
            return gw.hub.clients()[0] == 0

        await until(flood_until_cut, 30, "the stalled stream client cut off", step_s=0.01)
        assert gw.page.stalled_total == 1
        # its connection is closed, not just the stream
        await until(lambda: gw.server.open_connections == 0, 10, "the connection closed")


# ---------------------------------------------------------------------------------- item 6: bcrypt queue
async def test_wrong_passwords_beyond_the_bcrypt_queue_are_refused_at_once() -> None:
    hashed = bcrypt.hashpw(b"correct horse", bcrypt.gensalt(rounds=4))
    registry = make_registry(SnapshotHolder().get, CollectorRegistry())
    server = MetricsServer(registry, "127.0.0.1", 0, WebConfig(basic_auth_users={"prometheus": hashed}))
    auth = server._auth
    assert auth is not None
    real_check, gate, entered = auth.check, threading.Event(), []

    def gated_check(header: str | None) -> bool:  # bcrypt held until the test lets it go
        entered.append(header)
        gate.wait(30)
        return real_check(header)

    auth.check = gated_check  # type: ignore[method-assign]

    def basic(password: str) -> dict[str, str]:
        return {"Authorization": "Basic " + base64.b64encode(f"prometheus:{password}".encode()).decode()}

    flood = 3 * AUTH_QUEUE
    try:
        with server:
            async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as http:

                async def get(password: str) -> aiohttp.ClientResponse:
                    async with http.get(server.url, headers=basic(password)) as resp:
                        await resp.read()
                        return resp

                wrong = [asyncio.create_task(get(f"wrong {i}")) for i in range(flood)]

                def answered_503() -> list[aiohttp.ClientResponse]:
                    return [t.result() for t in wrong if t.done() and t.result().status == 503]

                # bcrypt is held: only the queue's worth wait, the rest are answered 503 at once
                await until(lambda: len(answered_503()) == flood - AUTH_QUEUE, 20, "the excess refused")
                assert len(entered) == 1 and not any(t.done() and t.result().status != 503 for t in wrong)
                assert all(r.headers.get("Retry-After") for r in answered_503())
                # a valid login not yet verified is refused as quickly (it would wait behind them)
                assert (await get("correct horse")).status == 503
                gate.set()
                statuses = sorted(r.status for r in await asyncio.gather(*wrong))
                assert statuses == [401] * AUTH_QUEUE + [503] * (flood - AUTH_QUEUE)
                assert len(entered) == AUTH_QUEUE  # bcrypt ran for the queue only
                assert (await get("correct horse")).status == 200  # verified and cached now
                gate.clear()
                # bcrypt held and its queue full again: the verified scraper passes first
                wrong = [asyncio.create_task(get(f"wrong again {i}")) for i in range(AUTH_QUEUE)]
                await until(lambda: server.auth_pending == AUTH_QUEUE, 20, "a full queue")
                ok = await get("correct horse")
                assert ok.status == 200 and not any(t.done() for t in wrong)
                gate.set()
                assert [r.status for r in await asyncio.gather(*wrong)] == [401] * AUTH_QUEUE
                async with http.get(server.url, headers=basic("correct horse")) as resp:
                    refusals = _samples(await resp.read(), "tactile_http_refused_total", "reason")
                assert refusals["auth_queue"] == flood - AUTH_QUEUE + 1
    finally:
        gate.set()


async def test_stopping_with_bcrypt_checks_queued_leaves_no_pending_task(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    # cost 12: a check takes ~0.2-0.4 s, so the queued checks outlast the (shortened) grace
    # the server gives its connections' handlers when it stops
    monkeypatch.setattr(server_module, "SHUTDOWN_TIMEOUT_S", 0.05)
    hashed = bcrypt.hashpw(b"correct horse", bcrypt.gensalt(rounds=12))
    registry = make_registry(SnapshotHolder().get, CollectorRegistry())
    server = MetricsServer(registry, "127.0.0.1", 0, WebConfig(basic_auth_users={"prometheus": hashed}))
    caplog.set_level(logging.DEBUG)
    handled: list[dict[str, object]] = []
    socks = []
    server.start()
    try:
        loop = server._loop
        assert loop is not None
        loop.call_soon_threadsafe(loop.set_exception_handler, lambda _, context: handled.append(context))
        wrong = b"Authorization: Basic " + base64.b64encode(b"prometheus:wrong") + b"\r\n"
        for _ in range(AUTH_QUEUE):
            s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
            s.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\n" + wrong + b"\r\n")
            socks.append(s)
        await until(lambda: server.auth_pending == AUTH_QUEUE, 20, "a full bcrypt queue")
        for s in socks:  # the clients give up: nothing waits for their answers any more
            s.close()
    finally:
        for s in socks:
            s.close()
        await asyncio.to_thread(server.stop)
    del loop
    gc.collect()
    assert handled == []
    assert "Task was destroyed" not in caplog.text
    assert "Traceback" not in caplog.text
