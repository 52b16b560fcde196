"""Issue 24 §3: ``calibrate`` and ``discrepancy`` on an endless input (/dev/zero) or a pipe are
refused unread, as ``check-config`` and ``run`` refuse them, and a record larger than the
reader's limit is refused naming the limit (the limit is made small here)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from gateway.analysis import records
from gateway.analysis.records import read_record
from gateway.cli import main
from gateway.errors import RecordError

RECORD = "time_s,channel,resistance_ohm,force_n\n" + "".join(
    f"{i * 0.1:.1f},a,{1e5 / (1 + i % 7):.1f},{0.1 * (i % 7):.1f}\n" for i in range(200)
)


def invoke(command: str, path: Path) -> tuple[int, str]:
    result = CliRunner().invoke(main, [command, str(path)])
    return result.exit_code, result.output


@pytest.mark.parametrize("command", ["calibrate", "discrepancy"])
def test_a_device_is_refused_unread(command: str) -> None:
    code, output = invoke(command, Path("/dev/zero"))
    assert code == 2, output
    assert "/dev/zero: not a regular file" in output and "a record is a file" in output


@pytest.mark.parametrize("command", ["calibrate", "discrepancy"])
def test_a_named_pipe_is_refused_without_waiting_for_a_writer(tmp_path: Path, command: str) -> None:
    fifo = tmp_path / "record.csv"
    os.mkfifo(fifo)
    code, output = invoke(command, fifo)
    assert code == 2, output
    assert "not a regular file" in output


@pytest.mark.parametrize("command", ["calibrate", "discrepancy"])
def test_a_record_over_the_limit_is_refused_naming_the_limit(
    tmp_path: Path, command: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "r.csv"
    path.write_text(RECORD)
    monkeypatch.setattr(records, "MAX_RECORD_BYTES", 1024)
    code, output = invoke(command, path)
    assert code == 2, output
    assert f"{path}: larger than the limit of 1 KiB for a record" in output


def test_the_limit_bounds_what_is_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "r.csv"
    path.write_text(RECORD)
    size = path.stat().st_size
    assert read_record(path, max_bytes=size).channel("a").n_samples == 200  # at the limit: read
    with pytest.raises(RecordError, match=f"larger than the limit of {size - 1} bytes"):
        read_record(path, max_bytes=size - 1)
    # a file that grows while read (st_size said less) is cut off at the limit, in steps
    monkeypatch.setattr(records, "_READ_CHUNK", 64)
    monkeypatch.setattr(records.os, "fstat", lambda fd: os.stat_result((0o100644, 0, 0, 1, 0, 0, 0, 0, 0, 0)))
    with pytest.raises(RecordError, match="larger than the limit of 1 KiB"):
        read_record(path, max_bytes=1024)
    assert records.MAX_RECORD_BYTES == 2 * 1024**3
