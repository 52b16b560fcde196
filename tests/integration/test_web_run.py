"""``tactile-gateway run`` as a user starts it, with regions of interest and a ``[web]``
section (issue 35 items 3-5): its frames carry the regions, its history serves the last
seconds, and its export is a record that names the configuration, so ``view`` plays it back
with the configuration's regions of interest in every frame."""

from __future__ import annotations

import asyncio
import json
import signal
from pathlib import Path

import pytest
from netutil import free_port
from test_metrics_http import GATEWAY, _array, _write_config, get, scrape_until
from waiting import until

from gateway.analysis.records import read_record
from gateway.cli.view_cmd import load_playback
from sim_device import serve_tcp

ROIS = """
[[bus.device.roi]]
name = "left"
channels = ["0-1", "4-5", "8-9", "12-13"]

[[bus.device.roi]]
name = "all"
channels = ["0-15"]

[web]
history_s = 60
export_s = 30
"""


@pytest.mark.slow  # a gateway process
async def test_run_serves_rois_history_and_an_export_that_view_plays_back(tmp_path: Path) -> None:
    array = _array(scenario="indentation", speed=3.0)
    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        port = free_port()
        cfg = tmp_path / "gateway.toml"
        _write_config(cfg, port, sim.port, 0.05)
        cfg.write_text(cfg.read_text() + ROIS)
        proc = await asyncio.create_subprocess_exec(
            *GATEWAY, "run", "-c", str(cfg), stderr=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.DEVNULL
        )
        assert proc.stderr is not None
        errors = asyncio.create_task(proc.stderr.read())
        base = f"http://127.0.0.1:{port}"
        try:
            up_key = ("tactile_device_up", (("device", "array1"),))
            values = await scrape_until(
                f"{base}/metrics", lambda v: v.get(up_key) == 1.0, proc, 30, "the device up"
            )
            assert values.get(up_key) == 1.0
            assert {k[1] for k in values if k[0] == "tactile_roi_force_newtons"} == {
                (("device", "array1"), ("roi", "left")),
                (("device", "array1"), ("roi", "all")),
            }
            status, body, _ = await asyncio.to_thread(get, f"{base}/api/devices/array1/frame")
            frame = json.loads(body)
            assert status == 200 and [r["name"] for r in frame["rois"]] == ["left", "all"]
            status, body, _ = await asyncio.to_thread(get, f"{base}/api/devices/array1")
            assert json.loads(body)["history_s"] == 60.0 and json.loads(body)["export_s"] == 30.0

            async def polls_kept() -> bool:
                status, body, _ = await asyncio.to_thread(
                    get, f"{base}/api/devices/array1/history?seconds=60"
                )
                return status == 200 and len(json.loads(body)["points"]) >= 10

            await until(polls_kept, 20, "ten polls in the history", step_s=0.05)
            status, text, headers = await asyncio.to_thread(get, f"{base}/api/devices/array1/export.csv")
            assert status == 200 and headers["Content-Type"].startswith("text/csv")
            proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(proc.wait(), timeout=15) == 0
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            err = (await errors).decode()
    path = tmp_path / "export.csv"
    path.write_text(text)
    record = read_record(path)
    assert record.metadata["config"] == str(cfg.resolve()), err
    assert len(record.channels) == 16
    playback = load_playback(path, None, None, [])  # the configuration the export names
    assert playback.info["layout_from"] == f"the record's configuration {cfg.resolve()}"
    assert [r["name"] for r in playback.frames[-1]["rois"]] == ["left", "all"]
    whole = playback.frames[-1]["rois"][1]
    assert whole["force_n"] == pytest.approx(playback.frames[-1]["total_force_n"], abs=1e-6)
