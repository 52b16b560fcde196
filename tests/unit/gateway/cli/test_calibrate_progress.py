"""``calibrate``'s progress over several channels: plain lines on stderr when it is not a terminal
(and with ``--json``, whose stdout stays one JSON object), none with ``--no-progress``, and the
bar's counts (tqdm) as channels and records are done."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest
from array_records import array_record
from click.testing import CliRunner

from gateway.cli import main
from gateway.cli.calibrate_progress import Bar, Lines

pytestmark = pytest.mark.slow  # a few calibrations of simulated channels

SHORT = ["--model", "line", "--objective", "log-r", "--force-offset", "none", "--jobs", "2"]
LINE = re.compile(
    r"^\[ *(\d+\.\d) s\] (\S+) channel '(taxel\d)' done: "
    r"(\d)/3 channels, (\d)/1 records(, about \d+ s left)?$"
)


def test_plain_lines_on_stderr_and_pure_json_on_stdout(tmp_path: Path) -> None:
    record = array_record(tmp_path / "array.csv", channels=3, seed=5)
    result = CliRunner().invoke(main, ["calibrate", str(record), "--json", *SHORT])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)  # the whole of stdout is one JSON object
    assert [c["channel"] for c in payload["calibrations"]] == ["taxel0", "taxel1", "taxel2"]
    found = [LINE.match(line) for line in result.stderr.splitlines()]
    assert all(found) and len(found) == 3, result.stderr
    matches = [m for m in found if m is not None]
    assert [int(m[4]) for m in matches] == [1, 2, 3]  # channels done, counted up
    assert sorted(m[3] for m in matches) == ["taxel0", "taxel1", "taxel2"]
    assert {m[2] for m in matches} == {str(record)}
    seconds = [float(m[1]) for m in matches]
    assert seconds == sorted(seconds)
    quiet = CliRunner().invoke(main, ["calibrate", str(record), "--json", "--no-progress", *SHORT])
    assert quiet.exit_code == 0 and quiet.stderr == "" and json.loads(quiet.stdout) == payload


def test_the_time_left_is_the_pace_so_far_times_the_channels_to_do() -> None:
    out = io.StringIO()
    lines = Lines(records=2, out=out)
    lines.add_record("a.csv", 4)
    assert lines.left_s() is None  # nothing done: no pace yet
    lines.start_s -= 10.0  # as if the run began 10 s ago
    lines.channel_done("a.csv", "taxel0")
    left = lines.left_s()
    # 1 channel in 10 s; 3 more of a.csv and the 4 the unread record is assumed to have
    assert left is not None and 69.0 <= left <= 71.0
    assert "1/4 channels, 0/2 records, about 70 s left" in out.getvalue()


def test_the_bar_counts_channels_and_records() -> None:
    out = io.StringIO()
    bar = Bar(records=2, out=out)
    bar.add_record("a.csv", 2)
    bar.channel_done("a.csv", "taxel0")
    bar.channel_done("a.csv", "taxel1")
    bar.record_done("a.csv", ok=True)
    bar.close()
    last = out.getvalue().split("\r")[-1]
    assert "2/2" in last and "1/2 records" in last, out.getvalue()
