"""The live page draws a device made of regions as the device: the shipped 1,062-taxel hand
profile (17 regions) in a real browser (Debian chromium, headless, via Playwright). Each
region's outline sits where the configuration places it (boxes hand-computed from the
profile's drawing, mapped to pixels by the page's fit-to-canvas rule), the loaded cells are
bright in their region and the idle ones dark, and the sum per finger, per palm and per
region equals the sum of the frame's forces over its channels. Writes the screenshot
``docs/screenshot-hand.png`` (``make screenshots``)."""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from prometheus_client import CollectorRegistry
from web_fixtures import CHROMIUM, CHROMIUM_ARGS, until_async

from gateway.config import DeviceConfig, parse_config
from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.runtime.poller import SnapshotHolder
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot, GatewaySnapshot
from gateway.web import FrameHub, WebPage

HAND = """
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = 6000

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
{words}"""
#: a state code and the error bits of two fingers (addresses in the profile's bytes)
WORDS = """
[[bus.device.status_word]]
name = "index-state"
address = 2000
codes = { 0 = "idle", 1 = "grasping", 2 = "force reached", 3 = "stall", 4 = "fault" }
error_codes = [3, 4]

[[bus.device.status_word]]
name = "index-errors"
address = 2002
errors = { 0 = "stall", 1 = "over-temperature", 2 = "over-current", 3 = "motor", 4 = "communication" }

[[bus.device.status_word]]
name = "thumb-state"
address = 2004
codes = { 0 = "idle", 1 = "grasping", 2 = "force reached", 3 = "stall", 4 = "fault" }
error_codes = [3, 4]

[[bus.device.status_word]]
name = "thumb-errors"
address = 2006
errors = { 0 = "stall", 1 = "over-temperature", 2 = "over-current", 3 = "motor", 4 = "communication" }
"""
#: the words' register values at the poll: index force reached, over-temperature and
#: over-current set (0b00110); thumb grasping, no error
WORD_VALUES = (2, 0b00110, 1, 0)
#: the map's canvas side for a device made of regions (px) and the page's margin around the drawing
MAP_PX = 600
MARGIN_PX = 12
#: loads (N at the centre, mm) pressed on the hand: the index fingertip, the thumb's tip, the palm
LOADS = ((83.75, 2.5, 1.8), (113.75, 42.5, 1.2), (46.25, 83.75, 2.5), (58.75, 53.75, 0.9))
SIGMA_MM = 3.0
#: the one poll's interval (s): the page calls a device stale after 5 intervals without a frame,
#: 25 s here, so the one frame served stays up on a busy machine until the screenshot
POLL_INTERVAL_S = 5.0


def hand_config(words: str = WORDS) -> DeviceConfig:
    return parse_config(HAND.format(words=words)).buses[0].devices[0]


def hand_snapshot(dev: DeviceConfig) -> DeviceSnapshot:
    """One poll of the hand with Gaussian loads at ``LOADS`` (forces below 10 mN read 0, no contact)."""
    x = np.array([c.x_mm for c in dev.channels])
    y = np.array([c.y_mm for c in dev.channels])
    f = np.zeros(len(x))
    for cx, cy, peak in LOADS:
        f += peak * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * SIGMA_MM**2))
    f = np.where(f < 0.01, 0.0, np.round(f, 4))
    status = np.where(f > 0, ChannelStatus.OK, ChannelStatus.NO_CONTACT).astype(np.int8)
    total = float(f.sum())
    peak_k = int(np.argmax(f))
    now = time.time()
    return DeviceSnapshot(
        device="hand", bus="hand", channel_index=np.arange(len(x), dtype=np.int64),
        channel_names=tuple(c.name for c in dev.channels), x_mm=x, y_mm=y,
        resistance_ohm=np.full(len(x), np.nan), force_n=f, static_estimate=None,
        reference_force_n=np.full(len(x), np.nan), status=status, up=True, timestamp_s=now,
        last_success_timestamp_s=now, device_time_s=None, poll_interval_s=POLL_INTERVAL_S,
        total_force_n=total, center_of_pressure_mm=(float(f @ x / total), float(f @ y / total)),
        channels_in_contact=int((f > 0).sum()), contact_area_mm2=float((f > 0).sum() * 6.25),
        peak_channel=dev.channels[peak_k].name, peak_force_n=float(f[peak_k]),
        status_words=tuple(w.read(v) for w, v in zip(dev.status_words, WORD_VALUES, strict=True)),
    )  # fmt: skip


