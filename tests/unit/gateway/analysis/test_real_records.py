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
from gateway.analysis.objectives import OFFSET
from gateway.analysis.records import read_record
from gateway.cli import main
from gateway.model.params import PARAMETER_RANGES, Interval

OFFSET_RANGE = Interval(-3.0, 3.0)  # the zero offset's bounds are within +-10 % of full scale (26 N)
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
        assert d["verdict"] and d["best"] == next(row["name"] for row in d["ranking"] if row["writable"])
        # what auto writes never reads held-out force worse than the lookup, nor worse than a line
        # whose holds drift no more than the lookup's
        assert rms[c.best] <= rms["lookup"]
        line = c.score("line")
        assert line is not None and (rms[c.best] <= rms["line"] or c.drifts_more(line))
        assert not d["noise"]["estimated"] and 0 < d["noise"]["floor_log_resistance"] < 0.3
        for e in c.fit.estimates:  # intervals never cross the parameter's own bounds
            allowed = PARAMETER_RANGES.get(e.name, OFFSET_RANGE)
            assert allowed.low <= e.low <= e.value <= e.high <= allowed.high, e
        # both objectives were fitted; the one written reads held-out force best
        assert c.other is not None and {c.fit.objective, c.other.objective} == {"log_r", "force"}
        assert c.fit.gap_test.force_rms_n <= c.other.gap_test.force_rms_n
        assert d["objective"]["used"] == c.fit.objective and set(d["objective"]["held_out_force_rms_n"]) == {
            "log_r",
            "force",
        }
        assert d["force_offset"]["mode"] == "auto" and d["force_offset"]["value_n"] == c.fit.force_offset_n


def rms_of(c: Calibration, name: str) -> float:
    return c.force_rms()[name]


def test_measured_numbers_on_the_real_files() -> None:
    nosil, thinsil, thick = cal(NOSIL), cal(THINSIL), cal(THICK)
    for c, full_scale in ((nosil, 4.461), (thinsil, 3.24), (thick, 25.94)):
        # the model reads held-out force at least as well as the line, and within 5 % of full scale
        assert c.fit.gap_test.force_rms_n <= c.rivals.line_force_rms_n, c.record
        assert c.fit.gap_test.force_rms_n < 0.05 * full_scale, c.record
        assert not c.verdict.startswith("THE LINE WINS")
        # what auto writes reads held-out force at least as well as the lookup
        rms = c.force_rms()
        assert rms[c.best] <= rms["lookup"], c.record
    # thinsil: a conductance line with hysteresis on top reads held-out force best (0.1313 N against
    # the physical model's 0.1438 N read as the gateway reads it, and the lookup's 0.1375 N), but
    # its holds right after a higher load drift more than the lookup's (0.47 against 0.34 % FS), so
    # the lookup is written; the verdict says why the better line is not
    ranked = thinsil.score("line + hysteresis")
    assert ranked is not None and ranked.held_out_force_rms_n < 0.99 * rms_of(thinsil, "lookup")
    assert thinsil.drifts_more(ranked) and thinsil.best == "lookup"
    assert "not written: its held-out holds drift more than the lookup's" in thinsil.verdict
    # nosil: the physical model's and the static power law's holds drift more than the lookup's
    # after a higher load (3.17 and 2.41 against 0.88 % FS), so the lookup is written
    assert nosil.best == "lookup"
    physics = nosil.score("physics")
    assert physics is not None and "physics" not in {s.name for s in nosil.writable()}
    assert physics.drift.after_higher_pct_fs > nosil.static_drift_reference()[0] + 0.5
    # nosil: the log-R fit with hysteresis (which makes the force error smaller) is kept
    assert nosil.fit.objective == "log_r" and "hysteresis" in nosil.fit.effects
    assert nosil.fit_before is not None
    assert nosil.fit.gap_test.force_rms_n < nosil.fit_before.gap_test.force_rms_n
    # thinsil: the force objective is what makes the model tie with the line (0.135 N against 0.1356 N);
    # the log-R objective loses (0.164 N)
    assert thinsil.fit.objective == "force" and thinsil.other is not None
    assert thinsil.other.gap_test.force_rms_n > 1.1 * thinsil.rivals.line_force_rms_n
    # thick: the 26 N record no longer reads 10 N at most; the model beats the line by far
    assert thick.fit.objective == "force"
    # (1.2336 N against 1.8398 N: the line read as the gateway reads it, a negative force as no
    # contact at 0 N; read raw, with its negative forces, it scored 2.081 N before)
    assert thick.fit.gap_test.force_rms_n < 0.7 * thick.rivals.line_force_rms_n
    assert any("above the configured force_max_n = 10 N" in w for w in thick.warnings)
    assert thick.rows_outside_configured > 10
    # its fitted zero offset is the one the file's header describes (an unloaded cell reads ~0.49 N):
    # at its bound, where the smallest loaded reference force (0.486 N) is driven at about 0 N
    off = thick.fit.estimate(OFFSET)
    assert -0.49 < off.value < -0.40 and off.low <= off.value < off.low + 1e-6 and "lower bound" in off.note
    assert thick.force_range_n[1] == thick.record_range_n[1] + off.value and thick.force_range_n[1] > 25.0


