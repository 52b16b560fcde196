"""Calibration and discrepancy on real measurements (tests/data/real, third-party TAMS logs)."""

from __future__ import annotations

import json
import math
from functools import cache
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from gateway.analysis.calibration import Calibration, calibrate, calibration_toml
from gateway.analysis.discrepancy import run_discrepancy
from gateway.analysis.measurement import noise_model, read_out_from_metadata, time_is_real
from gateway.analysis.records import read_record
from gateway.cli import main
from gateway.model.params import PARAMETER_RANGES

REAL = Path(__file__).resolve().parents[3] / "data" / "real"
NOSIL, THINSIL, THICK = (
    REAL / "tams_10k-nosil-cylindertip.csv",
    REAL / "tams_10k-thinsil-cylindertip.csv",
    REAL / "tams_thick.csv",
)


@cache
def cal(path: Path) -> Calibration:
    record = read_record(path, require_force=True)
    return calibrate(record.channel(), record_name=path.name, metadata=record.metadata)


def test_real_headers_give_the_read_out_and_no_real_time() -> None:
    for path, ref in ((NOSIL, 10e3), (THICK, 1e3)):
        meta = read_record(path).metadata
        ro = read_out_from_metadata(meta)
        assert ro is not None and ro.kind == "reciprocal"
        assert ro.reference_ohm == ref and ro.full_scale_counts == 1024
        assert not time_is_real(meta)
    # one count at R = 1.02 Mohm on the 10 kohm board moves R by about 10 %
    ro = read_out_from_metadata(read_record(NOSIL).metadata)
    assert ro is not None
    assert abs(float(ro.log_r_per_count(np.array([1.02e6]))[0]) - 0.0996) < 0.001
    assert time_is_real({"time": "s since start"}) and not time_is_real({"time": "none"})


def test_without_metadata_the_noise_model_is_estimated_and_says_so() -> None:
    rng = np.random.default_rng(3)
    f = np.repeat(np.linspace(0.2, 5.0, 40), 10)
    r = 1e5 / f * np.exp(0.02 * rng.standard_normal(f.size))
    nm = noise_model({}, f, r)
    assert nm.estimated and "estimated from the record" in nm.describe()
    assert 0.015 < nm.rel_noise < 0.025  # the 2 % put in
    assert np.allclose(nm.sigma_log, nm.rel_noise)


def test_every_real_calibration_reports_model_and_line_on_the_same_held_out_rows() -> None:
    for path in (NOSIL, THINSIL, THICK):
        c = cal(path)
        rms = c.force_rms()
        assert all(math.isfinite(v) for v in rms.values()), rms
        assert c.fit.n_test > 40
        d = c.as_dict()
        assert d["held_out_force_rms_n"]["line"] == c.rivals.line_force_rms_n
        assert d["verdict"] and d["best"] in ("physics", "line", "lookup")
        assert not d["noise"]["estimated"] and 0 < d["noise"]["floor_log_resistance"] < 0.3
        for e in c.fit.estimates:  # intervals never cross the parameter's own bounds
            allowed = PARAMETER_RANGES[e.name]
            assert allowed.low <= e.low <= e.value <= e.high, e


def test_measured_numbers_on_the_real_files() -> None:
    nosil, thinsil, thick = cal(NOSIL), cal(THINSIL), cal(THICK)
    # nosil: the model (with hysteresis, which makes the force error smaller) beats the line
    assert "hysteresis" in nosil.fit.effects
    assert nosil.fit_before is not None
    assert nosil.fit.gap_test.force_rms_n < nosil.fit_before.gap_test.force_rms_n
    assert nosil.fit.gap_test.force_rms_n < nosil.rivals.line_force_rms_n
    assert nosil.fit.gap_test.force_rms_n < 0.05 * 4.461  # within 5 % of full scale
    # thick: the 26 N record no longer reads 10 N at most; the model beats the line
    assert thick.force_range_n[1] > 25.0
    assert thick.fit.gap_test.force_rms_n < 0.8 * thick.rivals.line_force_rms_n
    assert any("above the configured force_max_n = 10 N" in w for w in thick.warnings)
    assert thick.rows_outside_configured > 10
    # thinsil: the line wins, and the report says so plainly
    assert thinsil.best == "line"
    assert thinsil.verdict.startswith("THE LINE WINS")


def test_auto_writes_the_line_where_the_physics_loses_and_the_force_range() -> None:
    text = calibration_toml([cal(THINSIL)], model="auto", names={"0": "tip"})
    assert '[channel."tip"]' in text and '[channel."0"]' not in text
    assert '[line."tip"]' in text and "slope_s_per_n = " in text
    assert "force_max_n = 3.24" in text
    lookup = calibration_toml([cal(THICK)], model="lookup", names={"0": "pad"})
    assert '[lookup."pad"]' in lookup and "force_max_n = 25.9" in lookup


def test_cli_refuses_channel_0_without_as_and_writes_with_it(tmp_path: Path) -> None:
    out = tmp_path / "cal.toml"
    result = CliRunner().invoke(main, ["calibrate", str(THICK), "--out", str(out)])
    assert result.exit_code == 2 and "--as NAME" in result.output
    result = CliRunner().invoke(
        main, ["calibrate", str(THICK), "--out", str(out), "--as", "pad3", "--json", "--plots", str(tmp_path)]
    )
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    (one,) = payload["calibrations"]
    assert one["force_range_n"][1] > 25.0 and one["rows_outside_configured_range"] > 10
    assert '[channel."pad3"]' in out.read_text()
    assert (tmp_path / "calibration_0.png").stat().st_size > 10_000


def test_discrepancy_on_a_real_file_has_no_time_candidates_and_the_line_beside_it() -> None:
    record = read_record(NOSIL, require_force=True)
    report = run_discrepancy(
        record.channel(), baseline=("tunneling", "contact"), record_name="nosil", metadata=record.metadata
    )
    assert "creep" not in report.candidates and "creep2" not in report.candidates
    assert any("no real time" in n for n in report.notes)
    j = report.as_json()
    assert j["rivals"]["line_force_rms_n"] > 0 and "conductance line" in j["rivals"]["verdict"]
    assert 0 < j["noise"]["floor_log_resistance"] < 0.3
    # nothing that makes the held-out force worse is added
    before = report.steps[0].fit_before.gap_test.force_rms_n
    assert report.final_fit.gap_test.force_rms_n <= before * 1.02 + 1e-3
    print(f"\nnosil discrepancy: added {report.added}; {report.rival_summary()}")
