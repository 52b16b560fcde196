"""Issue 33 §4, over real sockets on loopback: 8 connections sending wrong passwords without
pause once kept the bcrypt queue (4) full, so a scraper with the right password, not yet
verified, was refused (503) on every try. It must now get in within a scrape timeout (10 s)."""

from __future__ import annotations

import asyncio
import base64
import time

import aiohttp
import bcrypt
from prometheus_client import CollectorRegistry
from waiting import until

from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.metrics.web_config import WebConfig
from gateway.runtime.poller import SnapshotHolder

#: Prometheus' default scrape timeout (s)
SCRAPE_TIMEOUT_S = 10.0
FLOOD_CONNECTIONS = 8


def _basic(password: str) -> dict[str, str]:
    return {"Authorization": "Basic " + base64.b64encode(f"prometheus:{password}".encode()).decode()}


async def test_a_right_password_gets_in_within_a_scrape_timeout_under_a_flood_of_wrong_ones() -> None:
    hashed = bcrypt.hashpw(b"correct horse", bcrypt.gensalt(rounds=10))  # ~70 ms a check
    registry = make_registry(SnapshotHolder().get, CollectorRegistry())
    server = MetricsServer(registry, "127.0.0.1", 0, WebConfig(basic_auth_users={"prometheus": hashed}))
    stop = asyncio.Event()
    flood_statuses: list[int] = []

    async def flooder(k: int) -> None:
        # one connection, a new wrong password each time (no cache can answer it), no pause
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=1)) as http:
            i = 0
            while not stop.is_set():
                i += 1
                async with http.get(server.url, headers=_basic(f"wrong {k}.{i}")) as resp:
                    await resp.read()
                    flood_statuses.append(resp.status)

    with server:
        flood = [asyncio.create_task(flooder(k)) for k in range(FLOOD_CONNECTIONS)]
        try:
            # the flood is under way: bcrypt busy with wrong passwords
            await until(lambda: flood_statuses.count(401) >= 2 * FLOOD_CONNECTIONS, 30, "the flood")
            tries: list[int] = []
            t0 = time.monotonic()
            timeout = aiohttp.ClientTimeout(total=SCRAPE_TIMEOUT_S)
            async with aiohttp.ClientSession(timeout=timeout) as http:
                # a scraper's retries: one every scrape interval would do; here as fast as answered
                while time.monotonic() - t0 < SCRAPE_TIMEOUT_S:
                    async with http.get(server.url, headers=_basic("correct horse")) as resp:
                        await resp.read()
                        tries.append(resp.status)
                    if resp.status == 200:
                        break
            assert tries and tries[-1] == 200, f"refused {len(tries)} times: {tries[:10]}"
            assert time.monotonic() - t0 < SCRAPE_TIMEOUT_S
        finally:
            stop.set()
            await asyncio.gather(*flood, return_exceptions=True)
    assert 401 in flood_statuses
