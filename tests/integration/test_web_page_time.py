"""Time on the page (issue 35 item 4) in a real browser (Debian chromium, headless, via
Playwright): the trend chart's peak-force and centre-of-pressure tracks, filled on load from the
gateway's history (a missing history endpoint leaves the chart live); in playback: frame steps
(buttons and arrow keys), loop, markers, "playback" wording and the difference map between two
chosen frames. Writes screenshots when asked (``make screenshots``)."""

from __future__ import annotations

import json
import os
import shutil
import urllib.request
from collections.abc import AsyncIterator, Awaitable
from pathlib import Path
from typing import Any

import pytest
from test_web_page_tool import open_page, text
from test_web_playback import served, set_time, write_grasp
from web_fixtures import CHROMIUM, CHROMIUM_ARGS, steady_page, until_async

pytestmark = [pytest.mark.browser, pytest.mark.slow]

DEMO_FORCES = [0.0] * 16
DEMO_FORCES[5], DEMO_FORCES[6], DEMO_FORCES[9] = 1.0, 0.5, 0.25

#: pixels of the trend chart within 40 (sum over R, G, B) of a colour
COLOUR_PIXELS_JS = """([r, g, b]) => {
  const c = document.getElementById("history");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (Math.abs(d[i] - r) + Math.abs(d[i + 1] - g) + Math.abs(d[i + 2] - b) < 40) n++;
  }
  return n;
}"""


@pytest.fixture
async def browser() -> AsyncIterator[Any]:
    from playwright.async_api import async_playwright

    async with async_playwright() as pw:
        b = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            await b.close()


PEAK_RGB = (0xE8, 0x4A, 0x5F)
COP_X_RGB = (0xB3, 0x8C, 0xFF)
COP_Y_RGB = (0x3F, 0xD0, 0x9C)


def _frame_t(base: str) -> float:
    with urllib.request.urlopen(base + "/api/devices/arr/frame", timeout=10) as resp:
        return float(json.load(resp)["t"])


async def _dataset(page: Any, selector: str, key: str) -> str | None:
    value = await page.evaluate(f"() => document.querySelector('{selector}').dataset.{key} ?? null")
    return None if value is None else str(value)


async def test_the_chart_fills_from_the_history_and_draws_peak_and_cop(browser: Any, tmp_path: Path) -> None:
    """The gateway's last 20 s (40 points, served here by the test in the endpoint's format) are
    on the chart at load, with the peak force and the centre of pressure's x and y."""
    async with steady_page(DEMO_FORCES) as server:
        t_end = _frame_t(server.base_url)
        points = [
            {"t": t_end - 20 + 0.5 * i, "force_n": 1.0 + 0.02 * i, "peak_n": 0.6, "area_mm2": 10.0,
             "cop_x_mm": 3.0 + 0.05 * i, "cop_y_mm": 4.0, "rois": {}}
            for i in range(40)
        ]  # fmt: skip
        body = json.dumps({"device": "arr", "history_s": 20.0, "points": points})
        page = await browser.new_page(viewport={"width": 1280, "height": 1000})
        asked: list[str] = []

        async def history(route: Any) -> None:
            asked.append(route.request.url)
            await route.fulfill(status=200, content_type="application/json", body=body)

        async def devices(route: Any) -> None:  # the gateway says it keeps a history
            resp = await route.fetch()
            data = await resp.json()
            for dev in data["devices"]:
                dev["history_s"] = 600.0
            await route.fulfill(response=resp, body=json.dumps(data))

        await page.route("**/api/devices/arr/history*", history)
        await page.route("**/api/devices", devices)
        await page.goto(server.base_url + "/")
        await until_async(lambda: _is_async(page, "#history", "source", "server"), 10, "the history loaded")
        assert asked and "seconds=30" in asked[0], asked
        assert int(await _dataset(page, "#history", "points") or 0) >= 41  # 40 served, 1 live
        for key in ("#key-total", "#key-peak", "#key-area", "#key-cop-x", "#key-cop-y"):
            assert await page.is_visible(key), key
        for name, rgb in (("peak", PEAK_RGB), ("cop x", COP_X_RGB), ("cop y", COP_Y_RGB)):
            n = int(await page.evaluate(COLOUR_PIXELS_JS, list(rgb)))
            assert n > 200, (name, n)  # a line across the chart's 20 s of history
        assert (await text(page, "#history-range")) == "-30 s … now"
        shot = tmp_path / "history.png"
        await page.screenshot(path=str(shot), full_page=True)
        if target := os.environ.get("TACTILE_SCREENSHOT_HISTORY"):
            shutil.copyfile(shot, target)
        await page.close()


