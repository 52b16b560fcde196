"""The live pressure-map page in a real browser (Debian chromium, headless, via Playwright)
against the simulated array: it loads without console errors, its map follows the probe,
its centre-of-pressure readout follows the load within a pitch, the device turns stale
within 2 s of the simulator stopping and comes back when it restarts; with basic auth the
page and its streams refuse a request without credentials. The colour scale follows the peak
(auto-range) or stays fixed on request, reads in N or kPa, numbers can be shown on the cells,
a disabled channel has its own look and the summary is marked old while the device is stale.
Writes screenshots."""

from __future__ import annotations

import base64
import os
import shutil
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import bcrypt
import pytest
from web_fixtures import (
    CHROMIUM,
    CHROMIUM_ARGS,
    PITCH_MM,
    Gateway,
    gateway_with_page,
    steady_page,
    true_cop,
    until_async,
)

from gateway.metrics.web_config import load_web_config

#: the map's pixels as a coarse grid of mean luminance (16 x 16 cells)
MAP_CELLS_JS = """() => {
  const c = document.getElementById("map");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  const n = 16, out = new Array(n * n).fill(0), cw = c.width / n, ch = c.height / n;
  for (let y = 0; y < c.height; y += 2) for (let x = 0; x < c.width; x += 2) {
    const o = 4 * (y * c.width + x);
    out[Math.floor(y / ch) * n + Math.floor(x / cw)] += d[o] + d[o + 1] + d[o + 2];
  }
  return out.map((v) => v / (cw * ch / 4) / 3);
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


async def text(page: Any, selector: str) -> str:
    return str(await page.text_content(selector))


async def cop_readout(page: Any) -> tuple[float, float] | None:
    x, y = await text(page, "#cop-x"), await text(page, "#cop-y")
    try:
        return float(x), float(y)
    except ValueError:
        return None


async def follow_cop(page: Any, gw: Gateway, x_range: tuple[float, float]) -> tuple[float, float]:
    """Wait for the page's centre of pressure to lie in ``x_range``; check it against the
    simulator's true centre of pressure there (within a pitch)."""
    seen: dict[str, tuple[float, float] | None] = {}

    async def there() -> bool:
        seen["page"] = cop = await cop_readout(page)
        seen["true"] = true_cop(gw.array)
        return cop is not None and seen["true"] is not None and x_range[0] <= cop[0] <= x_range[1]

    await until_async(there, 20, f"the centre of pressure at x in {x_range} mm")
    page_cop, sim_cop = seen["page"], seen["true"]
    assert page_cop is not None and sim_cop is not None
    assert abs(page_cop[0] - sim_cop[0]) < PITCH_MM and abs(page_cop[1] - sim_cop[1]) < PITCH_MM, (
        page_cop, sim_cop)  # fmt: skip
    return page_cop


async def test_the_page_shows_the_array_live(browser: Any, tmp_path: Path) -> None:
    async with gateway_with_page() as gw:
        page = await browser.new_page(viewport={"width": 1280, "height": 900})
        errors: list[str] = []
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        resp = await page.goto(gw.server.base_url + "/")
        assert resp is not None and resp.status == 200
        assert "script-src 'self'" in (resp.headers.get("content-security-policy") or "")
        await until_async(lambda: _is(page, "#state", "up"), 10, "the device shown as up")
        assert await text(page, "#dev-name") == "arr"

        # the probe slides from left to right along the middle row: the map follows it
        left = await follow_cop(page, gw, (-1.0, 2.5))
        pixels_left = await page.evaluate(MAP_CELLS_JS)
        right = await follow_cop(page, gw, (5.0, 9.0))
        pixels_right = await page.evaluate(MAP_CELLS_JS)
        assert right[0] - left[0] > PITCH_MM
        changed = sum(abs(a - b) > 8 for a, b in zip(pixels_left, pixels_right, strict=True))
        assert changed >= 16, f"only {changed} of 256 map cells changed as the probe moved"
        assert float(await text(page, "#total-force")) > 0.1
        assert float(await text(page, "#poll-rate")) > 5
        shot = tmp_path / "pressure-map.png"
        await page.screenshot(path=str(shot))
        assert shot.stat().st_size > 10_000
        if target := os.environ.get("TACTILE_SCREENSHOT"):
            shutil.copyfile(shot, target)

        # the hover shows a channel's value
        box = await page.locator("#map").bounding_box()
        await page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        tip = await text(page, "#tooltip")
        assert tip.startswith("ch") and (" N, " in tip or "no value" in tip), tip

        # the simulator stops: stale within 2 s; it restarts: up again
        await gw.stop_sim()
        waited = await until_async(lambda: _is(page, "#state", "stale"), 2.0, "the device shown as stale")
        assert await page.locator("#map").is_visible()
        await gw.start_sim()
        await until_async(lambda: _is(page, "#state", "up"), 10, "the device shown as up again")
        await page.close()
        assert waited <= 2.0
    assert errors == [], errors


