"""The gateway's history of each device (issue 35 item 4) over real HTTP against the simulated
array: ``/api/devices/{name}/history`` gives the last seconds of polls as compact points (the
frames' own figures, per region of interest too), the device's entry says the span, a bad
query is a 400 naming it, and a gateway that keeps none answers 404."""

from __future__ import annotations

from typing import Any

import aiohttp
import pytest
from web_fixtures import first_poll, gateway_with_page, until_async

from gateway.config.rois import Roi

HEEL = Roi("heel", (4, 5, 8, 9))


async def test_the_history_serves_the_last_seconds_of_polls_as_the_frames_had_them() -> None:
    async with (
        gateway_with_page(rois=(HEEL,), history_s=60.0) as gw,
        aiohttp.ClientSession(gw.server.base_url) as http,
    ):
        await first_poll(gw)
        async with http.get("/api/devices/arr") as resp:
            assert (await resp.json())["history_s"] == 60.0
        got: list[dict[str, Any]] = []

        async def a_few_seconds() -> bool:
            async with http.get("/api/devices/arr/history?seconds=60") as resp:
                assert resp.status == 200
                got.append(await resp.json())
            points = got[-1]["points"]
            return len(points) >= 20 and points[-1]["t"] - points[0]["t"] >= 1.0

        await until_async(a_few_seconds, 20, "a second of history")
        body = got[-1]
        assert body["device"] == "arr" and body["history_s"] == 60.0
        points = body["points"]
        ts = [p["t"] for p in points]
        assert ts == sorted(ts) and len(set(ts)) == len(ts)
        for p in points:
            assert set(p) == {"t", "force_n", "peak_n", "area_mm2", "cop_x_mm", "cop_y_mm", "rois"}
            assert set(p["rois"]) == {"heel"}
            assert p["area_mm2"] == pytest.approx(round(p["area_mm2"] / 6.25) * 6.25)  # whole cells
            assert p["rois"]["heel"]["force_n"] <= p["force_n"] + 1e-6

        # a point is the frame of its poll: the latest frame is the newest point (or newer)
        async with http.get("/api/devices/arr/frame") as resp:
            frame = await resp.json()
        async with http.get("/api/devices/arr/history?seconds=0.5") as resp:
            recent = (await resp.json())["points"]
        assert recent and recent[-1]["t"] - recent[0]["t"] <= 0.5
        match = [p for p in recent if p["t"] == frame["t"]]
        if match:  # the frame was polled before the history was asked
            (p,) = match
            assert p["force_n"] == frame["total_force_n"] and p["area_mm2"] == frame["contact_area_mm2"]
            assert p["peak_n"] == frame["peak_force_n"]
            assert [p["cop_x_mm"], p["cop_y_mm"]] == (frame["cop_mm"] or [None, None])
            (heel,) = frame["rois"]
            assert p["rois"]["heel"]["force_n"] == heel["force_n"]

        for query, word in (
            ("seconds=abc", "seconds"),
            ("seconds=-1", "seconds"),
            ("seconds=nan", "seconds"),
        ):
            async with http.get(f"/api/devices/arr/history?{query}") as resp:
                assert resp.status == 400, query
                assert (await resp.text()).startswith(f"{word}: ")
        async with http.get("/api/devices/nope/history") as resp:
            assert resp.status == 404


async def test_a_gateway_without_history_answers_404_and_says_so() -> None:
    async with gateway_with_page() as gw, aiohttp.ClientSession(gw.server.base_url) as http:
        await first_poll(gw)
        async with http.get("/api/devices/arr") as resp:
            assert (await resp.json())["history_s"] == 0.0
        async with http.get("/api/devices/arr/history") as resp:
            assert resp.status == 404
