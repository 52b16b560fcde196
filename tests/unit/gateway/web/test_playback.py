"""Playback frames (``gateway.web.playback``) from a small record written here, read with a
line conversion (conductance = m F + n) so the forces and totals are known by hand."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from aiohttp import web
from aiohttp.test_utils import TestClient, TestServer

from gateway.analysis.records import format_record, read_record
from gateway.cli.view_cmd import record_snapshots
from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.model.conversion import line_conversion
from gateway.web.playback import PlaybackPage, playback_frames, thin

M, N = 2e-5, 1e-6  # conductance (S) = M * force (N) + N
PITCH_MM = 2.5


def line_device(n_channels: int = 4, columns: int = 2) -> DeviceConfig:
    line = line_conversion(M, N, 0.01, 50.0)
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", (k % columns) * PITCH_MM, (k // columns) * PITCH_MM, True,
                      PAPER_EFFECTS, SensorParams(), None, line)
        for k in range(n_channels)
    )  # fmt: skip
    return DeviceConfig("arr", 1, "float32", n_channels, RegisterMap(), Divider(), channels, False,
                        GridLayout(n_channels, columns, PITCH_MM, PITCH_MM), None)  # fmt: skip


def ohm(force_n: float) -> float:
    return 1.0 / (M * force_n + N)


#: the forces of the record (N), one row per sample at 0, 0.5, 1.0 s: ch00 early, ch03 late
FORCES = [[1.0, 0.5, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 3.0]]
REFERENCE = [[1.1, 0.4, 0.0, 0.0], [2.2, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 2.9]]
TIMES_S = [0.0, 0.5, 1.0]


def write(tmp_path: Path, with_reference: bool = True) -> Path:
    rs = [[ohm(f) if f > 0 else math.inf for f in row] for row in FORCES]
    text = format_record(
        {"source": "test"}, ["ch00", "ch01", "ch02", "ch03"], TIMES_S, rs,
        REFERENCE if with_reference else None,
    )  # fmt: skip
    path = tmp_path / "rec.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_frames_carry_the_recorded_forces_and_hand_computed_totals(tmp_path: Path) -> None:
    record = read_record(write(tmp_path))
    snaps, has_ref, _ = record_snapshots(record, line_device())
    assert has_ref and len(snaps) == 3
    pb = playback_frames(snaps, has_reference=True, source="rec.csv")
    assert (pb.start_s, pb.end_s) == (0.0, 1.0)
    assert [f["t"] for f in pb.frames] == TIMES_S
    assert [f["seq"] for f in pb.frames] == [1, 2, 3]
    # totals by hand: 1.0 + 0.5, 2.0, 3.0 N; references 1.1 + 0.4, 2.2, 2.9 N
    assert [f["total_force_n"] for f in pb.frames] == pytest.approx([1.5, 2.0, 3.0], abs=1e-5)
    assert [f["reference_total_force_n"] for f in pb.frames] == pytest.approx([1.5, 2.2, 2.9], abs=1e-9)
    assert pb.frames[0]["force_n"] == pytest.approx([1.0, 0.5, 0.0, 0.0], abs=1e-5)
    # the centre of pressure by hand: (1.0 * 0 + 0.5 * 2.5) / 1.5 = 0.8333 mm at y 0; then ch03
    assert pb.frames[0]["cop_mm"] == pytest.approx([2.5 * 0.5 / 1.5, 0.0], abs=1e-5)
    assert pb.frames[2]["cop_mm"] == pytest.approx([2.5, 2.5], abs=1e-6)
    assert pb.frames[2]["peak_channel"] == "ch03"
    # the same members as a live frame, plus the reference total
    from gateway.web.frames import frame_json

    assert set(pb.frames[0]) == set(frame_json(snaps[0], 1, None)) | {
        "reference_total_force_n",
        "reference_force_n",
    }
    # each channel's reference, as recorded (the page's error per channel is force - this)
    for frame, reference in zip(pb.frames, REFERENCE, strict=True):
        assert frame["reference_force_n"] == pytest.approx(reference, abs=1e-9)
    assert [c["name"] for c in pb.layout["channels"]] == ["ch00", "ch01", "ch02", "ch03"]
    assert pb.layout["cell_area_mm2"] == pytest.approx(6.25)


def test_without_a_reference_column_the_reference_is_null(tmp_path: Path) -> None:
    snaps, has_ref, _ = record_snapshots(read_record(write(tmp_path, with_reference=False)), line_device())
    pb = playback_frames(snaps, has_reference=has_ref)
    assert not has_ref and all(f["reference_total_force_n"] is None for f in pb.frames)
    assert all("reference_force_n" not in f for f in pb.frames)


def test_no_snapshot_is_refused() -> None:
    with pytest.raises(ValueError, match="no device sample"):
        playback_frames([], has_reference=False)


def test_thinning_keeps_the_end_and_the_bound() -> None:
    assert thin(5, 10) == [0, 1, 2, 3, 4]
    kept = thin(1001, 100)
    assert len(kept) <= 100 and kept[0] == 0 and kept[-1] == 1000
    assert np.all(np.diff(kept) > 0)


async def test_the_page_and_api_are_served(tmp_path: Path) -> None:
    snaps, has_ref, _ = record_snapshots(read_record(write(tmp_path)), line_device())
    page = PlaybackPage(playback_frames(snaps, has_reference=has_ref, source="rec.csv"))
    app = web.Application()
    page.install(app)
    async with TestClient(TestServer(app)) as client:
        index = await client.get("/")
        assert index.status == 200 and "script-src 'self'" in index.headers["Content-Security-Policy"]
        assert 'id="playback"' in await index.text()
        devices = await (await client.get("/api/devices")).json()
        assert devices["playback"]["has_reference"] is True
        assert devices["playback"]["n_frames"] == 3
        assert devices["devices"][0]["playback"] is True and devices["devices"][0]["name"] == "arr"
        assert (await client.get("/api/devices/arr")).status == 200
        assert (await client.get("/api/devices/nope")).status == 404
        assert (await client.get("/static/nope.js")).status == 404
        body = json.loads(await (await client.get("/api/playback")).read())
        assert body["device"] == "arr" and len(body["frames"]) == 3
        assert body["frames"][1]["total_force_n"] == pytest.approx(2.0, abs=1e-5)
