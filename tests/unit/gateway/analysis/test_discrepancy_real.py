"""Discrepancy on the real TAMS records (tests/data/real): hysteresis is named where the data
has it and it reads the held-out force better, and not where it reads the force worse.

The nosil cell's branches differ by a factor of about 2 at 0.15-0.4 N (median log residual
+0.42 loading, -0.38 unloading) and hardly above 1 N. The model's hysteresis is a strain offset
at every force, so it catches little of that in log-R (held-out RMS 0.4476 -> 0.4439, penalized
score gain 2.6, below the 30 of a clear win) and its parameters stay at the prior; it lowers the
held-out force RMS 0.187 -> 0.179 N (4.3 %; 4.5 % with the state the reference force drives),
which the force route of ``discrepancy_choice`` accepts because the diagnostics found the load
direction disagreement it answers.

On every file, from the default and the paper's baselines, no step reads the tracked held-out
force worse, and an unexplained residual remains: the final held-out log-R RMS is 2.9-5.5 x the
noise floor the measurement model predicts (nosil, thinsil, thick), and on thinsil and thick
the line or the lookup reads held-out force better than the model.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.analysis.discrepancy import run_discrepancy
from gateway.analysis.discrepancy_choice import TRACKED_FORCE_SLACK
from gateway.analysis.records import read_record

REAL = Path(__file__).resolve().parents[3] / "data" / "real"
NOSIL = REAL / "tams_10k-nosil-cylindertip.csv"
THINSIL = REAL / "tams_10k-thinsil-cylindertip.csv"
THICK = REAL / "tams_thick.csv"


def test_nosil_names_hysteresis_and_the_held_out_force_gets_smaller() -> None:
    record = read_record(NOSIL, require_force=True)
    report = run_discrepancy(
        record.channel(), baseline=("tunneling", "contact"), record_name="nosil", metadata=record.metadata
    )
    j = report.as_json()
    print(
        f"\nnosil: added {report.added}; held-out log-R RMS {j['gap_before']['log_resistance_rms']} -> "
        f"{j['gap_after']['log_resistance_rms']}, force RMS {j['gap_before']['force_rms_n']} -> "
        f"{j['gap_after']['force_rms_n']} N; noise floor log-R {report.noise_floor_log:.4f}; "
        f"{report.rival_summary()}\n{report.steps[0].evidence}"
    )
    assert report.added == ["hysteresis"]
    assert any(f.axis == "direction" for f in report.steps[0].findings)
    before, after = j["gap_before"]["force_rms_n"], j["gap_after"]["force_rms_n"]
    assert after < 0.97 * before
    assert j["gap_after"]["log_resistance_rms"] < j["gap_before"]["log_resistance_rms"]
    evidence = report.steps[0].evidence
    assert "added on the force" in evidence and "while loading" in evidence
    # the record does not determine the size of the hysteresis; the evidence says so
    assert "kept at the prior" in evidence
    assert 0 < report.noise_floor_log < 0.3


def test_thinsil_hysteresis_lowers_log_r_but_reads_the_force_worse_and_is_not_added() -> None:
    record = read_record(THINSIL, require_force=True)
    report = run_discrepancy(
        record.channel(), baseline=("tunneling", "contact"), record_name="thinsil", metadata=record.metadata
    )
    step = report.steps[0]
    hysteresis = next(c for c in step.candidates if c.effect == "hysteresis")
    before = step.fit_before.gap_test
    print(
        f"\nthinsil: added {report.added}; hysteresis log-R {before.log_resistance_rms:.4f} -> "
        f"{hysteresis.gap_test.log_resistance_rms:.4f}, force {before.force_rms_n:.4g} -> "
        f"{hysteresis.gap_test.force_rms_n:.4g} N"
    )
    assert hysteresis.gap_test.log_resistance_rms < 0.9 * before.log_resistance_rms
    assert hysteresis.gap_test.force_rms_n > 1.2 * before.force_rms_n
    assert "hysteresis" not in report.added
    assert "hysteresis refused: tracked held-out force 0.1669 -> 0.233 N" in step.evidence


@pytest.mark.parametrize("path", [NOSIL, THINSIL, THICK], ids=lambda p: p.stem)
@pytest.mark.parametrize("baseline", [("tunneling",), ("tunneling", "contact")], ids=",".join)
def test_no_step_reads_the_tracked_force_worse_and_an_unexplained_residual_remains(
    path: Path, baseline: tuple[str, ...]
) -> None:
    record = read_record(path, require_force=True)
    report = run_discrepancy(
        record.channel(), baseline=baseline, record_name=path.stem, metadata=record.metadata
    )
    j = report.as_json()
    for step in j["steps"]:
        before, after = step["tracked_force_rms_n"]["before"], step["tracked_force_rms_n"]["after"]
        assert after <= before * (1.0 + TRACKED_FORCE_SLACK), step
    for refused in j["refused"]:
        assert refused["tracked_force_rms_n"]["after"] > refused["tracked_force_rms_n"]["before"]
    u = j["unexplained_residual"]
    print(f"\n{path.stem} from {', '.join(baseline)}: added {j['added']}; {u['sentence']}")
    assert u["remains"] is True
    assert u["floor_ratio"] > 2.0
    # sample-index time: no time-in-hold or rate axis, said so; no runs line in these files
    skipped = " / ".join(u["structure"]["skipped"])
    assert "no real time" in skipped and "no '# runs:' line" in skipped
    finite = [a for a in u["alternatives"] if a["force_rms_n"] is not None]
    assert u["best_alternative"] == min(finite, key=lambda a: a["force_rms_n"])
    assert u["best_alternative"]["force_rms_n"] <= u["best_static_rival"]["force_rms_n"]


def test_the_verdict_names_the_best_static_rival_not_the_line_alone() -> None:
    """Issue 31 item 5: on the thick cell the physical model (tunneling) reads held-out force
    better than the line but worse than the lookup; the verdict once said "the physical model
    wins" against the line with the better lookup in the same sentence."""
    record = read_record(THICK, require_force=True)
    report = run_discrepancy(
        record.channel(), baseline=("tunneling",), record_name="thick", metadata=record.metadata
    )
    statics = dict(report.static_rivals)
    model = report.final_fit.gap_test.force_rms_n
    best = min(statics, key=lambda n: statics[n])
    print(f"\nthick: {report.rival_summary()}")
    assert statics["conductance line"] > model > statics["monotone lookup"] >= statics[best]
    summary = report.rival_summary()
    assert f"THE {best.upper()} WINS: the physical model reads force worse ({model:.4g} N)" in summary
    assert "the physical model wins" not in summary
    assert report.as_json()["rivals"]["verdict"] == summary
