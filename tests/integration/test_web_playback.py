"""Playback of a recorded file on the page (``tactile-gateway view``) in a real browser (Debian
chromium, headless, via Playwright): a record in which one channel is loaded early and another
late; the slider's two positions draw the one and then the other cell bright, play advances the
time, and the trend chart's key names the reference force the record carries. The live page
keeps its look (no playback controls, no reference entry in the key). Writes a screenshot."""

from __future__ import annotations

import contextlib
import math
import os
import shutil
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
from prometheus_client import CollectorRegistry
from web_fixtures import CHROMIUM, CHROMIUM_ARGS, steady_page, until_async

from gateway.analysis.records import format_record, write_record
from gateway.cli.view_cmd import load_playback
from gateway.metrics.server import MetricsServer
from gateway.web.playback import PlaybackPage

#: the record's span: ch00 (top left) is loaded for t < 2 s, ch03 (bottom right) for t >= 3 s
SPAN_S = 6.0
STEP_S = 0.1
LOADED_OHM = 20_000.0  # about 3.5 N with the default sensor parameters

#: mean RGB luminance of a 9 x 9 pixel patch at each channel's centre on the map, drawn as
#: app.js places it (transform() with a 12 px margin)
CELL_LUMA_JS = """() => {
  const c = document.getElementById("map");
  const ctx = c.getContext("2d");
  const res = {};
  const chans = JSON.parse(c.dataset.channels);
  const xs = chans.map((k) => k.x_mm), ys = chans.map((k) => k.y_mm), p = 2.5;
  const x0 = Math.min(...xs) - p / 2, x1 = Math.max(...xs) + p / 2;
  const y0 = Math.min(...ys) - p / 2, y1 = Math.max(...ys) + p / 2;
  const s = Math.min((c.width - 24) / (x1 - x0), (c.height - 24) / (y1 - y0));
  const ox = (c.width - s * (x1 - x0)) / 2 - s * x0, oy = (c.height - s * (y1 - y0)) / 2 - s * y0;
  for (const k of chans) {
    const px = Math.round(ox + s * k.x_mm), py = Math.round(oy + s * k.y_mm);
    const d = ctx.getImageData(px - 4, py - 4, 9, 9).data;
    let sum = 0;
    for (let i = 0; i < d.length; i += 4) sum += d[i] + d[i + 1] + d[i + 2];
    res[k.name] = sum / (d.length / 4) / 3;
  }
  return res;
}"""


def write_grasp(path: Path) -> None:
    names = ["ch00", "ch01", "ch02", "ch03"]
    times = [round(k * STEP_S, 6) for k in range(int(SPAN_S / STEP_S))]
    rs, fs = [], []
    for t in times:
        early, late = t < 2.0, t >= 3.0
        rs.append([LOADED_OHM if early else math.inf, math.inf, math.inf, LOADED_OHM if late else math.inf])
        fs.append([2.0 if early else 0.0, 0.0, 0.0, 2.0 if late else 0.0])
    write_record(path, format_record({"source": "test", "columns": "2"}, names, times, rs, fs))


@pytest.fixture
async def browser() -> AsyncIterator[Any]:
    from playwright.async_api import async_playwright

    async with async_playwright() as pw:
        b = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            await b.close()


@contextlib.contextmanager
def served(record: Path) -> Iterator[MetricsServer]:
    page = PlaybackPage(load_playback(record, None, None))
    with MetricsServer(CollectorRegistry(), "127.0.0.1", 0, None, page.install) as server:
        yield server


async def set_time(page: Any, t_s: float) -> None:
    await page.evaluate(
        """(t) => { const s = document.getElementById("time"); s.value = String(t);
                    s.dispatchEvent(new Event("input")); }""",
        t_s,
    )


async def cells(page: Any) -> dict[str, float]:
    await page.evaluate(
        """async () => { const r = await fetch("/api/devices"); const d = await r.json();
                         document.getElementById("map").dataset.channels =
                           JSON.stringify(d.devices[0].channels); }"""
    )
    return dict(await page.evaluate(CELL_LUMA_JS))


