"""Regions of interest and export on the page (issue 35 items 5 and 6) in a real browser (Debian
chromium, headless, via Playwright): a rectangle dragged on the map selects the cells whose
centres it holds; the region's sum, peak, contact area and centre of pressure equal those over
its cells in the frame JSON; regions persist in the URL; regions named in the configuration
(the frame's ``rois``) are listed with the gateway's figures. The CSV buttons download the
gateway's export of the frame or the chart's span (read back as records); the PNG button saves
the map with its key. Writes screenshots when asked (``make screenshots``)."""

from __future__ import annotations

import asyncio
import io
import json
import math
import os
import shutil
import urllib.parse
import urllib.request
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from test_web_page_tool import cell_px, open_page
from web_fixtures import CHROMIUM, CHROMIUM_ARGS, PITCH_MM, steady_page, until_async

pytestmark = [pytest.mark.browser, pytest.mark.slow]

DEMO_FORCES = [0.0] * 16
DEMO_FORCES[5], DEMO_FORCES[6], DEMO_FORCES[9] = 1.0, 0.5, 0.25


@pytest.fixture
async def browser() -> AsyncIterator[Any]:
    from playwright.async_api import async_playwright

    async with async_playwright() as pw:
        b = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            await b.close()


def frame_json(base: str) -> dict[str, Any]:
    with urllib.request.urlopen(base + "/api/devices/arr/frame", timeout=10) as resp:
        return dict(json.load(resp))


