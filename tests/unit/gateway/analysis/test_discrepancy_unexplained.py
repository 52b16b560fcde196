"""A discrepancy workflow that never makes a reading worse, and says "unexplained residual".

Records are generated here, not by ``sim_device``: the gateway's own forward model
(``gateway.model.SensorModel``, the paper's ``tunneling, contact, creep``) driven by a load
protocol, with 1 % log-normal resistance noise, plus one effect applied to the resistance:

- catalogued ones, through the model itself (``hysteresis``, ``creep2``, ``series_resistance``,
  ``leakage``): the workflow names them and no residual is left;
- three outside the catalogue, which no catalogued name may claim:
  (a) **wear**: the conductance loses 3 % with each loading cycle (R / (1 - 0.03 n));
  (b) **rate dependence**: R x (1 - g dF/dt), g = 0.3 s/N, on sweeps at 0.1, 0.3 and 1 N/s;
  (c) **humidity-like drift**: R x (1 + 0.15 sin(2 pi t / P + 0.7)), P = 0.6 x the record,
  unrelated to the load.

What can be asserted honestly: an added name always lowers the tracked held-out force (the
rule); an unexplained residual remains; its structure varies most with time or run for wear
and humidity (a measurement run starts every few cycles, ``# runs:``), with the loading
direction or rate for the rate dependence. Hysteresis, a direction-dependent offset, does
read the rate-dependent record's force better (tracked held-out force 0.12 -> 0.10 N on
seeds 1-3) and is added there: it is allowed by the rule, and the residual it leaves is still
four times the noise floor.
"""

from __future__ import annotations

import json
import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.discrepancy import DiscrepancyReport, run_discrepancy
from gateway.analysis.discrepancy_choice import TRACKED_FORCE_SLACK
from gateway.analysis.fitting import FitData
from gateway.analysis.records import ChannelRecord, format_record, parse_record
from gateway.cli import main
from gateway.model import EFFECT_NAMES, SensorModel, SensorParams

PAPER = ("tunneling", "contact", "creep")
CATALOGUE = frozenset(EFFECT_NAMES) - {"tunneling"}
NOISE = 0.01
CYCLES = 8
#: the cycles at which a new measurement run starts (``# runs:``), unevenly
RUN_STARTS = (0, 3, 4, 6)
WEAR_PER_CYCLE = 0.03
RATE_GAIN_S_PER_N = 0.3
HUMIDITY_AMPLITUDE = 0.15

#: out-of-catalogue effect -> the axes its residual may vary most along
OUTSIDE: dict[str, frozenset[str]] = {
    "wear": frozenset({"run", "elapsed"}),
    "rate": frozenset({"direction", "rate"}),
    "humidity": frozenset({"run", "elapsed"}),
}