async def test_playback_moves_through_the_record(browser: Any, tmp_path: Path) -> None:
    record = tmp_path / "grasp.csv"
    write_grasp(record)
    with served(record) as server:
        page = await browser.new_page(viewport={"width": 1280, "height": 1000})
        errors: list[str] = []
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        resp = await page.goto(server.base_url + "/")
        assert resp is not None and resp.status == 200
        assert "script-src 'self'" in (resp.headers.get("content-security-policy") or "")

        async def ready() -> bool:
            return await page.evaluate("document.body.dataset.playback === 'ready'") is True

        await until_async(ready, 10, "the playback controls ready")
        assert await page.is_visible("#playback")
        assert await page.is_visible("#key-reference"), "the record has force_n: the key names it"
        assert await page.is_visible("#key-total") and await page.is_visible("#key-area")

        async def frame_at(t_s: float, loaded: str) -> dict[str, float]:
            await set_time(page, t_s)
            want = str(round(t_s / STEP_S) + 1)  # the frame's seq: one per 0.1 s sample

            async def drawn() -> bool:
                return await page.evaluate("document.getElementById('map').dataset.frame") == want

            await until_async(drawn, 5, f"the frame at {t_s} s drawn")
            lumas: dict[str, float] = {}

            async def painted() -> bool:  # the draw after the seek (requestAnimationFrame)
                lumas.update(await cells(page))
                return lumas[loaded] > 100

            await until_async(painted, 5, f"{loaded} drawn loaded at {t_s} s")
            return lumas

        early = await frame_at(1.0, "ch00")
        assert early["ch03"] < 30 and early["ch01"] < 30, early
        assert float(await page.text_content("#total-force") or "nan") > 0.5
        late = await frame_at(4.0, "ch03")
        assert late["ch00"] < 30 and late["ch01"] < 30, late
        assert float(await page.text_content("#cop-x") or "nan") == pytest.approx(2.5)

        assert await page.evaluate("document.getElementById('history').dataset.reference") == "1"
        shot = tmp_path / "playback.png"
        await page.screenshot(path=str(shot), full_page=True)
        assert shot.stat().st_size > 10_000
        if target := os.environ.get("TACTILE_SCREENSHOT_PLAYBACK"):
            shutil.copyfile(shot, target)

        # play at 10x from the start: the slider's time advances on its own, then pause stops it
        await set_time(page, 0.0)
        await page.select_option("#speed", "10")
        await page.click("#play")

        async def slider_t() -> float:
            return float(await page.evaluate("document.getElementById('time').dataset.t"))

        async def advanced() -> bool:
            return await slider_t() > 1.5

        await until_async(advanced, 10, "play to advance the time past 1.5 s")
        await page.click("#pause")
        assert await page.is_enabled("#play") and not await page.is_enabled("#pause")
        stopped = await slider_t()

        async def ended_or_stopped() -> bool:
            return await page.evaluate("document.getElementById('playback').dataset.playing") == "0"

        await until_async(ended_or_stopped, 5, "pause to stop playing")
        assert await slider_t() == stopped
        assert not errors, errors


async def test_the_live_page_has_no_playback_and_a_key_without_reference(browser: Any) -> None:
    async with steady_page([1.0, 0.5, 0.25] + [0.0] * 13) as server:
        page = await browser.new_page(viewport={"width": 1280, "height": 900})
        await page.goto(server.base_url + "/")

        async def up() -> bool:
            return await page.text_content("#state") == "up"

        await until_async(up, 10, "the device shown as up")
        assert not await page.is_visible("#playback")
        assert await page.is_visible("#key-total") and await page.is_visible("#key-area")
        assert not await page.is_visible("#key-reference")
        assert "total force" in (await page.text_content("#history-key") or "")