async def _is(page: Any, selector: str, value: str) -> bool:
    return await text(page, selector) == value


def _status(url: str, auth: tuple[str, str] | None = None) -> int:
    req = urllib.request.Request(url)
    if auth is not None:
        req.add_header("Authorization", "Basic " + base64.b64encode(f"{auth[0]}:{auth[1]}".encode()).decode())
    try:
        with urllib.request.urlopen(req, timeout=10) as resp:
            return int(resp.status)
    except urllib.error.HTTPError as exc:
        exc.close()
        return int(exc.code)


async def test_basic_auth_guards_the_page_and_the_streams(browser: Any, tmp_path: Path) -> None:
    hashed = bcrypt.hashpw(b"correct horse", bcrypt.gensalt(rounds=4)).decode()
    web = tmp_path / "web.yml"
    web.write_text(f"basic_auth_users:\n  viewer: '{hashed}'\n")
    async with gateway_with_page(load_web_config(web)) as gw:
        base = gw.server.base_url
        paths = ["/", "/static/app.js", "/api/devices", "/api/devices/arr/frame", "/api/devices/arr/stream",
                 "/api/live", "/metrics"]  # fmt: skip
        for path in paths:
            assert await _to_thread(_status, base + path) == 401, path
            assert await _to_thread(_status, base + path, ("viewer", "wrong")) == 401, path
        for path in paths[:4]:
            assert await _to_thread(_status, base + path, ("viewer", "correct horse")) == 200, path
        # a browser without credentials is refused; with them the page runs
        from playwright.async_api import Error as PlaywrightError

        anonymous = await browser.new_context()
        with pytest.raises(PlaywrightError, match="ERR_INVALID_AUTH_CREDENTIALS"):
            await (await anonymous.new_page()).goto(base + "/")
        await anonymous.close()
        context = await browser.new_context(
            http_credentials={"username": "viewer", "password": "correct horse"}
        )
        page = await context.new_page()
        errors: list[str] = []
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        await page.goto(base + "/")
        await until_async(lambda: _is(page, "#state", "up"), 10, "the device shown as up with credentials")
        await context.close()
    assert errors == [], errors


async def _to_thread(fn: Any, *args: Any) -> Any:
    import asyncio

    return await asyncio.to_thread(fn, *args)


#: the map's pixels in the colour of an extrapolated channel's dashed outline (#3fd0c9), which
#: the force colour scale (black, purple, red, orange, yellow) never makes
EXTRAPOLATED_PIXELS_JS = """() => {
  const c = document.getElementById("map");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let o = 0; o < d.length; o += 4) {
    if (Math.abs(d[o] - 63) < 24 && Math.abs(d[o + 1] - 208) < 24 && Math.abs(d[o + 2] - 201) < 24) n++;
  }
  return n;
}"""


