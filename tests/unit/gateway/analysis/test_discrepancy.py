"""The discrepancy workflow names the effect hidden in data from the simulated world.

Records come from the simulated array, whose physics is written independently of the gateway:
the paper's tunneling, contact and creep, and ``sim_device.world`` for the
hidden effect, driven by the built-in ``discrepancy`` protocol (log-spaced loads 0.2-8 N,
holds, unload-and-hold, ramps at two rates, cycles, a temperature step), with 1 %
log-normal resistance noise.
"""

from __future__ import annotations

import itertools
import json
import tempfile
from collections import Counter
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from drawn_sensor import drawn_sensor

from gateway.analysis.discrepancy import DiscrepancyReport, run_discrepancy
from gateway.analysis.records import ChannelRecord, read_record
from gateway.cli import main
from sim_device import ArrayConfig, SimSensorParams, record_offline

NOISE = 0.01
PAPER = ("tunneling", "contact", "creep")
SEEDS = (1, 2, 3)
# hidden effect -> (baseline, what the workflow must name)
CASES: dict[str, tuple[tuple[str, ...], frozenset[str]]] = {
    "nothing": (PAPER, frozenset()),
    "paper physics, tunneling baseline": (("tunneling",), frozenset({"contact", "creep"})),
    "creep2": (PAPER, frozenset({"creep2"})),
    "hysteresis": (PAPER, frozenset({"hysteresis"})),
    "temperature": (PAPER, frozenset({"temperature"})),
    "series_resistance": (PAPER, frozenset({"series_resistance"})),
    "leakage": (PAPER, frozenset({"leakage"})),
}


