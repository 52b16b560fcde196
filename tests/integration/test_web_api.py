"""The frame API over real HTTP against the simulated array: the device list with layout and
units, the latest frame, the stream of every poll (consecutive sequence numbers, one per
poll), read-only methods, the page's policy headers, and the server with the page off."""

from __future__ import annotations

import json
from typing import Any

import aiohttp
from prometheus_client import CollectorRegistry
from prometheus_client.parser import text_string_to_metric_families
from web_fixtures import gateway_with_page, until

from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.runtime.poller import SnapshotHolder


async def read_frames(resp: aiohttp.ClientResponse, n: int) -> list[dict[str, Any]]:
    frames: list[dict[str, Any]] = []
    ids: list[int] = []
    async for line in resp.content:
        if line.startswith(b"id: "):
            ids.append(int(line[4:]))
        elif line.startswith(b"data: "):
            frames.append(json.loads(line[6:]))
            if len(frames) == n:
                break
    assert ids == [f["seq"] for f in frames]
    return frames


async def test_devices_frame_and_a_stream_of_every_poll() -> None:
    async with gateway_with_page() as gw, aiohttp.ClientSession(gw.server.base_url) as http:
        await until(lambda: (d := gw.holder.get().devices.get("arr")) is not None and d.up, 10, "a good poll")
        async with http.get("/api/devices") as resp:
            listing = await resp.json()
        (dev,) = listing["devices"]
        assert dev["name"] == "arr" and len(dev["channels"]) == 16 and dev["units"]["force"] == "N"
        assert dev["channels"][5] == {
            "index": 5,
            "name": dev["channels"][5]["name"],
            "x_mm": 2.5,
            "y_mm": 2.5,
        }
        async with http.get("/api/devices/arr/frame") as resp:
            latest = await resp.json()
        assert latest["device"] == "arr" and latest["seq"] >= 1 and len(latest["force_n"]) == 16
        async with http.get("/api/devices/arr/stream") as resp:
            assert resp.headers["Content-Type"] == "text/event-stream"
            frames = await read_frames(resp, 30)
        seqs = [f["seq"] for f in frames]
        assert seqs == list(range(seqs[0], seqs[0] + 30)), seqs  # every poll, none skipped
        assert all(f["dropped"] == 0 for f in frames)
        assert frames[-1]["polls_total"] - frames[0]["polls_total"] == 29  # one frame per poll
        assert gw.hub.dropped_total.get("arr", 0) == 0
        for path, status in (("/api/devices/nope", 404), ("/api/devices/nope/stream", 404), ("/nope", 404)):
            async with http.get(path) as resp:
                assert resp.status == status, path
        for method in ("POST", "PUT", "DELETE"):
            async with http.request(method, "/api/devices") as resp:
                assert resp.status == 405
        async with http.get("/") as resp:
            csp = resp.headers["Content-Security-Policy"]
            assert "default-src 'none'" in csp and "script-src 'self'" in csp and "unsafe-inline" not in csp
            assert '<script src="/static/app.js"' in await resp.text()
        async with http.get("/metrics") as resp:
            assert "Content-Security-Policy" not in resp.headers
            names = {f.name for f in text_string_to_metric_families(await resp.text())}
            assert "tactile_force_newtons" in names


async def test_without_the_page_only_metrics_are_served() -> None:
    holder = SnapshotHolder()
    with MetricsServer(make_registry(holder.get, CollectorRegistry()), "127.0.0.1", 0) as server:
        assert server.page_url is None
        async with aiohttp.ClientSession(server.base_url) as http:
            async with http.get("/") as resp:
                assert resp.status == 200 and 'href="/metrics"' in await resp.text()
            async with http.get("/api/devices") as resp:
                assert resp.status == 404 and await resp.text() == "Not found\n"