async def test_the_page_draws_extrapolated_channels_apart(browser: Any, tmp_path: Path) -> None:
    """Channels calibrated on 0.5-5 N reading 0.3 N and 8 N: the page draws them in the colour
    of their force with a dashed outline, says ``extrapolated`` on hover and in the legend."""
    import math
    import time

    import numpy as np
    from prometheus_client import CollectorRegistry

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

    m, n = 2e-5, 1e-6
    line = line_conversion(m, n, 0.5, 5.0)  # a line calibrated on 0.5-5 N
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", (k % 4) * PITCH_MM, (k // 4) * PITCH_MM, True, PAPER_EFFECTS,
                      SensorParams(), None, line)
        for k in range(16)
    )  # fmt: skip
    device = DeviceConfig("arr", 1, "float32", 16, RegisterMap(), Divider(), channels, False,
                          GridLayout(16, 4, PITCH_MM, PITCH_MM), None)  # fmt: skip
    forces = [0.0, 0.3, 2.0, 8.0, 0.0, 0.0, 1.0, 0.0, 0.0, 6.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]
    r = np.array([math.inf if f < 0 else 1.0 / (m * f + n) for f in forces])  # the last: open
    proc = DeviceProcessor(device, "sim", 0.05)
    holder = SnapshotHolder()
    hub = FrameHub(holder)
    server = MetricsServer(
        make_registry(holder.get, CollectorRegistry()), "127.0.0.1", 0, None,
        WebPage(hub, scale_max_n=10.0).install,
    )  # fmt: skip

    # one poll: the load does not change, and the page draws the newest frame it is sent
    now = time.time()
    snap, _ = proc.process(proc.initial_state(), RawSample(resistance_ohm=r, device_time_s=0.05), now, now)
    holder.publish(GatewaySnapshot.build({"arr": snap}, {}, 1))

    with server:
        page = await browser.new_page(viewport={"width": 1280, "height": 900})
        errors: list[str] = []
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        await page.goto(server.base_url + "/")
        await until_async(lambda: _is(page, "#state", "up"), 10, "the device shown as up")
        assert "extrapolated (outside the calibrated range)" in await text(page, ".legend")
        # three channels in the outline's colour: more than a thousand pixels of it
        await until_async(
            lambda: page.evaluate(f"() => ({EXTRAPOLATED_PIXELS_JS})() > 1000"), 5, "the dashed outlines"
        )
        # the 8 N channel (x 7.5 mm, y 0 mm) on hover: its force, extrapolated
        box = await page.locator("#map").bounding_box()
        # the 480 px canvas draws the 10 mm from -1.25 mm to 8.75 mm inside a 12 px margin
        px_per_mm, scale = (480 - 2 * 12) / 10.0, box["width"] / 480
        px, py = 12 + px_per_mm * (7.5 + 1.25), 12 + px_per_mm * (0.0 + 1.25)
        await page.mouse.move(box["x"] + px * scale, box["y"] + py * scale)
        tip = await text(page, "#tooltip")
        assert tip == "ch03 (7.5, 0 mm): 8.000 N, extrapolated", tip
        assert float(await text(page, "#total-force")) == pytest.approx(0.3 + 2.0 + 8.0 + 1.0 + 6.0, abs=1e-3)
        assert await text(page, "#in-contact") == "5"
        shot = tmp_path / "extrapolated.png"
        await page.screenshot(path=str(shot), full_page=True)  # the legend is below the map
        assert shot.stat().st_size > 10_000
        if target := os.environ.get("TACTILE_SCREENSHOT_EXTRAPOLATED"):
            shutil.copyfile(shot, target)
        await page.close()
    assert errors == [], errors


# ---------------------------------------------------------------- scale, units, numbers, states

#: the map's canvas draws the 4 x 4 grid (pitch 2.5 mm: -1.25 to 8.75 mm) inside a 12 px margin
_PX_PER_MM = (480 - 2 * 12) / 10.0