def loading_cycles(
    cycles: int = CYCLES, dt_s: float = 2.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:
    """Time, force, the loading cycle of each row (0, 1, ...) and the cycles' start times.

    Each cycle: 30 s unloaded, then holds at 0.3, 1, 4, 2, 6 and 0.5 N (30-60 s) joined by
    ramps at 0.05 and 0.5 N/s (slow and fast swap every cycle, so direction and rate are not
    confounded), and back to 0 N."""
    knots: list[tuple[float, float]] = [(0.0, 0.0)]
    starts: list[float] = []

    def go(force: float, duration: float) -> None:
        knots.append((knots[-1][0] + duration, force))

    for k in range(cycles):
        slow, fast = (0.05, 0.5) if k % 2 == 0 else (0.5, 0.05)
        go(0.0, 30.0)
        starts.append(knots[-1][0])
        steps = (
            (0.3, fast, 40),
            (1.0, slow, 40),
            (4.0, fast, 60),
            (2.0, slow, 40),
            (6.0, slow, 30),
            (0.5, fast, 40),
        )
        for level, rate, hold in steps:
            go(level, abs(level - knots[-1][1]) / rate)
            go(level, hold)
        go(0.0, 0.5 / fast)
    go(0.0, 30.0)
    kt, kf = np.array([p[0] for p in knots]), np.array([p[1] for p in knots])
    t = np.arange(0.0, kt[-1], dt_s)
    cycle = np.maximum(np.searchsorted(np.array(starts), t, side="right") - 1, 0).astype(np.float64)
    return t, np.interp(t, kt, kf), cycle, starts


def sweeps(dt_s: float = 0.5, low: float = 0.3, high: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Time and force: sweeps low -> high -> low at 0.1, 0.3 and 1 N/s in every pairing of up
    and down rates, 5 s holds at both ends, twice."""
    rates = ((0.1, 1.0), (1.0, 0.1), (0.3, 0.3), (0.1, 0.3), (1.0, 1.0), (0.3, 0.1))
    knots: list[tuple[float, float]] = [(0.0, low)]
    for _ in range(2):
        for up, down in rates:
            for level, rate in ((high, up), (low, down)):
                t = knots[-1][0] + (high - low) / rate
                knots += [(t, level), (t + 5.0, level)]
    kt, kf = np.array([p[0] for p in knots]), np.array([p[1] for p in knots])
    t = np.arange(0.0, kt[-1], dt_s)
    return t, np.interp(t, kt, kf)


def _sensor(seed: int) -> SensorParams:
    rng = np.random.default_rng(seed)
    return SensorParams(
        r0_ohm=200e3 * rng.uniform(0.85, 1.15),
        e0_pa=15e6 * rng.uniform(0.9, 1.1),
        series_resistance_ohm=5000.0,
        leakage_resistance_ohm=1e6,
        hysteresis_strain=2e-3,
    )


@cache
def generated_record(hidden: str, seed: int) -> tuple[ChannelRecord, dict[str, str]]:
    """One channel of ``SensorModel(PAPER [+ hidden])`` with 1 % noise and, for ``wear``,
    ``rate`` or ``humidity``, that effect applied to the resistance (see the module docstring).
    Read back through the strict record reader, with its metadata."""
    rng = np.random.default_rng(1000 + seed)
    params = _sensor(seed)
    effects = PAPER + ((hidden,) if hidden in CATALOGUE else ())
    metadata = {"sensor": f"generated, hidden effect: {hidden}", "time": "s since the start"}
    temperature = None
    if hidden == "rate":
        t, f = sweeps()
    else:
        t, f, cycle, starts = loading_cycles()
        metadata["runs"] = ", ".join(f"{starts[k] - 30.0:g}" for k in RUN_STARTS)
        # a temperature column that varies by 0.6 K (not a candidate; an axis of the structure)
        temperature = 25.0 + 0.3 * np.sin(2.0 * np.pi * t / 900.0)
    terms, _ = SensorModel(effects, params).simulate(
        f[:, None], t, temperature_c=None if temperature is None else temperature[:, None]
    )
    r = terms.total_ohm[:, 0].copy()
    if hidden == "wear":
        r = r / (1.0 - WEAR_PER_CYCLE * cycle)
    elif hidden == "rate":
        r = r * (1.0 - RATE_GAIN_S_PER_N * np.gradient(f, t))
    elif hidden == "humidity":
        r = r * (1.0 + HUMIDITY_AMPLITUDE * np.sin(2.0 * np.pi * t / (0.6 * t[-1]) + 0.7))
    r = r * np.exp(NOISE * rng.standard_normal(r.size))
    text = format_record(
        metadata, ["0"], t, r[:, None], f[:, None], None if temperature is None else temperature[:, None]
    )
    record = parse_record(text)
    return record.channel("0"), record.metadata


@cache
def outcome(hidden: str, seed: int) -> DiscrepancyReport:
    channel, metadata = generated_record(hidden, seed)
    return run_discrepancy(channel, baseline=PAPER, record_name=f"{hidden}-{seed}", metadata=metadata)


def tracked_violations(report: DiscrepancyReport) -> list[str]:
    """Every step whose tracked held-out force is worse than the step before's, in words."""
    j = json.loads(json.dumps(report.as_json()))
    bad = []
    previous = report.steps[0].tracked_before
    for s in j["steps"]:
        before, after = s["tracked_force_rms_n"]["before"], s["tracked_force_rms_n"]["after"]
        if before != previous or not after <= before * (1.0 + TRACKED_FORCE_SLACK):
            bad.append(f"{s['added']}: {before} -> {after} (previous step ended at {previous})")
        previous = after
    return bad


@pytest.mark.parametrize("hidden", list(OUTSIDE))
def test_an_effect_outside_the_catalogue_gets_unexplained_residual_not_a_false_name(hidden: str) -> None:
    report = outcome(hidden, 1)
    j = report.as_json()
    u = j["unexplained_residual"]
    print(
        f"\n{hidden}: added {j['added']}; {report.unexplained.sentence() if report.unexplained else ''}\n"
        + "\n".join(f"  step {i}: {s.evidence[:300]}" for i, s in enumerate(report.steps, 1))
    )
    # a catalogued name is added only where it reads the tracked held-out force better
    for step in j["steps"]:
        assert step["added"] in CATALOGUE
        assert step["tracked_force_rms_n"]["after"] < step["tracked_force_rms_n"]["before"], step
    assert not tracked_violations(report)
    # the residual is left unexplained, with the numbers that say so
    assert u["remains"] is True
    assert u["floor_ratio"] > 2.0, u["reasons"]
    assert u["noise_floor_log_resistance"] == pytest.approx(NOISE, rel=0.25)
    # ... and its structure points at the right axis
    structure = u["structure"]
    assert structure["most_varying_axis"] in OUTSIDE[hidden], structure["sentence"]
    assert structure["most_varying_axis_force"] in OUTSIDE[hidden], structure["sentence"]
    best = max(structure["axes"], key=lambda a: a["explained_share_log_resistance"])
    assert best["explained_share_log_resistance"] > 0.2
    assert "UNEXPLAINED RESIDUAL REMAINS" in u["sentence"]
    # the best empirical alternative is named: the best of the line, the lookup and calibrate's
    # curves with drift correction, fitted on the same rows
    names = {a["name"] for a in u["alternatives"]}
    assert {"conductance line", "monotone lookup", "power_law + static", "lookup + creep"} <= names
    finite = [a for a in u["alternatives"] if a["force_rms_n"] is not None]
    assert u["best_alternative"] == min(finite, key=lambda a: a["force_rms_n"])


def test_the_wear_record_has_every_axis_and_its_residual_climbs_run_by_run() -> None:
    """Wear: the measured resistance climbs against the model from run to run (3 % of
    conductance lost per cycle); every axis is there (temperature from the record's column, the
    runs from its ``# runs:`` line) and each bin has its mean and RMS."""
    u = outcome("wear", 1).as_json()["unexplained_residual"]
    axes = {a["axis"]: a for a in u["structure"]["axes"]}
    assert set(axes) == {
        "force", "time_in_hold", "load_history", "direction", "rate", "temperature", "run", "elapsed",
    }  # fmt: skip
    assert u["structure"]["skipped"] == []
    runs = axes["run"]["bins"]
    assert [b["label"].split(" (")[0] for b in runs] == ["in run 1", "in run 2", "in run 3", "in run 4"]
    means = [b["log_resistance_mean"] for b in runs]
    assert means == sorted(means), means
    for axis in axes.values():
        for b in axis["bins"]:
            assert b["n_rows"] > 0
            assert b["log_resistance_rms"] >= abs(b["log_resistance_mean"])
            assert b["force_rms_n"] is None or b["force_rms_n"] >= abs(b["force_mean_n"])


def test_a_record_without_runs_or_temperature_skips_those_axes_and_says_why() -> None:
    u = outcome("rate", 1).as_json()["unexplained_residual"]
    assert {a["axis"] for a in u["structure"]["axes"]} == {
        "force",
        "time_in_hold",
        "load_history",
        "direction",
        "rate",
        "elapsed",
    }
    skipped = " / ".join(u["structure"]["skipped"])
    assert "no temperature column" in skipped and "no '# runs:' line" in skipped


CATALOGUED_CASES = (("hysteresis", 1), ("creep2", 2), ("leakage", 2))


@pytest.mark.parametrize(("hidden", "seed"), CATALOGUED_CASES)
def test_catalogued_effects_made_with_the_model_are_still_named_and_nothing_is_left(
    hidden: str, seed: int
) -> None:
    report = outcome(hidden, seed)
    assert report.added == [hidden], [s.evidence for s in report.steps]
    assert report.unexplained is not None and not report.unexplained.remains, report.unexplained.reasons
    assert report.final_fit.gap_test.log_resistance_rms <= 1.5 * NOISE


PROPERTY_CASES = (
    *CATALOGUED_CASES,
    ("series_resistance", 1),
    ("wear", 1),
    ("wear", 2),
    ("rate", 1),
    ("rate", 3),
    ("humidity", 1),
    ("humidity", 2),
)


def test_property_no_step_reads_the_tracked_held_out_force_worse_than_the_step_before() -> None:
    """Over seeded records with catalogued and out-of-catalogue effects: each step starts from
    the previous step's model, and no step's tracked held-out force is worse than the previous
    step's; the final model's is not worse than the baseline's; every refused candidate's
    reason carries the numbers."""
    rows = []
    for hidden, seed in PROPERTY_CASES:
        report = outcome(hidden, seed)
        j = report.as_json()
        assert not tracked_violations(report), (hidden, seed)
        assert report.final_fit.gap_test.force_rms_n <= report.steps[0].tracked_before * (
            1.0 + TRACKED_FORCE_SLACK
        )
        for r in j["refused"]:
            assert r["tracked_force_rms_n"]["after"] > r["tracked_force_rms_n"]["before"]
            assert r["reason"].startswith("refused: tracked held-out force ")
        rows.append(
            f"| {hidden} | {seed} | {', '.join(report.added) or '-'} | "
            + " -> ".join(f"{s.tracked_before:.4g}" for s in report.steps)
            + f" | {report.unexplained.remains if report.unexplained else '?'} |"
        )
    header = "| hidden | seed | added | tracked held-out force by step (N) | unexplained |"
    print("\n" + "\n".join([header, "|---|---|---|---|---|", *rows]))


def test_the_alternatives_hook_takes_further_empirical_models() -> None:
    seen: list[FitData] = []

    def oracle(data: FitData) -> list[tuple[str, float]]:
        seen.append(data)
        return [("power law with drift correction (stand-in)", 1e-3), ("no rows", math.nan)]

    channel, metadata = generated_record("rate", 1)
    report = run_discrepancy(channel, baseline=PAPER, metadata=metadata, candidates=(), alternatives=oracle)
    assert len(seen) == 1 and seen[0].test.any()
    u = report.as_json()["unexplained_residual"]
    assert u["best_alternative"] == {
        "name": "power law with drift correction (stand-in)",
        "force_rms_n": 1e-3,
    }
    assert [a["name"] for a in u["alternatives"]][:2] == ["conductance line", "monotone lookup"]
    assert u["alternatives"][-1] == {"name": "no rows", "force_rms_n": None}
    # the static rivals alone decide "worse than the best static rival"
    assert u["best_static_rival"]["name"] in {"conductance line", "monotone lookup"}


def test_cli_prints_the_unexplained_residual_and_its_json_keys(tmp_path: Path) -> None:
    channel, metadata = generated_record("humidity", 1)
    assert channel.force_n is not None and channel.temperature_c is not None
    rec = tmp_path / "humidity.csv"
    rec.write_text(
        format_record(
            metadata, ["0"], channel.time_s, channel.resistance_ohm[:, None], channel.force_n[:, None],
            channel.temperature_c[:, None],
        )
    )  # fmt: skip
    args = ["discrepancy", str(rec), "--baseline", "tunneling,contact,creep", "--candidates", "hysteresis"]
    result = CliRunner().invoke(main, [*args, "--json"])
    assert result.exit_code == 0, result.output
    j = json.loads(result.stdout)
    assert {"record", "baseline", "added", "final", "gap_before", "gap_after", "steps"} <= set(j)
    assert j["unexplained_residual"]["remains"] is True
    assert j["unexplained_residual"]["structure"]["most_varying_axis"] in {"run", "elapsed"}
    assert isinstance(j["refused"], list)
    out = tmp_path / "report"
    result = CliRunner().invoke(main, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "AN UNEXPLAINED RESIDUAL REMAINS" in result.output
    assert "the log-R residual varies most with" in result.output
    text = (out / "report.md").read_text()
    assert "## An unexplained residual remains" in text
    assert "### Residual by measurement run" in text and "### Residual by temperature" in text


def test_the_rule_is_checked_again_where_the_model_changes(monkeypatch: pytest.MonkeyPatch) -> None:
    """A route that forgot the rule (here: one that always picks the candidate with the worst
    tracked force) still cannot add a worse reading: the workflow checks it again."""
    import gateway.analysis.discrepancy as workflow

    def careless(fit, data, scored, findings, force_floor=0.0):  # type: ignore[no-untyped-def]
        worst = max(scored, key=lambda c: c.gap_test.force_rms_n)
        return worst.effect, "picked without the rule", None

    monkeypatch.setattr(workflow, "_decide", careless)
    channel, metadata = generated_record("rate", 1)
    report = run_discrepancy(channel, baseline=PAPER, metadata=metadata, candidates=("creep2", "leakage"))
    assert not tracked_violations(report)
    first = report.steps[0]
    worst = max(first.candidates, key=lambda c: c.gap_test.force_rms_n)
    assert worst.gap_test.force_rms_n > first.tracked_before  # the worst candidate reads it worse
    assert first.added is None and f"not added after all: {worst.effect} refused" in first.evidence
