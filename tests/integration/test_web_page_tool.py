"""The page as a pressure-mapping tool (issue 35) in a real browser (Debian chromium, headless,
via Playwright): the array is visible with nothing pressed (a grid line and outline for each
cell, mm axes from the configured geometry), also at phone width; one colour scale across
devices on request, with one key; units N, kPa and mmHg on every number; a contact threshold set
from the page. Writes screenshots when asked (``make screenshots``)."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import shutil
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from prometheus_client import CollectorRegistry
from web_fixtures import CHROMIUM, CHROMIUM_ARGS, PITCH_MM, steady_page, until_async

from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.model.conversion import line_conversion
from gateway.runtime.poller import SnapshotHolder
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot
from gateway.web import FrameHub, WebPage

pytestmark = [pytest.mark.browser, pytest.mark.slow]

#: 1 kPa in mmHg (the conventional millimetre of mercury: 133.322 Pa)
MMHG_PER_KPA = 7.50062
#: the 4 x 4 test grid's cell (pitch 2.5 mm)
CELL_AREA_MM2 = PITCH_MM * PITCH_MM
#: the map's canvas draws the 4 x 4 grid (-1.25 to 8.75 mm) inside a 12 px margin
PX_PER_MM = (480 - 2 * 12) / 10.0

#: a steady load: 1 N at ch05, 0.5 N at ch06, 0.25 N at ch09
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


async def text(page: Any, selector: str) -> str:
    return str(await page.text_content(selector))


async def open_page(
    browser: Any, url: str, width: int = 1280, height: int = 900, state: str = "#state"
) -> tuple[Any, list[str]]:
    page = await browser.new_page(viewport={"width": width, "height": height})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    await page.goto(url)
    if state:
        await until_async(lambda: _is(page, state, "up"), 10, "the device shown as up")
    return page, errors


async def _is(page: Any, selector: str, value: str) -> bool:
    return await text(page, selector) == value


def shot_to(env: str, shot: Path) -> None:
    if target := os.environ.get(env):
        shutil.copyfile(shot, target)


LUMA_AT_JS = """([sel, x, y]) => {
  const c = document.querySelector(sel).getContext("2d");
  const d = c.getImageData(Math.round(x), Math.round(y), 1, 1).data;
  return (d[0] + d[1] + d[2]) / 3;
}"""


def cell_px(index: int) -> tuple[float, float]:
    """The canvas pixel at the centre of channel ``index`` of the 4 x 4 test grid."""
    x_mm, y_mm = (index % 4) * PITCH_MM, (index // 4) * PITCH_MM
    return 12 + PX_PER_MM * (x_mm + 1.25), 12 + PX_PER_MM * (y_mm + 1.25)


# ---------------------------------------------------------------- 1. a visible array


async def test_an_unloaded_array_shows_its_grid_outline_and_mm_axes(browser: Any, tmp_path: Path) -> None:
    async with steady_page([0.0] * 16) as server:
        page, errors = await open_page(browser, server.base_url + "/")
        # the line between ch00 and ch01 (x = 1.25 mm) and the array's outline (x = -1.25 mm)
        # are lit; the cells' insides stay the black of no contact
        y = cell_px(0)[1]
        gap_x = 12 + PX_PER_MM * 2.5

        async def grid_drawn() -> bool:
            return float(await page.evaluate(LUMA_AT_JS, ["#map", gap_x, y])) > 25

        await until_async(grid_drawn, 5, "the grid line between ch00 and ch01")
        assert float(await page.evaluate(LUMA_AT_JS, ["#map", 12, y])) > 50, "no outline"
        assert float(await page.evaluate(LUMA_AT_JS, ["#map", *cell_px(0)])) < 8
        # mm axes: a tick at each column's and each row's centre, named
        xs = await page.locator("#axes .tick.x").all_text_contents()
        ys = await page.locator("#axes .tick.y").all_text_contents()
        assert xs == ["0", "2.5", "5", "7.5"] and ys == ["0", "2.5", "5", "7.5"], (xs, ys)
        assert await text(page, "#axes .axis-title.x") == "x, mm"
        assert await text(page, "#axes .axis-title.y") == "y, mm"
        # each x tick label is centred on its column (CSS px: the canvas may be scaled)
        box = await page.locator("#map").bounding_box()
        for k, label in enumerate(await page.locator("#axes .tick.x").all()):
            lb = await label.bounding_box()
            want = box["x"] + (12 + PX_PER_MM * (k * PITCH_MM + 1.25)) * box["width"] / 480
            assert abs(lb["x"] + lb["width"] / 2 - want) < 2, (k, lb, want)
        shot = tmp_path / "array.png"
        await page.screenshot(path=str(shot))
        shot_to("TACTILE_SCREENSHOT_ARRAY", shot)
        await page.close()
    assert errors == [], errors


async def test_the_map_is_legible_at_phone_width(browser: Any, tmp_path: Path) -> None:
    async with steady_page(DEMO_FORCES) as server:
        page, errors = await open_page(browser, server.base_url + "/", width=375, height=812)
        # nothing wider than the screen: no sideways scrolling
        width = await page.evaluate("() => document.documentElement.scrollWidth")
        assert width <= 375, width
        box = await page.locator("#map").bounding_box()
        assert box["width"] >= 250 and box["x"] + box["width"] <= 375, box
        # the axes' labels keep a legible size and do not overlap
        labels = await page.locator("#axes .tick.x").all()
        boxes = [await lb.bounding_box() for lb in labels]
        for a, b in itertools.pairwise(boxes):
            assert a["x"] + a["width"] < b["x"], (a, b)
        size = await page.locator("#axes .tick.x").first.evaluate("(el) => getComputedStyle(el).fontSize")
        assert float(size.removesuffix("px")) >= 11, size
        # the hover still finds ch05 (1 N) through the scaled canvas
        px, py = cell_px(5)
        k = box["width"] / 480
        await page.mouse.move(box["x"] + px * k, box["y"] + py * k)
        assert (await text(page, "#tooltip")).startswith("ch05 (2.5, 2.5 mm): 1.000 N")
        width = await page.evaluate("() => document.documentElement.scrollWidth")
        assert width <= 375, f"the tooltip widens the page to {width} px"
        # the trend chart is drawn at its shown width (its 12 px text not scaled down)
        chart = await page.evaluate(
            "() => { const c = document.getElementById('history'); return [c.width, c.clientWidth]; }"
        )
        assert chart[1] <= 375 and abs(chart[0] - chart[1]) <= 1, chart
        shot = tmp_path / "phone.png"
        await page.screenshot(path=str(shot), full_page=True)
        shot_to("TACTILE_SCREENSHOT_PHONE", shot)
        await page.close()
    assert errors == [], errors


# ---------------------------------------------------------------- 2. one scale, units


@contextlib.asynccontextmanager
async def two_devices(forces: dict[str, list[float]]) -> AsyncIterator[MetricsServer]:
    """Devices of 4 x 4 cells (pitch 2.5 mm), each channel reading ``forces[name]`` (N) at one
    poll, served with the page."""
    m, n = 2e-5, 1e-6
    line = line_conversion(m, n, 0.01, 50.0)
    devices, snaps = [], {}
    now = time.time()
    for unit, (name, f) in enumerate(forces.items(), start=1):
        channels = tuple(
            ChannelConfig(k, f"ch{k:02d}", (k % 4) * PITCH_MM, (k // 4) * PITCH_MM, True,
                          PAPER_EFFECTS, SensorParams(), None, line)
            for k in range(16)
        )  # fmt: skip
        dev = DeviceConfig(name, unit, "float32", 16, RegisterMap(), Divider(), channels, False,
                           GridLayout(16, 4, PITCH_MM, PITCH_MM), None)  # fmt: skip
        devices.append(dev)
        proc = DeviceProcessor(dev, "sim", 0.05)
        r = np.array([1.0 / (m * v + n) for v in f])
        snaps[name], _ = proc.process(
            proc.initial_state(), RawSample(resistance_ohm=r, device_time_s=0.05), now, now
        )
    holder = SnapshotHolder()
    page = WebPage(FrameHub(holder), scale_max_n=5.0, device_configs=lambda: devices)
    server = MetricsServer(make_registry(holder.get, CollectorRegistry()), "127.0.0.1", 0, None, page.install)
    holder.publish(GatewaySnapshot.build(snaps, {}, 1))
    with server:
        yield server


def one_load(index: int, force_n: float) -> list[float]:
    f = [0.0] * 16
    f[index] = force_n
    return f


CARD_LUMA_JS = """([name, x, y]) => {
  const c = document.querySelector(`.card[data-device="${name}"] canvas`);
  if (!c) return -1;
  const d = c.getContext("2d").getImageData(Math.round(x), Math.round(y), 1, 1).data;
  return (d[0] + d[1] + d[2]) / 3;
}"""


def card_px(index: int) -> tuple[float, float]:
    """A point of channel ``index`` on a 200 px overview card (6 px margin): 14 px right of and
    below its centre, clear of the centre of pressure's white mark (8 px radius), inside the
    cell (43 px wide)."""
    s = (200 - 12) / 10.0
    return 20 + s * ((index % 4) * PITCH_MM + 1.25), 20 + s * ((index // 4) * PITCH_MM + 1.25)


async def test_one_scale_across_devices_draws_equal_forces_equal(browser: Any, tmp_path: Path) -> None:
    """0.75 N on one device and 3 N on the other: each card's own scale draws both peaks bright;
    the one scale (0-4 N: 3 N times the 1.1 headroom, rounded up) draws 0.75 N dark, and one key
    says so."""
    async with two_devices({"a": one_load(5, 0.75), "b": one_load(5, 3.0)}) as server:
        page, errors = await open_page(browser, server.base_url + "/#overview", state="")
        lumas: dict[str, float] = {}

        async def both_bright() -> bool:
            for name in ("a", "b"):
                lumas[name] = float(await page.evaluate(CARD_LUMA_JS, [name, *card_px(5)]))
            return min(lumas.values()) > 100

        await until_async(both_bright, 10, "each card's peak bright on its own scale")
        assert not await page.locator("#overview-key").is_visible()
        await page.check("#same-scale")

        async def one_scale() -> bool:
            for name in ("a", "b"):
                lumas[name] = float(await page.evaluate(CARD_LUMA_JS, [name, *card_px(5)]))
            # 0.75 / 4 of the scale: rgb(55, 14, 91); 3 / 4: rgb(245, 125, 21)
            return abs(lumas["a"] - 53) < 6 and abs(lumas["b"] - 130) < 6

        await until_async(one_scale, 5, "0.75 N dark and 3 N bright on one scale")
        assert await page.locator("#overview-key").is_visible()
        assert await text(page, "#overview-range") == "0–4.00 N (auto, all devices)"
        assert "same=1" in page.url
        shot = tmp_path / "overview.png"
        await page.screenshot(path=str(shot))
        shot_to("TACTILE_SCREENSHOT_OVERVIEW", shot)
        # the URL alone gives the same scale, in the detail view too
        await page.goto(server.base_url + "/?same=1#device=a")
        await until_async(lambda: _is(page, "#scale-range", "0–4.00 N (auto, all devices)"), 5, "one scale")
        await page.close()
    assert errors == [], errors


async def test_mmhg_applies_to_every_number(browser: Any) -> None:
    """In mmHg: the key, the hover, the peak (1 N over 6.25 mm^2: 160 kPa, 1200.1 mmHg) and the
    total, shown as the mean pressure over the contact area (1.75 N over 3 cells, 18.75 mm^2:
    93.33 kPa, 700.06 mmHg)."""
    async with steady_page(DEMO_FORCES) as server:
        page, errors = await open_page(browser, server.base_url + "/?unit=mmHg")
        # the auto range's top: the next nice step above 1.1 x 1200.1 mmHg
        await until_async(lambda: _is(page, "#scale-range", "0–1500 mmHg (auto)"), 5, "the key in mmHg")
        peak_mmhg = 1.0 * 1000 / CELL_AREA_MM2 * MMHG_PER_KPA
        mean_mmhg = 1.75 / (3 * CELL_AREA_MM2) * 1000 * MMHG_PER_KPA
        name, value, unit = (await text(page, "#peak")).split()
        assert name == "ch05" and unit == "mmHg" and float(value) == pytest.approx(peak_mmhg, abs=0.1)
        assert float(await text(page, "#total-force")) == pytest.approx(mean_mmhg, abs=0.1)
        assert await text(page, "#total-unit") == "mmHg"
        assert "mean pressure over the contact area" in await text(page, "#total-label")
        box = await page.locator("#map").bounding_box()
        px, py = cell_px(6)
        await page.mouse.move(box["x"] + px * box["width"] / 480, box["y"] + py * box["width"] / 480)
        tip = await text(page, "#tooltip")
        want = 0.5 * 1000 / CELL_AREA_MM2 * MMHG_PER_KPA
        assert tip.startswith("ch06 ") and "0.500 N, " in tip and tip.endswith(", ok"), tip
        assert float(tip.split(" N, ")[1].split(" mmHg")[0]) == pytest.approx(want, abs=0.1), tip
        # back to N: the total is a force again
        await page.select_option("#unit", "N")
        await until_async(lambda: _is(page, "#total-unit", "N"), 5, "the total in N")
        assert float(await text(page, "#total-force")) == pytest.approx(1.75, abs=1e-3)
        assert await text(page, "#peak") == "ch05 1.000 N"
        assert "unit=N" in page.url
        await page.close()
    assert errors == [], errors


# ---------------------------------------------------------------- 3. contact threshold


async def test_a_contact_threshold_set_from_the_page(browser: Any, tmp_path: Path) -> None:
    """A threshold of 0.3 N leaves ch09 (0.25 N) out: drawn as no contact, not counted in the
    area (2 cells, 12.5 mm^2), the total or the contact count; the key says the threshold."""
    async with steady_page(DEMO_FORCES) as server:
        page, errors = await open_page(browser, server.base_url + "/?scale=fixed&max=2")
        await until_async(lambda: _is(page, "#in-contact", "3"), 5, "three channels in contact")
        assert float(await page.evaluate(LUMA_AT_JS, ["#map", *cell_px(9)])) > 20
        await page.fill("#threshold", "0.3")
        await page.dispatch_event("#threshold", "change")
        await until_async(lambda: _is(page, "#in-contact", "2"), 5, "two channels above 0.3 N")
        assert float(await text(page, "#area")) == pytest.approx(2 * CELL_AREA_MM2)
        assert float(await text(page, "#total-force")) == pytest.approx(1.5, abs=1e-3)
        assert await text(page, "#peak") == "ch05 1.000 N"
        assert await text(page, "#threshold-key") == "contact from 0.300 N"
        assert "threshold=0.3" in page.url

        async def dark() -> bool:
            return float(await page.evaluate(LUMA_AT_JS, ["#map", *cell_px(9)])) < 8

        await until_async(dark, 5, "ch09 drawn as no contact")
        # the slider's range is the scale's: 0 to its top; a larger value is clamped
        assert await page.get_attribute("#threshold-slider", "max") == "2"
        await page.fill("#threshold", "50")
        await page.dispatch_event("#threshold", "change")
        await until_async(lambda: _is(page, "#threshold-key", "contact from 2.000 N"), 5, "clamped to 2 N")
        assert await text(page, "#in-contact") == "0"
        # the URL alone sets it
        await page.goto(server.base_url + "/?scale=fixed&max=2&threshold=0.6")
        await until_async(lambda: _is(page, "#in-contact", "1"), 5, "one channel above 0.6 N")
        shot = tmp_path / "threshold.png"
        await page.screenshot(path=str(shot))
        shot_to("TACTILE_SCREENSHOT_THRESHOLD", shot)
        await page.close()
    assert errors == [], errors


async def test_the_sums_by_finger_follow_the_unit(browser: Any) -> None:
    """On the hand in kPa, each group's and region's figure is the mean pressure over its
    contact area: its forces in contact over (their count x 6.25 mm^2), by hand from the frame."""
    from test_web_hand import hand_page

    async with hand_page() as (server, dev, snap):
        page, errors = await open_page(browser, server.base_url + "/?unit=kPa", width=1400, height=1000)
        await until_async(
            lambda: _is(page, "#sums-title", "Mean pressure by finger and region (kPa)"), 5, "kPa"
        )
        groups: dict[str, list[float]] = {}
        for region in dev.regions:
            groups.setdefault(region.group, []).extend(float(v) for v in snap.force_n[region.channel_slice])
        for group, forces in groups.items():
            loaded = [f for f in forces if f > 0]
            want = "–" if not loaded else f"{sum(loaded) / (len(loaded) * CELL_AREA_MM2) * 1000:.1f}"
            got = await text(page, f'#sums-body tr[data-group="{group}"] .sum')
            assert got == want, (group, got, want)
        assert groups["palm"] and groups["little"]  # one loaded group and one idle one
        await page.close()
    assert errors == [], errors


async def test_pressure_on_a_device_of_regions_uses_each_regions_cell(browser: Any) -> None:
    """A hand whose palm is described with a 5 mm pitch (25 mm^2 cells; the layout served here by
    the test): in kPa a palm cell reads its force over 25 mm^2 (in the tooltip and the peak),
    a fingertip cell over 6.25 mm^2."""
    from test_web_hand import hand_page, map_px

    async with hand_page() as (server, dev, snap):
        page = await browser.new_page(viewport={"width": 1400, "height": 1000})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))

        async def devices(route: Any) -> None:
            resp = await route.fetch()
            data = await resp.json()
            for region in data["devices"][0]["regions"]:
                if region["name"] == "palm":
                    region["pitch_mm"] = [5.0, 5.0]
            await route.fulfill(response=resp, body=json.dumps(data))

        await page.route("**/api/devices", devices)
        await page.goto(server.base_url + "/?unit=kPa")
        await until_async(lambda: _is(page, "#state", "up"), 10, "the hand shown as up")
        # the peak is the palm's centre cell: over 25 mm^2
        peak_k = int(np.argmax(snap.force_n))
        assert snap.channel_names[peak_k].startswith("palm")
        want = float(snap.force_n[peak_k]) * 1000 / 25.0
        name, value, unit = (await text(page, "#peak")).split()
        assert name == snap.channel_names[peak_k] and unit == "kPa"
        assert float(value) == pytest.approx(want, abs=0.05)
        # the index fingertip's centre cell: over 6.25 mm^2
        tip = next(r for r in dev.regions if r.name == "index-tip")
        cx, cy = tip.position_mm(4)
        px, py, _, _ = map_px((cx, cy, cx, cy))
        box = await page.locator("#map").bounding_box()
        await page.mouse.move(box["x"] + px, box["y"] + py)
        tip_text = await text(page, "#tooltip")
        k = next(i for i, c in enumerate(dev.channels) if c.x_mm == cx and c.y_mm == cy)
        force = float(snap.force_n[k])
        assert tip_text.startswith(f"{dev.channels[k].name} ") and f"{force:.3f} N, " in tip_text, tip_text
        kpa = float(tip_text.split(" N, ")[1].split(" kPa")[0])
        assert kpa == pytest.approx(force * 1000 / CELL_AREA_MM2, abs=0.05), tip_text
        await page.close()
    assert errors == [], errors
