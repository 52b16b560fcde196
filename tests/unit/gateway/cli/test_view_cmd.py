"""``tactile-gateway view RECORD``: where the layout comes from, one-line errors with exit
status 2 for input it cannot show, and a server that prints its address and stops cleanly."""

from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
from click.testing import CliRunner

from gateway.analysis.records import format_record
from gateway.cli import main
from gateway.cli.view_cmd import load_playback

REPO = Path(__file__).resolve().parents[4]
EXAMPLE = REPO / "examples" / "gateway.toml"


def record_text(names: list[str], metadata: dict[str, str] | None = None) -> str:
    times = [0.0, 0.1, 0.2]
    rs = [[20_000.0 if k == 0 else math.inf for k in range(len(names))] for _ in times]
    return format_record(metadata or {}, names, times, rs)


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, ["view", *args])
    return result.exit_code, result.output


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no such file"),
        ("", "no header row"),
        ("time_s,resistance_ohm\n", "no data rows"),
        ("hello,world\n1,2\n", "missing required column 'time_s'"),
        ("time_s,resistance_ohm\n0,abc\n", "'abc' is not a number"),
    ],
    ids=["missing", "empty-file", "empty-record", "not-a-record", "bad-number"],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, content: str | None, message: str) -> None:
    path = tmp_path / "rec.csv"
    if content is not None:
        path.write_text(content, encoding="utf-8")
    code, out = run(str(path))
    assert code == 2, out
    assert message in out and "Traceback" not in out
    assert len(out.strip().splitlines()) == 1, out


def test_channels_not_of_the_device_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    path.write_text(record_text(["nail", "heel", "tip"]), encoding="utf-8")
    code, out = run(str(path), "--config", str(EXAMPLE))
    assert code == 2 and "nail, heel are not enabled channels of device 'array1'" in out, out
    assert len(out.strip().splitlines()) == 1


def test_an_unknown_device_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    path.write_text(record_text(["tip"]), encoding="utf-8")
    code, out = run(str(path), "--config", str(EXAMPLE), "--device", "nope")
    assert code == 2 and "no device 'nope'" in out, out


def test_positions_from_the_config(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    path.write_text(record_text(["tip", "ch05"]), encoding="utf-8")
    pb = load_playback(path, EXAMPLE, None)
    chans = pb.layout["channels"]
    # the device's 15 enabled channels (ch15 is off: listed as disabled)
    assert len(chans) == 15 and pb.layout["name"] == "array1"
    assert [c["name"] for c in pb.layout["disabled_channels"]] == ["ch15"]
    assert (chans[5]["name"], chans[5]["x_mm"], chans[5]["y_mm"]) == ("ch05", 2.5, 2.5)  # 4 columns
    # tip is loaded; channels the record does not have read no value (status error, 6)
    assert pb.frames[0]["force_n"][0] > 0.1 and pb.frames[0]["status"][1] == 6
    assert pb.info["layout_from"] == str(EXAMPLE)


def test_the_config_the_record_names_is_used(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    path.write_text(record_text(["tip"], {"config": str(EXAMPLE)}), encoding="utf-8")
    pb = load_playback(path, None, None)
    assert pb.layout["name"] == "array1" and "record's configuration" in pb.info["layout_from"]


def test_fallback_grid_is_said(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    path.write_text(record_text(["a", "b", "c"], {"pitch_mm": "4"}), encoding="utf-8")
    notes: list[str] = []
    pb = load_playback(path, None, None, notes)
    # 3 channels: 2 columns (ceil of the square root), at the record's 4 mm
    assert [(c["name"], c["x_mm"], c["y_mm"]) for c in pb.layout["channels"]] == [
        ("a", 0.0, 0.0), ("b", 4.0, 0.0), ("c", 0.0, 4.0)]  # fmt: skip
    assert len(notes) == 1 and "2 columns at 4 mm" in notes[0]


def test_bad_layout_metadata_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    path.write_text(record_text(["a"], {"columns": "many"}), encoding="utf-8")
    code, out = run(str(path))
    assert code == 2 and "metadata 'columns'" in out, out


def test_serves_prints_its_address_and_stops_on_sigterm(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    path.write_text(record_text(["ch00", "ch01"]), encoding="utf-8")
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli.view_cmd", str(path), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # the command prints its address once it serves
        m = re.search(r"page on (http://127\.0\.0\.1:(\d+)/)", line)
        assert m and int(m[2]) > 0, line
        with urllib.request.urlopen(m[1] + "api/playback", timeout=10) as resp:
            body = json.loads(resp.read())
        assert len(body["frames"]) == 3 and body["end_s"] == pytest.approx(0.2)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
        assert "Traceback" not in (proc.stderr.read() if proc.stderr else "")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
