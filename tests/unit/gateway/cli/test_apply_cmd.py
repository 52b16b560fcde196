"""``tactile-gateway apply CAL RECORD --out FILE``: the record written, the report, clean errors."""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.records import format_record, read_record, write_record
from gateway.cli import main

#: F = 1e5 / R (a conductance line of 1e-5 S/N through 0).
LINE = '[line."tip"]\nslope_s_per_n = 1e-5\nintercept_s = 0.0\n'


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    """A line calibration of ``tip`` and a record: 0 N, then 2 N held 5 s read as 2.5 N at
    first and 2 N after, then 0 N (every 0.5 s)."""
    cal = tmp_path / "cal.toml"
    cal.write_text(LINE)
    t = np.arange(0.0, 8.0, 0.5)
    force = np.where((t >= 1.0) & (t < 6.5), 2.0, 0.0)
    r = np.where(force > 0, 5e4, np.inf)
    r[2] = 4e4  # the hold's first row reads 2.5 N
    rec = tmp_path / "rec.csv"
    write_record(rec, format_record({"source": "bench"}, ["tip"], t, r[:, None], force[:, None]))
    return cal, rec


def test_apply_writes_the_record_with_tracked_static_and_status(
    tmp_path: Path, files: tuple[Path, Path]
) -> None:
    cal, rec = files
    out, png = tmp_path / "out.csv", tmp_path / "out.png"
    result = CliRunner().invoke(main, ["apply", str(cal), str(rec), "--out", str(out), "--plot", str(png)])
    assert result.exit_code == 0, result.output
    back = read_record(out, require_force=True)
    assert back.metadata["source"] == "tactile-gateway apply" and back.metadata["record_source"] == "bench"
    assert back.metadata["channels"] == "tip=tip"
    assert back.channel("tip").n_samples == 16
    rows = [line.split(",") for line in out.read_text().splitlines() if not line.startswith("#")]
    header = rows[0]
    assert header == [
        "time_s",
        "channel",
        "resistance_ohm",
        "force_n",
        "force_tracked_n",
        "force_static_n",
        "status",
    ]
    tracked = [float(r[4]) for r in rows[1:]]
    assert tracked[:4] == [0.0, 0.0, 2.5, 2.0] and tracked[-1] == 0.0
    assert [r[6] for r in rows[1:4]] == ["no_contact", "no_contact", "ok"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the report: RMS over 16 rows with one error of 0.5 N, in the hold's first row (1.0 s); the
    # hold is measured without 0.5 s at each end (1.5-5.5 s, 9 rows): no error at either edge
    rms = 0.5 / math.sqrt(16)
    assert f"{rms:.4f} ({100 * rms / 2.0:.2f} %)" in result.output
    (hold_line,) = [line for line in result.output.splitlines() if line.startswith("tip ") and "1.50" in line]
    assert hold_line.split() == ["tip", "1.50", "5.50", "2", "9", "+0.0000", "+0.0000", "+0.0000", "+0.0000"]
    assert f"wrote {out}" in result.output and f"wrote {png}" in result.output


def test_json_is_one_object_with_the_same_numbers(tmp_path: Path, files: tuple[Path, Path]) -> None:
    cal, rec = files
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(main, ["apply", str(cal), str(rec), "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["written"] == str(out) and payload["reference"] is True
    (channel,) = payload["channels"]
    assert channel["model"] == "line" and channel["status"] == {"ok": 11, "no_contact": 5}
    assert channel["errors"]["tracked"]["rms_n"] == pytest.approx(0.125)
    assert channel["errors"]["static"]["rms_pct_fs"] == pytest.approx(6.25)
    (hold,) = channel["holds"]
    assert (hold["start_s"], hold["end_s"], hold["rows"], hold["edge_rows"]) == (1.5, 5.5, 9, 1)
    assert hold["tracked"] == {"start_error_n": pytest.approx(0.0), "end_error_n": pytest.approx(0.0)}


def test_as_maps_a_record_channel_to_a_calibration_table(tmp_path: Path) -> None:
    cal = tmp_path / "cal.toml"
    cal.write_text(LINE)
    rec = tmp_path / "r.csv"
    rec.write_text("time_s,resistance_ohm\n0,5e4\n1,2.5e4\n")  # no channel column: channel "0"
    out = tmp_path / "o.csv"
    result = CliRunner().invoke(main, ["apply", str(cal), str(rec), "--out", str(out), "--as", "0=tip"])
    assert result.exit_code == 0, result.output
    assert "no reference force" in result.output
    back = [line.split(",") for line in out.read_text().splitlines()[-2:]]
    assert [(r[1], float(r[3]), r[5]) for r in back] == [("0", 2.0, "ok"), ("0", 4.0, "ok")]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{tmp}/none.toml", "{rec}"], "none.toml: no such file (calibration file)"),
        (["{cal}", "{tmp}/none.csv"], "none.csv: no such file"),
        (["{tmp}/bad.toml", "{rec}"], "bad.toml: invalid TOML at line 1"),
        (["{cal}", "{tmp}/empty.csv"], "empty.csv: no data rows after the header"),
        (["{cal}", "{rec}", "--channel", "tap"], "no channel 'tap' in the record (record channels: tip; "),
        (
            ["{tmp}/other.toml", "{rec}"],
            "record channel 'tip' has no calibration table (record channels: tip; calibration channels: "
            "pad); map a record channel to a table with --as RECORD_CH=CAL_CH",
        ),
        (["{cal}", "{rec}", "--as", "tip"], "'tip' is not RECORD_CH=CAL_CH"),
        (["{cal}", "{rec}", "--as", "tip=pad"], "'tip' is mapped to 'pad', which has no calibration table"),
    ],
)
def test_bad_input_is_a_clean_message(
    tmp_path: Path, files: tuple[Path, Path], args: list[str], message: str
) -> None:
    cal, rec = files
    (tmp_path / "bad.toml").write_text('[line."tip"\n')
    (tmp_path / "other.toml").write_text('[channel."pad"]\nr0_ohm = 1e5\n')
    (tmp_path / "empty.csv").write_text("# nothing yet\ntime_s,channel,resistance_ohm\n")
    argv = [a.format(tmp=tmp_path, cal=cal, rec=rec) for a in args]
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(main, ["apply", *argv, "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output
    assert isinstance(result.exception, SystemExit)  # click's usage error, not a crash
    assert not out.exists()


def test_out_never_replaces_an_input_nor_goes_into_a_missing_folder(
    tmp_path: Path, files: tuple[Path, Path]
) -> None:
    cal, rec = files
    before = rec.read_text()
    result = CliRunner().invoke(main, ["apply", str(cal), str(rec), "--out", str(rec)])
    assert result.exit_code == 2 and "is an input of this command" in result.output
    assert rec.read_text() == before
    result = CliRunner().invoke(main, ["apply", str(cal), str(rec), "--out", str(tmp_path / "no" / "o.csv")])
    assert result.exit_code == 2 and "directory" in result.output and "does not exist" in result.output


def test_the_plot_gets_the_permission_bits_of_the_csv_beside_it(
    tmp_path: Path, files: tuple[Path, Path]
) -> None:
    # PNGs were written 0600 (a private temporary file renamed) while the CSVs were 0644
    cal, rec = files
    out, png = tmp_path / "out.csv", tmp_path / "out.png"
    old = os.umask(0o022)
    try:
        result = CliRunner().invoke(
            main, ["apply", str(cal), str(rec), "--out", str(out), "--plot", str(png)]
        )
    finally:
        os.umask(old)
    assert result.exit_code == 0, result.output
    assert stat.S_IMODE(out.stat().st_mode) == 0o644
    assert stat.S_IMODE(png.stat().st_mode) == 0o644
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary file left