def by_hand(frame: dict[str, Any], cells: list[int]) -> dict[str, Any]:
    """Sum, peak, contact area (6.25 mm^2 a cell) and centre of pressure over ``cells`` of a
    frame (channel k at x = 2.5 (k % 4), y = 2.5 (k // 4) mm), from its forces alone."""
    forces = {k: frame["force_n"][k] for k in cells if (frame["force_n"][k] or 0.0) > 0}
    total = math.fsum(forces.values())
    return {
        "sum": total,
        "peak": max(forces.values()),
        "area": len(forces) * PITCH_MM * PITCH_MM,
        "cop": (
            math.fsum(f * PITCH_MM * (k % 4) for k, f in forces.items()) / total,
            math.fsum(f * PITCH_MM * (k // 4) for k, f in forces.items()) / total,
        ),
    }


async def drag(page: Any, a: int, b: int) -> None:
    """Drag on the map from the centre of channel ``a`` to the centre of channel ``b``."""
    box = await page.locator("#map").bounding_box()
    k = box["width"] / 480
    (ax, ay), (bx, by) = cell_px(a), cell_px(b)
    await page.mouse.move(box["x"] + ax * k, box["y"] + ay * k)
    await page.mouse.down()
    await page.mouse.move(box["x"] + (ax + bx) / 2 * k, box["y"] + (ay + by) / 2 * k, steps=3)
    await page.mouse.move(box["x"] + bx * k, box["y"] + by * k, steps=3)
    await page.mouse.up()


async def roi_row(page: Any, name: str) -> dict[str, float]:
    row = page.locator(f'#rois-body tr[data-roi="{name}"]')
    out = {}
    for key in ("sum", "peak", "area", "copx", "copy"):
        out[key] = float(await row.get_attribute(f"data-{key}") or "nan")
    return out


async def test_a_dragged_region_sums_its_cells_as_the_frame_json(browser: Any, tmp_path: Path) -> None:
    async with steady_page(DEMO_FORCES) as server:
        frame = frame_json(server.base_url)
        page, errors = await open_page(browser, server.base_url + "/?scale=fixed&max=2")
        await drag(page, 4, 9)  # the rectangle holds the centres of ch04, ch05, ch08 and ch09
        await until_async(lambda: page.locator('#rois-body tr[data-roi="roi1"]').count(), 5, "roi1 listed")
        assert await page.locator('#rois-body tr[data-roi="roi1"]').get_attribute("data-cells") == "4,5,8,9"
        want = by_hand(frame, [4, 5, 8, 9])
        got = await roi_row(page, "roi1")
        assert got["sum"] == pytest.approx(want["sum"], abs=1e-9) and want["sum"] == pytest.approx(
            1.25, abs=1e-3
        )
        assert got["peak"] == pytest.approx(want["peak"], abs=1e-9)
        assert got["area"] == pytest.approx(want["area"]) and want["area"] == 12.5
        assert (got["copx"], got["copy"]) == pytest.approx(want["cop"], abs=1e-9)
        cells = await page.locator('#rois-body tr[data-roi="roi1"] td').all_text_contents()
        assert cells[0] == f"{want['sum']:.3f}" and cells[1] == f"{want['peak']:.3f}", cells
        assert urllib.parse.unquote(page.url).count("roi=roi1:4,5,8,9") == 1, page.url
        shot = tmp_path / "roi.png"
        await page.screenshot(path=str(shot))
        if target := os.environ.get("TACTILE_SCREENSHOT_ROI"):
            shutil.copyfile(shot, target)
        # the URL alone brings it back; a threshold of 0.3 N leaves ch09 (0.25 N) out of it
        await page.goto(server.base_url + "/?roi=heel:4,5,8,9&threshold=0.3")
        await until_async(lambda: page.locator('#rois-body tr[data-roi="heel"]').count(), 5, "heel listed")
        await until_async(lambda: _row_has(page, "heel", "sum", 1.0), 5, "the heel's sum above 0.3 N")
        assert (await roi_row(page, "heel"))["area"] == pytest.approx(6.25)
        # removed: gone from the table and the URL
        await page.click('#rois-body tr[data-roi="heel"] button.remove')
        assert await page.locator("#rois-body tr").count() == 0
        assert "roi=" not in page.url
        await page.close()
    assert errors == [], errors


async def _row_has(page: Any, name: str, key: str, value: float) -> bool:
    got = await page.locator(f'#rois-body tr[data-roi="{name}"]').get_attribute(f"data-{key}")
    return got is not None and abs(float(got) - value) < 1e-6


async def test_regions_named_in_the_configuration_are_listed(browser: Any) -> None:
    """A frame with the gateway's ``rois`` (the configuration's regions, served here by the test
    in the frame's format): each is listed with the gateway's figures and outlined on the map."""
    async with steady_page(DEMO_FORCES) as server:
        frame = frame_json(server.base_url)
        want = by_hand(frame, [5, 6])
        frame["rois"] = [{
            "name": "heel", "channels": [5, 6], "force_n": want["sum"], "peak_n": want["peak"],
            "area_mm2": want["area"], "cop_x_mm": want["cop"][0], "cop_y_mm": want["cop"][1],
        }]  # fmt: skip
        body = f"event: frame\ndata: {json.dumps(frame)}\n\n"
        page = await browser.new_page(viewport={"width": 1280, "height": 900})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))

        async def live(route: Any) -> None:
            await route.fulfill(status=200, headers={"Content-Type": "text/event-stream"}, body=body)

        await page.route("**/api/live", live)
        await page.goto(server.base_url + "/")
        await until_async(lambda: page.locator('#rois-body tr[data-roi="heel"]').count(), 10, "heel listed")
        row = page.locator('#rois-body tr[data-roi="heel"]')
        assert await row.get_attribute("data-configured") == "1"
        assert "configured" in (await row.text_content() or "")
        got = await roi_row(page, "heel")
        assert got["sum"] == pytest.approx(1.5, abs=1e-3) and got["area"] == pytest.approx(12.5)
        assert await row.locator("button.remove").count() == 0  # the configuration's, not the page's
        await page.close()
    assert errors == [], errors


# ---------------------------------------------------------------- 6. export