async def _is_async(page: Any, selector: str, key: str, value: str) -> bool:
    return await _dataset(page, selector, key) == value


@pytest.mark.parametrize("says", [False, True], ids=["not-advertised", "advertised-but-404"])
async def test_a_gateway_without_history_leaves_the_chart_live(browser: Any, says: bool) -> None:
    """A gateway that does not say it keeps a history is not asked for one; one that says so
    but answers 404 leaves the chart to the live frames: no script error either way."""
    async with steady_page(DEMO_FORCES) as server:
        page = await browser.new_page(viewport={"width": 1280, "height": 900})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))

        async def missing(route: Any) -> None:
            await route.fulfill(status=404, content_type="text/plain", body="404: Not Found")

        async def devices(route: Any) -> None:
            resp = await route.fetch()
            data = await resp.json()
            for dev in data["devices"]:
                dev["history_s"] = 600.0
            await route.fulfill(response=resp, body=json.dumps(data))

        await page.route("**/api/devices/arr/history*", missing)
        if says:
            await page.route("**/api/devices", devices)
        await page.goto(server.base_url + "/")
        await until_async(lambda: _is_async(page, "#history", "source", "none"), 10, "no history")
        asked = await page.evaluate(
            "() => performance.getEntriesByType('resource').filter((e) => e.name.includes('/history')).length"
        )
        assert asked == (1 if says else 0), asked
        assert await text(page, "#state") in ("up", "stale")

        async def charted() -> int:
            return int(await _dataset(page, "#history", "points") or 0)

        # the live frame may come after the history's answer: wait for it, then count
        await until_async(lambda: _at_least(charted(), 1), 10, "the live frame charted")
        assert await charted() == 1  # the one live frame, and no other point
        assert float(await text(page, "#total-force")) == pytest.approx(1.75, abs=1e-3)
        await page.close()
    assert errors == [], errors


async def _at_least(count: Awaitable[int], n: int) -> bool:
    return await count >= n


# ---------------------------------------------------------------- playback

#: mean R, G, B of a 9 x 9 patch at each channel's centre of the record's 2 x 2 map (pitch
#: 2.5 mm, 12 px margin)
CELL_RGB_JS = """() => {
  const c = document.getElementById("map");
  const ctx = c.getContext("2d");
  const s = (c.width - 24) / 5, res = {};
  [["ch00", 0, 0], ["ch01", 1, 0], ["ch02", 0, 1], ["ch03", 1, 1]].forEach(([name, i, j]) => {
    const px = Math.round(12 + s * (1.25 + 2.5 * i)), py = Math.round(12 + s * (1.25 + 2.5 * j));
    const d = ctx.getImageData(px + 12, py + 12, 9, 9).data;
    const m = [0, 0, 0];
    for (let k = 0; k < d.length; k += 4) for (let q = 0; q < 3; q++) m[q] += d[k + q] / (d.length / 4);
    res[name] = m;
  });
  return res;
}"""


async def _frame(page: Any) -> str | None:
    return await _dataset(page, "#map", "frame")