def test_auto_writes_the_best_calibration_and_the_offset_corrected_force_range() -> None:
    thinsil, thick = cal(THINSIL), cal(THICK)
    text = calibration_toml([thick], model="auto", names={"0": "tip"})
    assert '[channel."tip"]' in text and '[channel."0"]' not in text
    # the winner is a curve: its [curve] table is written beside the physical model's parameters
    assert thick.best == "lookup + hysteresis"
    assert f"# model: {thick.best}" in text and '[curve."tip"]' in text
    assert "[line." not in text and "[lookup." not in text
    # thinsil's winner is the lookup: its [lookup] table, no curve
    text = calibration_toml([thinsil], model="auto", names={"0": "tip"})
    assert "# model: lookup" in text and '[lookup."tip"]' in text and "[curve." not in text
    assert "# parameters fitted with the force objective" in text
    text = calibration_toml([thinsil], model="physics", names={"0": "tip"})
    # the calibrated range is the record's + the fitted zero offset, and the meta says so; the
    # physical model's own range reaches from light touch to 3 x the top (extrapolated between)
    fit_low, fit_high = thinsil.force_range_n
    assert abs(fit_high - (3.2404 + thinsil.fit.force_offset_n)) < 1e-3 and thinsil.fit.force_offset_n < 0
    # ... widened by the reading noise at each end (3 sigma; never below half the low end)
    below, above = thinsil.range_margin_n
    low, high = thinsil.calibrated_range_n()
    assert min(below, above) >= 0.0
    assert (low, high) == (max(fit_low - below, fit_low / 2), fit_high + above)
    assert f"calibrated_max_n = {high!r}" in text and f"calibrated_min_n = {low!r}" in text
    assert f"force_max_n = {3 * high!r}" in text and f"force_min_n = {min(low / 10, 0.01)!r}" in text
    assert "# reference zero offset fitted: " in text and "record's range + offset" in text
    # a rival reads F_ref, so its channel keeps the record's own range
    line = calibration_toml([thinsil], model="line", names={"0": "tip"})
    assert '[line."tip"]' in line and "slope_s_per_n = " in line and "force_max_n = 3.24" in line
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
    assert one["objective"]["used"] == "force" and one["force_offset"]["fitted"]
    assert '[channel."pad3"]' in out.read_text()
    assert (tmp_path / "calibration_0.png").stat().st_size > 10_000
    # the options reach calibrate, and --out replaces the earlier calibration file (it has a [meta] table)
    args = ["--out", str(out), "--as", "pad3", "--objective", "log-r", "--force-offset", "none"]
    result = CliRunner().invoke(main, ["calibrate", str(THICK), *args])
    assert result.exit_code == 0, result.output
    assert "fit objective: log-R (requested: log_r; zero offset: none)" in result.output
    assert "# parameters fitted with the log-R objective" in out.read_text()
    assert "reference zero offset" not in out.read_text()
    result = CliRunner().invoke(main, ["calibrate", str(THICK), "--objective", "newtons"])
    assert result.exit_code == 2 and "--objective" in result.output


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