async def test_the_png_button_saves_the_map_with_its_key(browser: Any, tmp_path: Path) -> None:
    from PIL import Image

    async with steady_page(DEMO_FORCES) as server:
        page, errors = await open_page(browser, server.base_url + "/?scale=fixed&max=2")
        async with page.expect_download() as got:
            await page.click("#export-png")
        download = await got.value
        assert download.suggested_filename.startswith("arr-") and download.suggested_filename.endswith(".png")
        data = await asyncio.to_thread(Path(await download.path()).read_bytes)
        img = Image.open(io.BytesIO(data)).convert("RGB")
        # the map (480 x 480) at the left, the key to its right: the same pixels as on the page
        assert img.width > 480 + 60 and img.height >= 480, img.size
        px, py = cell_px(5)
        page_rgb = await page.evaluate(
            """([x, y]) => Array.from(document.getElementById("map").getContext("2d")
                 .getImageData(Math.round(x) + 12, Math.round(y) + 12, 1, 1).data.slice(0, 3))""",
            [px, py],
        )
        assert list(img.getpixel((round(px) + 12, round(py) + 12))) == page_rgb
        # the key's top colour (the scale's pale yellow) is in the image, right of the map
        right = img.crop((480, 0, img.width, img.height))
        colours = right.getcolors(maxcolors=1 << 20) or []
        assert any(r > 240 and g > 240 and 140 < b < 190 for _n, (r, g, b) in colours)
        (tmp_path / "export.png").write_bytes(data)
        await page.close()
    assert errors == [], errors


async def test_a_real_gateway_fills_the_chart_and_exports_the_frame(browser: Any, tmp_path: Path) -> None:
    """The simulated array polled for a while by a gateway keeping a history and readings to
    export: the page's chart starts with the gateway's past, and "this frame" downloads a CSV
    that reads back as a record with every channel."""
    from web_fixtures import gateway_with_page

    from gateway.analysis.records import read_record

    async with gateway_with_page(history_s=60.0, export_s=60.0) as gw:

        def kept() -> int:
            past = gw.hub.history("arr")
            return 0 if past is None else len(past.points(60.0))

        await until_async(_async(lambda: kept() >= 20), 20, "20 polls in the gateway's history")
        before = kept()
        page, errors = await open_page(browser, gw.server.base_url + "/")

        async def filled() -> bool:
            h = await page.evaluate("() => document.getElementById('history').dataset.source")
            return h == "server"

        await until_async(filled, 10, "the chart filled from the gateway's history")
        points = int(await page.evaluate("() => document.getElementById('history').dataset.points"))
        assert points >= before, (points, before)
        async with page.expect_download() as got:
            await page.click("#export-frame-csv")
        download = await got.value
        path = tmp_path / "frame.csv"
        await download.save_as(path)
        record = await asyncio.to_thread(read_record, path)
        assert len(record.channels) == 16, list(record.channels)
        # the frame: a window of its own time; the span: the chart's 30 s up to the frame
        frame_q = urllib.parse.parse_qs(urllib.parse.urlparse(download.url).query)
        assert float(frame_q["to_s"][0]) - float(frame_q["from_s"][0]) == pytest.approx(2e-5, abs=1e-6)
        assert len(next(iter(record.channels.values())).time_s) == 1, "one frame's readings"
        async with page.expect_download() as got:
            await page.click("#export-span-csv")
        span = await got.value
        span_q = urllib.parse.parse_qs(urllib.parse.urlparse(span.url).query)
        assert float(span_q["to_s"][0]) - float(span_q["from_s"][0]) == pytest.approx(30.0)
        await span.save_as(tmp_path / "span.csv")
        span_record = await asyncio.to_thread(read_record, tmp_path / "span.csv")
        assert len(span_record.channels) == 16
        await page.close()
    assert errors == [], errors


def _async(cond: Any) -> Any:
    async def run() -> bool:
        return bool(cond())

    return run


async def test_the_csv_buttons_are_off_without_readings_to_export(browser: Any) -> None:
    async with steady_page(DEMO_FORCES) as server:  # a gateway with export_s = 0
        page, errors = await open_page(browser, server.base_url + "/")
        await until_async(lambda: page.is_disabled("#export-frame-csv"), 5, "the CSV button off")
        assert await page.is_disabled("#export-span-csv") and await page.is_enabled("#export-png")
        await page.close()
    assert errors == [], errors
