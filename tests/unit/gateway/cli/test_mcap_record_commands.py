"""``apply``, ``view``, ``calibrate`` and ``discrepancy`` read an MCAP record as they read the
CSV record of the same data (issue 34 §6), and ``subscribe --out x.mcap`` writes MCAP. The
real records of tests/data are converted to MCAP in the test."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.mcap_records import MCAP_MAGIC, McapRecordWriter
from gateway.analysis.records import Record, format_record, read_record
from gateway.atomic import AtomicFile
from gateway.cli import main
from gateway.cli.subscribe_cmd import _Recorder
from gateway.cli.view_cmd import load_playback
from gateway.mqtt.frame_stream import Frame

REPO = Path(__file__).resolve().parents[4]
REAL = REPO / "tests" / "data" / "real"
EXAMPLE = REPO / "examples" / "gateway.toml"


def to_mcap(record: Record, path: Path) -> None:
    """``record`` written as MCAP, its rows in their CSV order."""
    rows = sorted(
        (int(ch.line[i]), name, i) for name, ch in record.channels.items() for i in range(ch.n_samples)
    )
    first = next(iter(record.channels.values()))
    with AtomicFile(path) as out:
        writer = McapRecordWriter(
            out,
            record.metadata,
            has_force=first.force_n is not None,
            has_temperature=first.temperature_c is not None,
        )
        for _, name, i in rows:
            ch = record.channels[name]
            writer.row(
                float(ch.time_s[i]),
                name,
                float(ch.resistance_ohm[i]),
                None if ch.force_n is None else float(ch.force_n[i]),
                None if ch.temperature_c is None else float(ch.temperature_c[i]),
            )
        writer.close()
        out.commit()


@pytest.fixture
def pair(tmp_path: Path) -> tuple[Path, Path]:
    """tams_thick.csv and its MCAP form, side by side under the same stem."""
    csv_path = tmp_path / "csv" / "thick.rec"
    mcap_path = tmp_path / "mcap" / "thick.rec"  # no .mcap: found by its magic bytes
    csv_path.parent.mkdir()
    mcap_path.parent.mkdir()
    csv_path.write_bytes((REAL / "tams_thick.csv").read_bytes())
    to_mcap(read_record(csv_path), mcap_path)
    assert mcap_path.read_bytes().startswith(MCAP_MAGIC)
    return csv_path, mcap_path


def _run(args: list[str], cwd: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    monkeypatch.chdir(cwd)
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    return result.output


def test_calibrate_an_mcap_record_as_its_csv(
    pair: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    outputs = []
    for path in pair:
        text = _run(["calibrate", path.name, "--as", "ch00", "--out", "cal.toml"], path.parent, monkeypatch)
        outputs.append((text, (path.parent / "cal.toml").read_text()))
    assert outputs[0] == outputs[1]
    assert '[channel."ch00"]' in outputs[0][1] and "r0_ohm = " in outputs[0][1]


def test_discrepancy_of_an_mcap_record_as_of_its_csv(
    pair: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    reports = [json.loads(_run(["discrepancy", p.name, "--json"], p.parent, monkeypatch)) for p in pair]
    assert reports[0] == reports[1]
    assert reports[0]["final"], "the workflow names a model"


def test_apply_to_an_mcap_record_as_to_its_csv(
    pair: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    results = []
    for path in pair:
        _run(["calibrate", path.name, "--as", "ch00", "--out", "cal.toml"], path.parent, monkeypatch)
        out = _run(
            ["apply", "cal.toml", path.name, "--as", "0=ch00", "--out", "applied.csv", "--json"],
            path.parent,
            monkeypatch,
        )
        results.append((json.loads(out), (path.parent / "applied.csv").read_text()))
    assert results[0] == results[1]
    assert results[0][0]["rows"] == 193 and results[0][0]["in_sample"] is True


def test_view_plays_an_mcap_record_as_its_csv(tmp_path: Path) -> None:
    times = [0.0, 0.1, 0.2, 0.35]
    names = ["tip", "ch05", "ch06"]
    rs = [[20_000.0 + 1000.0 * i, math.inf, 5_000.0 * (k + 1)] for k, i in enumerate(range(len(times)))]
    csv_path = tmp_path / "rec.csv"
    csv_path.write_text(format_record({"config": str(EXAMPLE)}, names, times, rs), encoding="utf-8")
    mcap_path = tmp_path / "rec.mcap"
    to_mcap(read_record(csv_path), mcap_path)
    pb_csv, pb_mcap = load_playback(csv_path, None, None), load_playback(mcap_path, None, None)
    assert pb_mcap.layout == pb_csv.layout and pb_mcap.layout["name"] == "array1"
    assert pb_mcap.frames == pb_csv.frames and len(pb_mcap.frames) == 4
    assert (pb_mcap.start_s, pb_mcap.end_s) == (0.0, 0.35)


def _frame(seq: int, t: float, values: list[float | None], statuses: list[str]) -> Frame:
    fields = {
        "sequence": seq,
        "device_time_s": t,
        "host_time_s": 1000.0 + t,
        "up": True,
        "channels": ["ch00", "ch01", "ch02"],
        "status": statuses,
        "resistance_ohm": values,
    }
    return Frame("gw1", "hand", fields)


def test_subscribe_out_mcap_records_the_frames_as_csv_does(tmp_path: Path) -> None:
    frames = [
        _frame(1, 10.0, [1000.0, None, 3000.0], ["ok", "open", "ok"]),
        _frame(2, 10.033, [1100.0, 2000.0, 3100.0], ["ok", "no_contact", "short"]),
        _frame(3, 10.066, [1200.0, 2100.0, 3200.0], ["ok", "ok", "ok"]),
    ]
    paths = [tmp_path / "sub.csv", tmp_path / "sub.mcap"]
    for path in paths:
        recorder = _Recorder(path, True, True, {"source": "tactile-gateway subscribe"})
        for frame in frames:
            recorder.add(frame)
        recorder.close(keep=True)
    csv_rec, mcap_rec = (read_record(p) for p in paths)
    assert paths[1].read_bytes().startswith(MCAP_MAGIC)
    assert (
        list(mcap_rec.channels)
        == list(csv_rec.channels)
        == ["gw1/hand/ch00", "gw1/hand/ch01", "gw1/hand/ch02"]
    )
    for name, ch in csv_rec.channels.items():
        other = mcap_rec.channels[name]
        assert other.time_s.tolist() == ch.time_s.tolist()
        assert other.resistance_ohm.tolist() == ch.resistance_ohm.tolist()
    # hand-checked: ch01 open (inf) then 2000 ohm; ch02's short in frame 2 has no row
    assert mcap_rec.channels["gw1/hand/ch01"].resistance_ohm.tolist() == [math.inf, 2000.0, 2100.0]
    np.testing.assert_allclose(mcap_rec.channels["gw1/hand/ch02"].time_s, [0.0, 0.066], atol=1e-9)
