"""Issue 33 §4, over real sockets on loopback: 8 connections sending wrong passwords without
pause once kept the bcrypt queue (4) full, so a scraper with the right password, not yet
verified, was refused (503) on every try. It must now get in within a scrape timeout (10 s),
also when the flood comes over more connections than the bcrypt queue holds (from another
address: 127.0.0.2, which Linux's loopback answers too)."""

from __future__ import annotations

import asyncio
import base64
import time

import aiohttp
import bcrypt
import pytest
from prometheus_client import CollectorRegistry
from waiting import until

from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.metrics.web_config import WebConfig
from gateway.runtime.poller import SnapshotHolder

#: Prometheus' default scrape timeout (s)
SCRAPE_TIMEOUT_S = 10.0
FLOOD_CONNECTIONS = 8
#: twice the bcrypt queue (``server.AUTH_QUEUE``, 32)
FLOODING_MORE_THAN_THE_QUEUE = 64


def _basic(password: str) -> dict[str, str]:
    return {"Authorization": "Basic " + base64.b64encode(f"prometheus:{password}".encode()).decode()}


@pytest.mark.parametrize(
    ("connections", "flood_address"),
    [(FLOOD_CONNECTIONS, None), (FLOODING_MORE_THAN_THE_QUEUE, "127.0.0.2")],
    ids=["8 connections", "64 connections from another address"],
)
async def test_a_right_password_gets_in_within_a_scrape_timeout_under_a_flood_of_wrong_ones(
    connections: int, flood_address: str | None
) -> None:
    hashed = bcrypt.hashpw(b"correct horse", bcrypt.gensalt(rounds=10))  # ~70 ms a check
    registry = make_registry(SnapshotHolder().get, CollectorRegistry())
    server = MetricsServer(registry, "127.0.0.1", 0, WebConfig(basic_auth_users={"prometheus": hashed}))
    stop = asyncio.Event()
    flood_statuses: list[int] = []

    async def flooder(k: int) -> None:
        # one connection, a new wrong password each time (no cache can answer it), no pause
        local = (flood_address, 0) if flood_address else None
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=1, local_addr=local)) as http:
            i = 0
            while not stop.is_set():
                i += 1
                async with http.get(server.url, headers=_basic(f"wrong {k}.{i}")) as resp:
                    await resp.read()
                    flood_statuses.append(resp.status)

    with server:
        flood = [asyncio.create_task(flooder(k)) for k in range(connections)]
        try:
            # the flood is under way: bcrypt busy with wrong passwords
            await until(lambda: flood_statuses.count(401) >= 2 * FLOOD_CONNECTIONS, 60, "the flood")
            t0 = time.monotonic()
            timeout = aiohttp.ClientTimeout(total=SCRAPE_TIMEOUT_S)
            # one scrape, as Prometheus makes one per interval: it must not be refused
            async with (
                aiohttp.ClientSession(timeout=timeout) as http,
                http.get(server.url, headers=_basic("correct horse")) as resp,
            ):
                await resp.read()
                status = resp.status
            assert status == 200, status
            assert time.monotonic() - t0 < SCRAPE_TIMEOUT_S
        finally:
            stop.set()
            await asyncio.gather(*flood, return_exceptions=True)
    assert 401 in flood_statuses