async def test_playback_steps_loops_marks_and_compares_two_frames(browser: Any, tmp_path: Path) -> None:
    """The record (0.1 s a frame): ch00 loaded for t < 2 s, ch03 from 3 s."""
    record = tmp_path / "grasp.csv"
    write_grasp(record)
    with served(record) as server:
        page, errors = await open_page(browser, server.base_url + "/", height=1000, state="")

        async def ready() -> bool:
            return await page.evaluate("document.body.dataset.playback === 'ready'") is True

        await until_async(ready, 10, "the playback controls ready")
        # the wording is playback's, not live's
        assert "playback" in (await text(page, "#health-title")).lower()
        assert (await text(page, "#history-range")).startswith("record 0.00 s")
        title = await page.evaluate("document.getElementById('history').getAttribute('aria-label')")
        assert title.endswith("the 30 s of the record up to the frame") and "last 30 s" not in title, title
        # frame steps: the buttons and the arrow keys
        assert await _frame(page) == "1"
        await page.click("#step-fwd")
        await until_async(lambda: _frame_is(page, "2"), 5, "one frame on")
        await page.locator("body").press("ArrowRight")
        await until_async(lambda: _frame_is(page, "3"), 5, "one more (the arrow key)")
        await page.locator("body").press("ArrowLeft")
        await until_async(lambda: _frame_is(page, "2"), 5, "one back (the arrow key)")
        await page.click("#step-back")
        await until_async(lambda: _frame_is(page, "1"), 5, "back at the first frame")
        # markers: added at the shown frame, listed, jumped to
        await set_time(page, 1.0)
        await page.click("#add-marker")
        await set_time(page, 4.0)
        await page.click("#add-marker")
        assert await page.locator("#markers button").all_text_contents() == ["1.00 s", "4.00 s"]
        await page.locator("#markers button").first.click()
        await until_async(lambda: _frame_is(page, "11"), 5, "the first marker's frame")
        # the difference B - A: A at 1 s (ch00 loaded), B at 4 s (ch03 loaded)
        await page.click("#set-a")
        await set_time(page, 4.0)
        await page.click("#set-b")
        await page.select_option("#map-mode", "diff")
        rgb: dict[str, list[float]] = {}

        async def diverging() -> bool:
            rgb.update(await page.evaluate(CELL_RGB_JS))
            r0, _, b0 = rgb["ch00"]
            r3, _, b3 = rgb["ch03"]
            return b0 > r0 + 60 and r3 > b3 + 60 and max(rgb["ch01"]) < 40

        await until_async(diverging, 5, "ch00 blue (less in B), ch03 red (more in B), ch01 dark")
        low, high = (await text(page, "#scale-range")).split(" ")[0].split("…")
        assert float(low) == -float(high) and float(high) > 0
        assert "B − A" in await text(page, "#scale-range")
        shot = tmp_path / "difference.png"
        await page.screenshot(path=str(shot), full_page=True)
        if target := os.environ.get("TACTILE_SCREENSHOT_DIFFERENCE"):
            shutil.copyfile(shot, target)
        await page.select_option("#map-mode", "force")
        # loop: at 10x the record's 6 s come round again, still playing
        await page.check("#loop")
        await page.select_option("#speed", "10")
        await page.click("#play")
        await until_async(lambda: _looped(page), 10, "a loop")
        assert await _dataset(page, "#playback", "playing") == "1"
        await page.click("#pause")
        await page.close()
    assert errors == [], errors


async def _looped(page: Any) -> bool:
    return int(await _dataset(page, "#playback", "loops") or 0) >= 1


async def _frame_is(page: Any, seq: str) -> bool:
    return await _frame(page) == seq


async def test_playback_shows_the_reference_and_error_per_channel(browser: Any, tmp_path: Path) -> None:
    """The record's reference is 2 N on ch00 for t < 2 s: the hover names it and the error
    (the channel's force minus it); the error map is offered and keyed as force − reference."""
    record = tmp_path / "grasp.csv"
    write_grasp(record)
    with served(record) as server:
        page, errors = await open_page(browser, server.base_url + "/", state="")
        await until_async(
            lambda: page.evaluate("document.body.dataset.playback === 'ready'"), 10, "playback ready"
        )
        await set_time(page, 1.0)
        await until_async(lambda: _frame_is(page, "11"), 5, "the frame at 1 s")
        box = await page.locator("#map").bounding_box()
        k = box["width"] / 480
        s = (480 - 24) / 5  # the 2 x 2 map: 5 mm in 456 px
        await page.mouse.move(box["x"] + (12 + s * 1.25) * k, box["y"] + (12 + s * 1.25) * k)
        tip = await text(page, "#tooltip")
        assert tip.startswith("ch00 ") and ", reference 2.000 N, error " in tip, tip
        force = float(tip.split(": ")[1].split(" N")[0])
        error = float(tip.split(", error ")[1].split(" N")[0])
        assert error == pytest.approx(force - 2.0, abs=1.5e-3), tip
        assert await page.is_enabled("#mode-error")
        await page.select_option("#map-mode", "error")
        await until_async(
            lambda: _text_has(page, "#scale-range", "force − reference"), 5, "the error map's key"
        )
        await page.close()
    assert errors == [], errors


async def _text_has(page: Any, selector: str, part: str) -> bool:
    return part in await text(page, selector)
