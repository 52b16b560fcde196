"""Export (issue 35 item 5): the gateway's ``/api/devices/{name}/export.csv`` against the
simulated array over loopback Modbus TCP is a record, written by ``record``'s writer, that
reads back with ``tactile-gateway apply`` and ``tactile-gateway view`` (its playback, as the
command loads it); in playback the same endpoint gives the record's own rows between two
times, which read back the same way."""

from __future__ import annotations

import math
from pathlib import Path

import aiohttp
import numpy as np
from click.testing import CliRunner
from prometheus_client import CollectorRegistry
from web_fixtures import first_poll, gateway_with_page, until

from gateway.analysis.records import read_record
from gateway.cli import main
from gateway.cli.view_cmd import load_playback
from gateway.metrics.server import MetricsServer
from gateway.web.playback import PlaybackPage

CALIBRATION = '[channel."ch05"]\nbaseline_ohm = 5e8\n'


def apply_reads(tmp_path: Path, record: Path) -> None:
    """``tactile-gateway apply`` reads ``record`` (channel ch05) and writes its output."""
    cal = tmp_path / "cal.toml"
    cal.write_text(CALIBRATION)
    out = tmp_path / f"{record.stem}-applied.csv"
    result = CliRunner().invoke(
        main, ["apply", str(cal), str(record), "--out", str(out), "--channel", "ch05"]
    )
    assert result.exit_code == 0, result.output
    applied = read_record(out)
    assert list(applied.channels) == ["ch05"]
    assert len(applied.channels["ch05"].time_s) == len(read_record(record).channels["ch05"].time_s)


async def test_an_exported_span_is_a_record_that_apply_and_view_read(tmp_path: Path) -> None:
    async with gateway_with_page(export_s=30.0) as gw, aiohttp.ClientSession(gw.server.base_url) as http:
        await first_poll(gw)

        def kept() -> int:
            past = gw.hub.history("arr")
            return 0 if past is None else past.export_frames()

        await until(lambda: kept() >= 20, 20, "20 polls kept for export")
        past = gw.hub.history("arr")
        assert past is not None
        polls = past.export(0.0, math.inf)
        from_s, to_s = polls[2].timestamp_s, polls[-3].timestamp_s
        async with http.get(f"/api/devices/arr/export.csv?from_s={from_s!r}&to_s={to_s!r}") as resp:
            assert resp.status == 200
            assert resp.headers["Content-Type"].startswith("text/csv")
            text = await resp.text()
        async with http.get("/api/devices/arr/export.csv") as resp:  # the last 10 s
            assert resp.status == 200 and (await resp.text()).count("\n") > 16
        for query in ("from_s=abc", "from_s=5&to_s=4", "to_s=inf"):
            async with http.get(f"/api/devices/arr/export.csv?{query}") as resp:
                assert resp.status == 400, query

    exported = [s for s in polls if from_s <= s.timestamp_s <= to_s]
    assert len(exported) == len(polls) - 4
    path = tmp_path / "export.csv"
    path.write_text(text)
    record = read_record(path)
    assert record.metadata["source"] == "test export"
    assert list(record.channels) == [f"ch{k:02d}" for k in range(16)]
    for k, name in enumerate(record.channels):
        ch = record.channels[name]
        # one row per exported poll, time from the first one, each resistance as polled
        assert len(ch.time_s) == len(exported)
        clock = [
            s.device_time_s if s.device_time_s is not None else s.last_success_timestamp_s for s in exported
        ]
        expected_t = [round(c - clock[0], 6) for c in clock]  # type: ignore[operator]
        assert ch.time_s.tolist() == expected_t
        got = [float(s.resistance_ohm[k]) for s in exported]
        assert np.array_equal(ch.resistance_ohm, np.where(np.isfinite(got), got, np.inf))

    apply_reads(tmp_path, path)
    playback = load_playback(path, None, None, [])
    assert playback.samples_total == len(exported)
    assert len(playback.frames[0]["force_n"]) == 16

    # in playback, the endpoint exports the record's own rows between two times
    server = MetricsServer(CollectorRegistry(), "127.0.0.1", 0, None, PlaybackPage(playback).install)
    t0, t1 = expected_t[3], expected_t[-3]
    with server:
        async with (
            aiohttp.ClientSession(server.base_url) as http,
            http.get(f"/api/devices/{playback.layout['name']}/export.csv?from_s={t0}&to_s={t1}") as resp,
        ):
            assert resp.status == 200
            span = await resp.text()
    again = tmp_path / "span.csv"
    again.write_text(span)
    rows = read_record(again)
    assert rows.channels["ch05"].time_s.tolist() == [t for t in expected_t if t0 <= t <= t1]
    assert np.array_equal(
        rows.channels["ch05"].resistance_ohm, record.channels["ch05"].resistance_ohm[3 : len(expected_t) - 2]
    )
    apply_reads(tmp_path, again)
    assert load_playback(again, None, None, []).samples_total == len(expected_t) - 5