def _cell_px(index: int) -> tuple[float, float]:
    """The canvas pixel at the centre of channel ``index`` of the 4 x 4 test grid."""
    x_mm, y_mm = (index % 4) * PITCH_MM, (index // 4) * PITCH_MM
    return 12 + _PX_PER_MM * (x_mm + 1.25), 12 + _PX_PER_MM * (y_mm + 1.25)


#: colours in a channel's cell (inner 80 %), at a few points away from the centre, and how many
#: of its pixels differ from the colour at its corner (text or lines drawn over the fill)
CELL_JS = """([cx, cy, half]) => {
  const c = document.getElementById("map");
  const d = c.getContext("2d").getImageData(Math.round(cx - half), Math.round(cy - half),
                                            Math.round(2 * half), Math.round(2 * half));
  const w = d.width;
  const px = (x, y) => { const o = 4 * (y * w + x); return [d.data[o], d.data[o + 1], d.data[o + 2]]; };
  const ref = px(1, 1);
  let differ = 0;
  for (let y = 0; y < d.height; y++) for (let x = 0; x < w; x++) {
    const p = px(x, y);
    if (Math.abs(p[0] - ref[0]) + Math.abs(p[1] - ref[1]) + Math.abs(p[2] - ref[2]) > 60) differ++;
  }
  const q = Math.round(w / 5);
  return { corners: [px(q, q), px(w - q, q), px(q, w - q), px(w - q, w - q)], ref, differ };
}"""
_HALF = _PX_PER_MM * PITCH_MM * 0.92 / 2 * 0.8


async def _cell(page: Any, index: int) -> dict[str, Any]:
    cx, cy = _cell_px(index)
    return dict(await page.evaluate(CELL_JS, [cx, cy, _HALF]))


def _lum(rgb: list[int]) -> float:
    return sum(rgb) / 3


async def _open(browser: Any, url: str) -> tuple[Any, list[str]]:
    page = await browser.new_page(viewport={"width": 1280, "height": 900})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    await page.goto(url)
    await until_async(lambda: _is(page, "#state", "up"), 10, "the device shown as up")
    return page, errors


#: a steady load of about the demo's forces: 1 N at ch05, 0.5 N at ch06, 0.25 N at ch09
DEMO_FORCES = [0.0] * 16
DEMO_FORCES[5], DEMO_FORCES[6], DEMO_FORCES[9] = 1.0, 0.5, 0.25


async def test_auto_range_makes_the_peak_bright_at_demo_forces(browser: Any, tmp_path: Path) -> None:
    """The live simulator at the demo's speed (peak about 1 N) with the server's 5 N default:
    the key's range follows the peak, and the peak cell is drawn in the top of the scale, not
    the dark purple of 1 N on a 0-5 N scale. Writes the after-screenshot."""
    async with gateway_with_page(speed=1.0, scale_max_n=5.0) as gw:
        page, errors = await _open(browser, gw.server.base_url + "/")
        seen: dict[str, Any] = {}

        async def bright_peak() -> bool:
            seen["peak"] = peak = await text(page, "#peak")  # "ch05 0.804 N"
            parts = peak.split()
            if len(parts) != 3 or float(parts[1]) < 0.75:
                return False
            corners = (await _cell(page, int(parts[0][2:])))["corners"]
            seen["corners"] = corners
            return sorted(_lum(c) for c in corners)[1] > 100  # 3 of 4 points bright (the trail may cross one)

        await until_async(bright_peak, 30, "a bright peak cell at about 1 N")
        seen["range"] = await text(page, "#scale-range")
        low, high, unit = _range(seen["range"])
        assert low == 0 and 0.6 < high <= 1.5 and unit == "N (auto)", seen
        # this page is not told the configuration: no what-is-on lines, and no empty heading
        assert await page.locator("#what-is-on li").count() == 0
        assert not await page.locator("#what-is-on-title").is_visible()
        shot = tmp_path / "pressure-map.png"
        await page.screenshot(path=str(shot), full_page=True)
        if target := os.environ.get("TACTILE_SCREENSHOT_DEMO"):
            shutil.copyfile(shot, target)
        await page.close()
    assert errors == [], errors


def _range(key: str) -> tuple[float, float, str]:
    """``0–1.00 N (auto)`` -> (0.0, 1.0, "N (auto)")."""
    span, unit = key.split(" ", 1)
    low, high = span.split("–")
    return float(low), float(high), unit


async def test_a_fixed_scale_keeps_0_to_5_n_when_asked(browser: Any) -> None:
    async with steady_page(DEMO_FORCES) as server:
        page, errors = await _open(browser, server.base_url + "/?scale=fixed")
        await until_async(lambda: _is(page, "#scale-range", "0–5.00 N (fixed)"), 5, "the fixed 0-5 N key")
        # 1 N of 5 N: the dark end of the scale, steadily
        assert max(_lum(c) for c in (await _cell(page, 5))["corners"]) < 80
        # a maximum typed in the control is kept in the URL (a bookmark) and drawn
        await page.fill("#scale-max", "2")
        await page.dispatch_event("#scale-max", "change")
        await until_async(lambda: _is(page, "#scale-range", "0–2.00 N (fixed)"), 5, "the 0-2 N key")
        assert "max=2" in page.url and "scale=fixed" in page.url, page.url
        # the URL alone gives the same scale
        await page.goto(server.base_url + "/?max=2")
        await until_async(
            lambda: _is(page, "#scale-range", "0–2.00 N (fixed)"), 5, "the bookmarked 0-2 N key"
        )
        await page.close()
    assert errors == [], errors


async def test_the_kpa_unit_shows_force_over_the_cell_area(browser: Any) -> None:
    async with steady_page(DEMO_FORCES) as server:
        dev = await _polled_device(server.base_url)
        assert dev["cell_area_mm2"] == 6.25 and dev["units"]["pressure"] == "kPa"
        page, errors = await _open(browser, server.base_url + "/?unit=kPa")
        # the peak, 1 N / 6.25 mm^2 = 160 kPa, sets the auto range's top at the next step above
        await until_async(lambda: _is(page, "#scale-range", "0–200 kPa (auto)"), 5, "the key in kPa")
        box = await page.locator("#map").bounding_box()
        scale = box["width"] / 480
        for index, force in ((5, 1.0), (6, 0.5), (9, 0.25)):
            px, py = _cell_px(index)
            await page.mouse.move(box["x"] + px * scale, box["y"] + py * scale)
            tip = await text(page, "#tooltip")
            assert tip.startswith(f"ch{index:02d} ") and f"{force:.3f} N, " in tip, tip
            kpa = float(tip.split(" N, ")[1].split(" kPa")[0])
            assert kpa == pytest.approx(force * 1000 / 6.25, abs=0.05), tip
        await page.close()
    assert errors == [], errors


def _get_json(url: str) -> Any:
    import json

    with urllib.request.urlopen(url, timeout=10) as resp:
        return json.load(resp)


async def _polled_device(base: str) -> dict[str, Any]:
    """The device's entry in /api/devices once its first poll has completed."""
    seen: dict[str, Any] = {}

    async def polled() -> bool:
        devices = (await _to_thread(_get_json, base + "/api/devices"))["devices"]
        seen["dev"] = devices[0] if devices else None
        return bool(devices) and devices[0]["seq"] > 0

    await until_async(polled, 10, "the device's first poll")
    return dict(seen["dev"])


async def test_numbers_appear_on_the_cells_when_toggled(browser: Any) -> None:
    async with steady_page(DEMO_FORCES) as server:
        page, errors = await _open(browser, server.base_url + "/?scale=fixed")

        async def drawn() -> bool:
            return _lum((await _cell(page, 5))["ref"]) > 8  # ch05 (1 N) is no longer black

        await until_async(drawn, 5, "the map drawn")
        # ch06 (0.5 N) and ch00 (0 N): plain fills without numbers
        assert (await _cell(page, 6))["differ"] == 0 and (await _cell(page, 0))["differ"] == 0
        await page.check("#numbers")

        async def written() -> bool:
            return all([(await _cell(page, k))["differ"] > 20 for k in (0, 5, 6)])

        await until_async(written, 5, "numbers drawn on the cells")
        assert "numbers=1" in page.url
        await page.close()
    assert errors == [], errors


async def test_the_page_says_what_is_on(browser: Any) -> None:
    """The summary lists what check-config says of the device: its values, how its force is
    read (here a calibration line on the 14 enabled channels: no drift correction) and that
    nothing is written to it."""
    async with steady_page(DEMO_FORCES, disabled=(3, 12)) as server:
        page, errors = await _open(browser, server.base_url + "/")

        async def listed() -> bool:
            return len(await page.locator("#what-is-on li").all_text_contents()) > 3

        await until_async(listed, 5, "the what-is-on list")
        lines = await page.locator("#what-is-on li").all_text_contents()
        title_shown = await page.locator("#what-is-on-title").is_visible()
        await page.close()
    assert title_shown, "the what-is-on list has no heading"
    assert lines[0] == "values: resistance in ohm, float32, input registers 400+32", lines
    assert "force: calibration line (static: no drift correction): 14 channels" in lines, lines
    assert lines[-1] == "writes: none (nothing is ever written to this device)", lines
    assert errors == [], errors


async def test_a_disabled_channel_has_its_own_look_and_legend_entry(browser: Any) -> None:
    async with steady_page(DEMO_FORCES, disabled=(3, 12)) as server:
        dev = await _polled_device(server.base_url)
        assert [c["name"] for c in dev["disabled_channels"]] == ["ch03", "ch12"]
        assert [c["index"] for c in dev["channels"]] == [k for k in range(16) if k not in (3, 12)]
        page, errors = await _open(browser, server.base_url + "/")
        assert "disabled (off in the configuration)" in await text(page, ".legend")
        assert await page.locator("#legend-disabled").is_visible()

        async def crossed() -> bool:
            off, no_contact = await _cell(page, 3), await _cell(page, 0)
            # a grey cross on a dark grey fill (#1c2026) vs the near black of no contact
            return (
                off["differ"] > 200
                and _lum(off["ref"]) > 20
                and no_contact["differ"] == 0
                and _lum(no_contact["ref"]) < 8
            )

        await until_async(crossed, 5, "the disabled channels drawn crossed")
        assert (await _cell(page, 12))["differ"] > 200
        await page.close()
    assert errors == [], errors


async def test_the_summary_is_marked_old_while_the_device_is_stale(browser: Any) -> None:
    async with gateway_with_page() as gw:
        page, errors = await _open(browser, gw.server.base_url + "/")
        assert not await page.locator("#summary-old").is_visible()
        assert "stale" not in (await page.get_attribute("#summary", "class") or "")
        before = [await page.locator(s).bounding_box() for s in ("#map", "#summary", ".side")]
        await gw.stop_sim()
        await until_async(lambda: page.locator("#summary-old").is_visible(), 5, "the summary marked old")
        assert (await text(page, "#summary-old")).startswith("old: stale")
        assert "stale" in (await page.get_attribute("#summary", "class") or "")
        opacity = await page.evaluate("() => getComputedStyle(document.querySelector('#summary dl')).opacity")
        assert float(opacity) < 0.6
        # the error message does not move the map, the key or the panel
        await until_async(
            lambda: page.evaluate("() => document.getElementById('health-up').textContent.startsWith('not')"),
            5, "the error shown",
        )  # fmt: skip
        after = [await page.locator(s).bounding_box() for s in ("#map", "#summary", ".side")]
        assert [(b["x"], b["y"]) for b in after] == [(b["x"], b["y"]) for b in before]
        await gw.start_sim()
        await until_async(lambda: _is(page, "#state", "up"), 10, "the device up again")
        assert not await page.locator("#summary-old").is_visible()
        await page.close()
    assert errors == [], errors
