"""``calibrate`` over a folder or a glob of records: one calibration per record, byte-identical to
the single-record command's, a summary (CSV and JSON) that names a broken record, and exit codes."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from gateway.cli import main

REAL = Path(__file__).resolve().parents[3] / "data" / "real"
NAMES = ("tams_10k-nosil-cylindertip", "tams_10k-thinsil-cylindertip", "tams_thick")
FAST = ["--model", "line", "--objective", "log-r", "--force-offset", "none", "--jobs", "1", "--as", "pad"]


@pytest.fixture(scope="module")
def batch(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, bytes], object]:
    root = tmp_path_factory.mktemp("batch")
    records = root / "records"
    records.mkdir()
    for name in NAMES:
        shutil.copyfile(REAL / f"{name}.csv", records / f"{name}.csv")
    (records / "broken.csv").write_text("time_s,resistance_ohm\nnot a number,1\n", encoding="utf-8")
    (records / "README.md").write_text("not a record\n", encoding="utf-8")  # not taken: not .csv/.mcap
    single: dict[str, bytes] = {}
    for name in NAMES:
        out = root / f"single-{name}.toml"
        res = CliRunner().invoke(main, ["calibrate", str(records / f"{name}.csv"), "--out", str(out), *FAST])
        assert res.exit_code == 0, res.output
        single[name] = out.read_bytes()
    out_dir = root / "cals"
    result = CliRunner().invoke(main, ["calibrate", str(records), "--out", str(out_dir), "--json", *FAST])
    return records, out_dir, single, result


def test_a_folder_gives_one_calibration_per_record_identical_to_the_single_command(batch: tuple) -> None:
    _records, out_dir, single, result = batch
    assert result.exit_code == 1, result.output  # one record failed
    for name in NAMES:
        assert (out_dir / f"{name}.toml").read_bytes() == single[name]
    assert not (out_dir / "broken.toml").exists()


def test_the_summary_names_the_broken_record_and_the_others_ok(batch: tuple) -> None:
    records, out_dir, _, result = batch
    printed = json.loads(result.stdout)
    stored = json.loads((out_dir / "summary.json").read_text(encoding="utf-8"))
    assert printed == stored
    assert (stored["records"], stored["ok"], stored["failed"]) == (4, 3, 1)
    by_record = {Path(r["record"]).name: r for r in stored["rows"]}
    assert by_record["broken.csv"]["status"] == "failed"
    # the reader's own message, one line: where, and what is wrong (the record has no force column)
    assert by_record["broken.csv"]["error"] == (
        f"{records / 'broken.csv'}:1: missing required column 'force_n' (found: time_s, resistance_ohm)"
    )
    for name in NAMES:
        row = by_record[f"{name}.csv"]
        assert row["status"] == "ok" and row["error"] == "" and row["channel"] == "pad"
        assert row["written"] == str(out_dir / f"{name}.toml")
        assert row["model"] == row["written_model"] == "line"
        # the figure the calibration file states for the model it wrote
        text = (out_dir / f"{name}.toml").read_text(encoding="utf-8")
        assert f"held_out_force_rms_n = {row['held_out_force_rms_n']!r}" in text
    with (out_dir / "summary.csv").open(encoding="utf-8", newline="") as f:
        table = list(csv.DictReader(f))
    assert sorted((Path(r["record"]).name, r["status"]) for r in table) == sorted(
        [("broken.csv", "failed")] + [(f"{n}.csv", "ok") for n in NAMES]
    )
    assert [r["error"] for r in table if r["status"] == "failed"] == [by_record["broken.csv"]["error"]]


def test_a_glob_takes_only_the_matching_records_and_all_ok_exits_0(batch: tuple, tmp_path: Path) -> None:
    records, _, single, _ = batch
    out_dir = tmp_path / "cals"
    result = CliRunner().invoke(
        main, ["calibrate", str(records / "tams_10k-*.csv"), "--out", str(out_dir), *FAST]
    )
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out_dir.glob("*.toml")) == [
        "tams_10k-nosil-cylindertip.toml",
        "tams_10k-thinsil-cylindertip.toml",
    ]
    assert (out_dir / "tams_10k-nosil-cylindertip.toml").read_bytes() == single["tams_10k-nosil-cylindertip"]
    assert "2 of 2 records calibrated, 0 failed" in result.stdout


def test_a_batch_without_out_or_with_a_file_as_out_is_refused(batch: tuple, tmp_path: Path) -> None:
    records = batch[0]
    result = CliRunner().invoke(main, ["calibrate", str(records), *FAST])
    assert result.exit_code == 2 and "several records need --out DIR" in result.output
    a_file = tmp_path / "cal.toml"
    a_file.write_text("x = 1\n", encoding="utf-8")
    result = CliRunner().invoke(main, ["calibrate", str(records), "--out", str(a_file), *FAST])
    assert result.exit_code == 2 and f"{a_file} is a file" in result.output
    assert a_file.read_text(encoding="utf-8") == "x = 1\n"


def test_a_glob_that_matches_nothing_is_refused(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["calibrate", str(tmp_path / "*.csv"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "no record matches" in result.output


def test_a_record_too_short_to_fit_fails_alone_and_the_next_one_is_written(tmp_path: Path) -> None:
    records = tmp_path / "records"
    records.mkdir()
    # readable, with a force column, but three rows: the fit itself refuses it
    (records / "a_short.csv").write_text(
        "time_s,resistance_ohm,force_n\n0,1000,1\n0.1,900,2\n0.2,800,3\n", encoding="utf-8"
    )
    shutil.copyfile(REAL / "tams_thick.csv", records / "b_thick.csv")
    out_dir = tmp_path / "cals"
    result = CliRunner().invoke(main, ["calibrate", str(records), "--out", str(out_dir), "--json", *FAST])
    assert result.exit_code == 1, result.output
    rows = json.loads(result.stdout)["rows"]
    assert [(Path(r["record"]).name, r["status"]) for r in rows] == [
        ("a_short.csv", "failed"),
        ("b_thick.csv", "ok"),
    ]
    assert "at least four rows" in rows[0]["error"]
    assert sorted(p.name for p in out_dir.iterdir()) == ["b_thick.toml", "summary.csv", "summary.json"]
