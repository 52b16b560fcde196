"""Measurement records: spec-conformant CSV, offline and live (interrupted) recordings."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from sim_device import ArrayConfig, Recorder, Scenario, SimArray, record_offline
from sim_device.record import COLUMNS, array_metadata


def read_record(path: Path) -> tuple[dict[str, str], list[dict[str, str]]]:
    """A strict reader of the spec: metadata lines, one header, exact names, valid values."""
    lines = path.read_text(encoding="utf-8").splitlines()
    meta: dict[str, str] = {}
    k = 0
    while lines[k].startswith("#"):
        key, sep, value = lines[k][1:].strip().partition(": ")
        assert sep and key, f"metadata line {k + 1} is not '# key: value': {lines[k]!r}"
        meta[key] = value
        k += 1
    rows = list(csv.DictReader(lines[k:]))
    assert set(rows[0]) >= {"time_s", "resistance_ohm", "force_n", "channel", "temperature_c"}
    last: dict[str, float] = {}
    for i, row in enumerate(rows):
        t = float(row["time_s"])
        r = float(row["resistance_ohm"])
        assert math.isfinite(t) and (r > 0 or math.isinf(r)), f"row {i}: {row}"
        assert math.isfinite(float(row["force_n"])) and math.isfinite(float(row["temperature_c"]))
        assert t >= last.get(row["channel"], -1.0), f"time goes backwards at row {i}"
        last[row["channel"]] = t
    return meta, rows


def test_record_offline_writes_spec_csv(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    cfg = ArrayConfig(channels=4, columns=2, scenario="holds", world_effects=("creep2",))
    rec = record_offline(cfg, "holds", 30.0, path, record_period_s=0.5)
    meta, rows = read_record(path)
    assert meta["source"] == "sim_device" and meta["scenario"] == "holds"
    assert meta["world_effects"] == "tunneling,contact,creep,creep2"
    assert len(rows) == rec.n_rows == 4 * 61
    assert [r["channel"] for r in rows[:4]] == ["0", "1", "2", "3"]
    forces = np.array([float(r["force_n"]) for r in rows]).reshape(61, 4)
    times = np.array([float(r["time_s"]) for r in rows]).reshape(61, 4)
    np.testing.assert_allclose(times[:, 0], np.arange(61) * 0.5, atol=1e-9)
    np.testing.assert_allclose(forces[times[:, 0] >= 10.0], 0.5)
    assert path.read_text().splitlines()[len(meta)] == ",".join(COLUMNS)
    assert not list(tmp_path.glob(".*.tmp")), "no temporary file is left behind"


def test_record_offline_is_deterministic_and_noisy_around_the_truth() -> None:
    layout = ArrayConfig(channels=2, columns=2).layout
    cfg = ArrayConfig(channels=2, columns=2, scenario=Scenario.constant(2.0, layout))
    a = record_offline(cfg, duration_s=5.0)
    b = record_offline(cfg, duration_s=5.0)
    np.testing.assert_array_equal(a.resistance_ohm, b.resistance_ohm)
    c = record_offline(cfg.with_changes(seed=2), duration_s=5.0)
    assert not np.array_equal(a.resistance_ohm, c.resistance_ohm)
    assert np.ptp(a.resistance_ohm[::2]) > 0, "ADC noise shows"


def test_record_offline_scenario_argument_and_shorted_rows(tmp_path: Path) -> None:
    text = (
        "[[load]]\nsteps = [{ hold_s = 2, force_n = 1.0 }]\n"
        "[[fault]]\nat_s = 1\nchannel = 0\nchannel_mode = 'short'\n"
    )
    cfg = ArrayConfig(channels=2, columns=2)
    scenario = Scenario.from_toml(text, cfg.layout)
    rec = record_offline(cfg, duration_s=2.0, scenario=scenario, path=tmp_path / "r.csv")
    assert rec.omitted_short_rows == 11  # channel 0 from 1.0 s to 2.0 s at 0.1 s
    meta, rows = read_record(tmp_path / "r.csv")
    assert meta["omitted_short_rows"] == "11"
    assert sum(r["channel"] == "0" for r in rows) == 10


def test_live_recorder_leaves_a_valid_file_when_interrupted(tmp_path: Path) -> None:
    now = [0.0]
    array = SimArray(ArrayConfig(scenario="sine", speed=1.0), clock=lambda: now[0])
    path = tmp_path / "live.csv"
    recorder = Recorder(path, 0.05, array_metadata(array, 0.05))
    recorder.attach(array)
    for step in range(1, 40):
        now[0] = step * 0.031
        array.advance()
    # no close(): the process could have been killed here
    meta, rows = read_record(path)
    assert meta["record_period_s"] == "0.05"
    times = sorted({float(r["time_s"]) for r in rows})
    assert len(times) == recorder.rows_written // 16
    assert np.all(np.diff(times) >= 0.05 - 1e-9) and times[-1] > 1.1
    recorder.close()
    array.advance(5.0)
    assert read_record(path)[1] == rows, "nothing is written after close"


def test_record_offline_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="record_period_s"):
        record_offline(ArrayConfig(), duration_s=1.0, record_period_s=0.0)
    with pytest.raises(ValueError, match="duration_s"):
        record_offline(ArrayConfig(), duration_s=float("nan"))