def world_channel(hidden: tuple[str, ...], seed: int, record_period_s: float = 2.0) -> ChannelRecord:
    """One channel of the simulated array under the discrepancy protocol, via a CSV record.

    ``sim_device.record_offline`` simulates the array (the model's paper physics plus the
    world's hidden effect, 1 % sensor resistance noise, 2 LSB ADC noise) and writes the
    spec's record format; the workflow reads it back with the strict reader.
    """
    params = drawn_sensor(seed, series_resistance_ohm=5000.0, leakage_resistance_ohm=1e6)
    config = ArrayConfig(
        channels=1,
        columns=1,
        seed=seed,
        scenario="discrepancy",
        world_effects=hidden,
        param_spread=False,
        channel_params=params,
        sensor_noise_rel=NOISE,
        noise_lsb_rms=2.0,
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "world.csv"
        record_offline(config, path=path, record_period_s=record_period_s)
        return read_record(path, require_force=True).channel("0")


#: An ADC-limited front end: eq. 18's divider with a 470 ohm reference on a 12-bit converter
#: (0.5 LSB rms noise) and 0.2 % sensor noise. One count moves R by 9 % at 0.2 N (10-11 % on the
#: ramps below it), 4 % at 1-2 N, 0.8 % at 3-5 N and 0.3 % at 8 N; an open sensor reads 0 counts
#: (1 count, 1.9 Mohm, on noise) and the 1 Mohm leakage path 2 counts, where one count is
#: 50-100 %. With a 390 ohm reference (11 % at 0.2 N) the 5 kohm series resistance is no longer
#: named: contact and tunneling absorb it once the low-force rows that separate them are coarser
#: (held-out score gain -1.8, force gain 1.8 %); everything else still is.
ADC_LIMITED: dict[str, Any] = {
    "adc_bits": 12, "reference_ohm": 470.0, "noise_lsb_rms": 0.5, "sensor_noise_rel": 0.002,
}  # fmt: skip
ADC_CASES = ("nothing", "creep2", "hysteresis", "temperature", "series_resistance", "leakage")


def adc_limited_record(hidden: tuple[str, ...], seed: int) -> tuple[ChannelRecord, dict[str, str]]:
    """``world_channel``'s sensor and protocol read through ``ADC_LIMITED``, with the front end
    stated in the record's metadata (``front_end``, ``adc_bits``, ``reference_ohm``,
    ``noise_lsb_rms``: what ``gateway.analysis.measurement`` reads)."""
    params = drawn_sensor(seed, series_resistance_ohm=5000.0, leakage_resistance_ohm=1e6)
    config = ArrayConfig(
        channels=1, columns=1, seed=seed, scenario="discrepancy", world_effects=hidden,
        param_spread=False, channel_params=params, **ADC_LIMITED,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "adc-limited.csv"
        record_offline(config, path=path, record_period_s=2.0, metadata={"front_end": "high_side"})
        record = read_record(path, require_force=True)
        return record.channel("0"), record.metadata


def refused_by_the_rule(report: DiscrepancyReport) -> set[str]:
    """The candidates the tracked-force rule refused at some step of ``report``."""
    return {r["effect"] for r in report.as_json()["refused"]}


def verdict_is_right(report: DiscrepancyReport, expected: frozenset[str]) -> bool:
    """Exactly the hidden effects are named, except those the tracked-force rule refused (their
    tracked held-out force got worse): never a false name."""
    got = frozenset(report.added)
    return got <= expected and expected - got <= refused_by_the_rule(report)


def test_confusion_table_under_adc_limited_noise_names_exactly_the_hidden_effect() -> None:
    """The front end of ``ADC_LIMITED``: the noise is non-uniform in log-R (the measurement
    model weights the rows by it) and near the open rail. Every hidden effect is named but
    hysteresis, and nothing on the null record. Hysteresis lowers the held-out log-R (0.0200 ->
    0.0168) but the force read with the tracked state gets worse (0.0336 -> 0.0442 N; with the
    state the reference force drives it improves): near-rail readings jitter the inverted
    force past hysteresis's dead band and flip the tracked load direction. Until the tracked-
    force rule it was named all the same; the runtime reads with the tracked state, so it is
    now refused, with its numbers. A 5 kohm series resistance is named on the force route
    (held-out score gain 8 < 30: the low-force rows that separate it from contact are the coarse
    ones; the held-out force falls 3.2 %)."""
    rows, wrong = [], []
    for case in ADC_CASES:
        hidden = () if case == "nothing" else (case,)
        channel, metadata = adc_limited_record(hidden, 1)
        report = run_discrepancy(channel, baseline=PAPER, record_name=case, metadata=metadata)
        assert "quantization up to" in report.noise_description  # the front end was read
        expected = frozenset(hidden) - {"hysteresis"}
        if report.added != sorted(expected):
            wrong.append((case, report.added, [s.evidence for s in report.steps]))
        refused = sorted(refused_by_the_rule(report) & set(hidden))
        note = f" (refused: {', '.join(refused)})" if refused else ""
        rows.append(f"| {case} | {', '.join(report.added) or '(nothing)'}{note} |")
        if case == "hysteresis":
            assert "hysteresis refused: tracked held-out force" in report.steps[0].evidence
    table = "\n".join(["| hidden | named (seed 1, ADC-limited) |", "|---|---|", *rows])
    print("\n" + table)
    assert not wrong, f"wrong verdicts: {wrong}\n{table}"


@cache
def outcome(case: str, seed: int) -> DiscrepancyReport:
    baseline, _ = CASES[case]
    hidden = () if case in ("nothing", "paper physics, tunneling baseline") else (case,)
    return run_discrepancy(world_channel(hidden, seed), baseline=baseline, record_name=f"{case}-{seed}")


def test_confusion_table_names_exactly_the_hidden_effect() -> None:
    """Exactly the hidden effects are named on seeds 1-3, except that the tracked-force rule may
    refuse one (then the report carries the refusal and its numbers): hysteresis on seed 2
    lowers the held-out log-R (0.0143 -> 0.0122) but reads the tracked force worse (0.0249 ->
    0.0278 N) and is refused. No false name is ever given, and where the hidden effects are
    all named no unexplained residual remains."""
    rows = []
    wrong = []
    missed: set[tuple[str, int, str]] = set()
    for case, (_, expected) in CASES.items():
        named: Counter[str] = Counter()
        for seed in SEEDS:
            report = outcome(case, seed)
            got = frozenset(report.added)
            named.update(report.added or ["(nothing)"])
            named.update(f"{e} refused" for e in expected - got)
            if not verdict_is_right(report, expected):
                wrong.append((case, seed, sorted(got)))
            missed.update((case, seed, e) for e in expected - got)
            if got == expected:
                assert report.unexplained is not None and not report.unexplained.remains, (case, seed)
        rows.append(f"| {case} | {', '.join(f'{k} x{v}' for k, v in sorted(named.items()))} |")
    table = "\n".join(["| hidden | named (over seeds 1-3) |", "|---|---|", *rows])
    print("\n" + table)
    assert not wrong, f"wrong verdicts: {wrong}\n{table}"
    # the one refusal seen: more would mean the rule costs more true names than it did
    assert missed <= {("hysteresis", 2, "hysteresis")}, missed


@pytest.mark.parametrize("case", list(CASES))
def test_every_named_effect_shrinks_the_held_out_gap_down_to_the_noise(case: str) -> None:
    for seed in SEEDS:
        report = outcome(case, seed)
        gaps = [report.steps[0].fit_before.gap_test.log_resistance_rms]
        for step in report.steps:
            if step.added:
                gaps.append(
                    next(c.gap_test.log_resistance_rms for c in step.candidates if c.effect == step.added)
                )
        assert all(b < a for a, b in itertools.pairwise(gaps)), (case, seed, gaps)
        final = report.final_fit.gap_test.log_resistance_rms
        assert final <= 1.5 * NOISE, (case, seed, final)


def test_from_the_tunneling_baseline_the_gap_shrinks_at_least_five_fold() -> None:
    for seed in SEEDS:
        j = outcome("paper physics, tunneling baseline", seed).as_json()
        before, after = j["gap_before"]["log_resistance_rms"], j["gap_after"]["log_resistance_rms"]
        print(
            f"\nseed {seed}: held-out log-R RMS {before} -> {after}, force RMS "
            f"{j['gap_before']['force_rms_n']} -> {j['gap_after']['force_rms_n']} N"
        )
        assert after * 5 <= before
        assert j["gap_after"]["force_rms_n"] < j["gap_before"]["force_rms_n"]


def test_json_object_has_the_spec_keys_and_meanings() -> None:
    report = outcome("paper physics, tunneling baseline", 1)
    j = json.loads(json.dumps(report.as_json()))
    assert {"record", "baseline", "added", "final", "gap_before", "gap_after", "steps"} <= set(j)
    assert j["baseline"] == ["tunneling"]
    assert j["final"] == ["tunneling", "contact", "creep"]
    assert [s["added"] for s in j["steps"]] == j["added"]
    for s in j["steps"]:
        assert set(s["gap"]) == {"log_resistance_rms", "force_rms_n"}
        assert isinstance(s["evidence"], str) and s["evidence"]
    assert j["gap_after"] == j["steps"][-1]["gap"]


def test_no_temperature_column_means_no_temperature_candidate() -> None:
    ch = world_channel((), 4)
    no_temp = ChannelRecord(ch.name, ch.time_s, ch.resistance_ohm, ch.force_n, None, ch.line)
    report = run_discrepancy(no_temp, baseline=PAPER)
    assert "temperature" not in report.candidates
    assert any("no temperature column" in n for n in report.notes)


def test_cli_json_and_report(tmp_path: Path) -> None:
    rec = tmp_path / "world.csv"
    config = ArrayConfig(
        channels=1,
        columns=1,
        seed=5,
        scenario="discrepancy",
        world_effects=("temperature",),
        sensor_noise_rel=NOISE,
    )
    record_offline(config, path=rec, record_period_s=2.0)
    out = tmp_path / "report"
    result = CliRunner().invoke(
        main, ["discrepancy", str(rec), "--baseline", "tunneling,contact,creep", "--out", str(out), "--json"]
    )
    assert result.exit_code == 0, result.output
    j = json.loads(result.stdout)  # nothing but the JSON object on stdout
    assert j["added"] == ["temperature"]
    assert j["record"] == str(rec)
    text = (out / "report.md").read_text()
    assert "Decision: add `temperature`" in text
    assert "°C the measured resistance is" in text
    assert sorted(p.name for p in out.glob("*.png")) == ["step1_residuals.png", "step2_residuals.png"]


def test_cli_refuses_unknown_effects_and_channels(tmp_path: Path) -> None:
    rec = tmp_path / "r.csv"
    rec.write_text("time_s,channel,resistance_ohm,force_n\n0,a,1e5,1\n0,b,1e5,1\n")
    result = CliRunner().invoke(
        main, ["discrepancy", str(rec), "--channel", "a", "--candidates", "hysterisis"]
    )
    assert result.exit_code == 2 and "did you mean 'hysteresis'" in result.output
    result = CliRunner().invoke(main, ["discrepancy", str(rec)])
    assert result.exit_code == 2 and "the record has 2 channels" in result.output


def test_a_few_torn_unloaded_rows_do_not_hide_the_hidden_effect() -> None:
    """A reading taken while the load changed (force block read before the step, resistance
    after: 0 N at 30 kohm) is ln(1e8 / 3e4)^2 = 65 in squared log residual, against about
    1e-4 for a good row. Scattered through the record, a handful of them must not hide the
    temperature effect the record carries."""
    from dataclasses import replace

    channel = world_channel(("temperature",), 1)
    assert channel.force_n is not None
    unloaded = np.flatnonzero(channel.force_n <= 0.0)
    torn = unloaded[:: max(1, unloaded.size // 8)]
    assert torn.size >= 6
    resistance = channel.resistance_ohm.copy()
    resistance[torn] = 3e4
    report = run_discrepancy(replace(channel, resistance_ohm=resistance), baseline=PAPER)
    assert report.added == ["temperature"], [s.evidence for s in report.steps]


def test_a_sensor_open_at_rest_still_gets_its_creep_named() -> None:
    """Issue 16: on a record whose sensor reads open when unloaded (contact open at rest, no
    leakage: 365 of 2352 rows are +inf), the open rows once dominated the score and nothing was
    named, not even with creep as the only candidate."""
    params = SimSensorParams(series_resistance_ohm=0.0, leakage_resistance_ohm=float("inf"))
    config = ArrayConfig(
        channels=1, columns=1, seed=1, scenario="discrepancy", world_effects=(), param_spread=False,
        channel_params=params, sensor_noise_rel=NOISE, noise_lsb_rms=2.0,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "open-at-rest.csv"
        record_offline(config, path=path, record_period_s=2.0)
        channel = read_record(path, require_force=True).channel("0")
    assert np.isinf(channel.resistance_ohm).sum() > 300
    assert run_discrepancy(channel, baseline=("tunneling", "contact")).added == ["creep"]
    alone = run_discrepancy(channel, baseline=("tunneling", "contact"), candidates=("creep",))
    assert alone.added == ["creep"]
    assert alone.final_fit.gap_test.log_resistance_rms <= 1.5 * NOISE