@contextlib.asynccontextmanager
async def hand_page() -> AsyncIterator[tuple[MetricsServer, DeviceConfig, DeviceSnapshot]]:
    dev = hand_config()
    snap = hand_snapshot(dev)
    holder = SnapshotHolder()
    page = WebPage(FrameHub(holder), scale_max_n=2.5, device_configs=lambda: [dev])
    server = MetricsServer(make_registry(holder.get, CollectorRegistry()), "127.0.0.1", 0, None, page.install)
    holder.publish(GatewaySnapshot.build({"hand": snap}, {}, 1))
    with server:
        yield server, dev, snap


@pytest.fixture
async def browser() -> AsyncIterator[Any]:
    from playwright.async_api import async_playwright

    async with async_playwright() as pw:
        b = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            await b.close()


def test_the_profile_draws_the_hand_where_this_test_expects() -> None:
    """The boxes the pixels below are checked against, by hand from the profile (cells 2.5 mm):
    the palm is 14 x 8 turned a quarter, drawn 35 mm wide and 20 high from (30, 75) - 1.25;
    the thumb's pad, 12 x 8 from (105, 92.5), ends the drawing at the right and the bottom."""
    boxes = {r.name: r.drawn_box_mm() for r in hand_config().regions}
    assert len(boxes) == 17
    assert boxes["palm"] == (28.75, 73.75, 63.75, 93.75)
    assert boxes["thumb-pad"] == (103.75, 91.25, 123.75, 121.25)
    assert boxes["index-tip"] == (80.0, -1.25, 87.5, 6.25)
    assert boxes["little-nail"] == (-1.25, 8.75, 18.75, 38.75)


def map_px(box_mm: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """A box (mm) in the map's pixels: the drawing (x -1.25..123.75, y -1.25..121.25 mm: the
    boxes above) fitted in the canvas less its margin, centred."""
    x0, y0, x1, y1 = -1.25, -1.25, 123.75, 121.25
    s = min((MAP_PX - 2 * MARGIN_PX) / (x1 - x0), (MAP_PX - 2 * MARGIN_PX) / (y1 - y0))
    ox = (MAP_PX - s * (x1 - x0)) / 2 - s * x0
    oy = (MAP_PX - s * (y1 - y0)) / 2 - s * y0
    left, top, right, bottom = box_mm
    return ox + s * left, oy + s * top, ox + s * right, oy + s * bottom


LUMA_AT_JS = """([x, y]) => {
  const c = document.getElementById("map").getContext("2d");
  const d = c.getImageData(Math.round(x), Math.round(y), 1, 1).data;
  return (d[0] + d[1] + d[2]) / 3;
}"""


#: pixels of a canvas within 30 of the outlines' grey, #8c96a3, in every channel
OUTLINE_PIXELS_JS = """(c) => {
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (Math.abs(d[i] - 140) < 30 && Math.abs(d[i + 1] - 150) < 30 && Math.abs(d[i + 2] - 163) < 30) n++;
  }
  return n;
}"""


async def test_the_page_draws_the_hand_by_regions_with_sums(browser: Any, tmp_path: Path) -> None:
    async with hand_page() as (server, dev, snap):
        page = await browser.new_page(viewport={"width": 1400, "height": 1000})
        errors: list[str] = []
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        resp = await page.goto(server.base_url + "/")
        assert resp is not None and resp.status == 200

        async def summed() -> bool:
            return bool(await page.locator('#sums-body tr[data-group="palm"] .sum').get_attribute("data-n"))

        await until_async(summed, 15, "the sums of the hand's groups")
        canvas = await page.locator("#map").bounding_box()
        assert canvas is not None and (canvas["width"], canvas["height"]) == (MAP_PX, MAP_PX)

        # 17 outlines, each where the profile draws its region
        outlines = page.locator("#regions .region")
        assert await outlines.count() == 17
        for region in dev.regions:
            box = await page.locator(f'#regions .region[data-region="{region.name}"]').bounding_box()
            assert box is not None, region.name
            left, top, right, bottom = map_px(region.drawn_box_mm())
            got = (box["x"] - canvas["x"], box["y"] - canvas["y"], box["width"], box["height"])
            want = (left, top, right - left, bottom - top)
            assert all(abs(g - w) <= 1.5 for g, w in zip(got, want, strict=True)), (region.name, got, want)

        # the index fingertip's centre cell is loaded (bright), the little finger's nail idle (black)
        tip = next(r for r in dev.regions if r.name == "index-tip")
        nail = next(r for r in dev.regions if r.name == "little-nail")
        cx, cy = tip.position_mm(4)  # the middle of 3 x 3
        lx, ly = nail.position_mm(0)
        px_tip, px_nail = map_px((cx, cy, cx, cy)), map_px((lx, ly, lx, ly))
        # 1.8 N on a scale to 2.5 N (the palm's peak, 2.10 N, times the 1.1 headroom, rounded up
        # to a nice 2.5): 0.72 of the way, 0.8 from the 0.6 stop to the 0.75: rgb(238, 114, 30)
        assert abs(await page.evaluate(LUMA_AT_JS, [px_tip[0], px_tip[1]]) - (238 + 114 + 30) / 3) < 4
        assert await page.evaluate(LUMA_AT_JS, [px_nail[0], px_nail[1]]) < 20

        # each group's and region's sum is the sum of the frame's forces over its channels
        groups: dict[str, float] = {}
        for region in dev.regions:
            want_n = float(snap.force_n[region.channel_slice].sum())
            groups[region.group] = groups.get(region.group, 0.0) + want_n
            if region.name != region.group:
                cell = page.locator(f'#sums-body tr[data-region="{region.name}"] .sum')
                assert math.isclose(float(await cell.get_attribute("data-n") or "nan"), want_n, abs_tol=1e-9)
        assert sorted(groups) == ["index", "little", "middle", "palm", "ring", "thumb"]
        for group, want_n in groups.items():
            cell = page.locator(f'#sums-body tr[data-group="{group}"] .sum')
            assert math.isclose(float(await cell.get_attribute("data-n") or "nan"), want_n, abs_tol=1e-9)
            assert await cell.text_content() == f"{want_n:.3f}"
        assert groups["palm"] > 1.0 and groups["little"] == 0.0
        assert math.isclose(sum(groups.values()), snap.total_force_n, rel_tol=1e-9)

        # the status words: a code chip per state word, a chip per named bit, set error bits red
        assert await page.locator("#device-status .word").count() == 4
        assert (
            await page.locator('.word[data-word="index-state"] .bit.code').text_content() == "force reached"
        )
        assert await page.locator('.word[data-word="thumb-state"] .bit.code').text_content() == "grasping"
        lit = page.locator('.word[data-word="index-errors"] .bit.on.error')
        assert sorted(await lit.all_text_contents()) == ["over-current", "over-temperature"]
        assert await page.locator('.word[data-word="index-errors"] .bit').count() == 5
        assert await page.locator('.word[data-word="thumb-errors"] .bit.on').count() == 0
        assert await page.locator(".word.error").count() == 1  # index-errors alone is in error
        red = await page.locator('.word[data-word="index-errors"] [data-bit="over-temperature"]').evaluate(
            "(el) => getComputedStyle(el).backgroundColor"
        )
        assert red == "rgb(208, 48, 48)"

        assert await page.text_content("#state") == "up"
        shot = tmp_path / "hand.png"
        await page.screenshot(path=str(shot))
        assert shot.stat().st_size > 10_000
        if target := os.environ.get("TACTILE_SCREENSHOT_HAND"):
            shutil.copyfile(shot, target)

        # the overview's card draws the hand by regions too: its outlines lit on the black map
        await page.evaluate("() => { location.hash = '#overview'; }")
        card = page.locator('.card[data-device="hand"] canvas')
        await card.wait_for(state="visible", timeout=10_000)
        lit = await card.evaluate(OUTLINE_PIXELS_JS)
        # the boxes' perimeters add up to 1,250 mm, about 1,900 px at the card's 1.5 px/mm; about
        # half are drawn in the grey itself (1,041 seen), the rest split by anti-aliasing; none
        # without the outlines (the cells are black or the scale's colours)
        assert lit > 600, lit
        assert errors == []
