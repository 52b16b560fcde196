"""Calibration: recover parameters, write a file the gateway reads, read a new record to 0.1 N."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.calibration import calibrate
from gateway.analysis.records import format_record, read_record, write_record
from gateway.cli import main
from gateway.config import parse_config
from gateway.model import ForceStatus, SensorModel, SensorParams

PAPER = ("tunneling", "contact", "creep")
TRUE = SensorParams(r0_ohm=225e3, e0_pa=13.5e6, rho2_ohm_m=0.85, e1_pa=140e6, mu1_pa_s=1.2e10)


def _write(path: Path, levels: list[float], hold_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hold_s * len(levels), 0.5)
    f = np.array(levels)[np.minimum((t // hold_s).astype(int), len(levels) - 1)]
    out, _ = SensorModel(PAPER, TRUE).simulate(f[:, None], t)
    r = out.total_ohm[:, 0] * np.exp(0.01 * rng.standard_normal(t.size))
    write_record(path, format_record({"sensor": "test"}, ["tip"], t, r[:, None], force_n=f[:, None]))
    return t, f


def test_calibrate_cli_json_and_file(tmp_path: Path) -> None:
    rec = tmp_path / "bench.csv"
    _write(rec, [0.0, 0.3, 1.0, 0.0, 2.0, 4.0, 0.5, 6.0, 0.0, 3.0, 8.0, 1.5, 0.0], 200.0, seed=11)
    cal = tmp_path / "cal.toml"
    result = CliRunner().invoke(main, ["calibrate", str(rec), "--out", str(cal), "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    (one,) = payload["calibrations"]
    values = {p["name"]: p for p in one["parameters"]}
    for name in ("r0_ohm", "e0_pa", "rho2_ohm_m", "e1_pa", "mu1_pa_s"):
        p = values[name]
        assert p["fitted"], p
        # one record, five intervals: allow twice the 95 % half-width (coverage is tested in test_fitting)
        half = (p["ci95_high"] - p["ci95_low"]) / 2
        assert abs(p["value"] - getattr(TRUE, name)) <= 2 * half, p
    held = one["fit_quality"]["held_out"]
    assert held["force_rms_n"] < 0.1
    # the paper's line is much worse on the same held-out rows
    assert one["conductance_line"]["held_out_force_rms_n"] > 3 * held["force_rms_n"]
    assert one["rows"]["unusable"]["zero_force"] > 0
    text = cal.read_text()
    assert '[channel."tip"]' in text and "r0_ohm = " in text


def test_round_trip_calibration_reads_another_record_within_a_tenth_of_a_newton(tmp_path: Path) -> None:
    first = tmp_path / "first.csv"
    _write(first, [0.0, 0.3, 1.0, 0.0, 2.0, 4.0, 0.5, 6.0, 0.0, 3.0, 8.0, 1.5, 0.0], 200.0, seed=21)
    cal_path = tmp_path / "cal.toml"
    result = CliRunner().invoke(main, ["calibrate", str(first), "--out", str(cal_path)])
    assert result.exit_code == 0, result.output
    assert "conductance line" in result.output
    config = parse_config(
        f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 1
calibration = "{cal_path}"
[[bus.device.channel]]
index = 0
name = "tip"
""",
        tmp_path / "gateway.toml",
    )
    params = config.buses[0].devices[0].channels[0].params
    assert abs(params.r0_ohm / TRUE.r0_ohm - 1) < 0.02
    second = tmp_path / "second.csv"
    t, f = _write(second, [0.0, 1.2, 2.5, 4.5, 0.8, 0.0, 3.5, 0.6], 150.0, seed=22)
    r = read_record(second).channel("tip").resistance_ohm
    inv, _ = SensorModel(PAPER, params).track_series(r[:, None], t)
    settled = np.ones(t.size, dtype=bool)
    steps = np.flatnonzero(np.diff(f) != 0) + 1
    for s in steps:
        settled[s : s + 4] = False  # 2 s after each step
    loaded = settled & (f > 0)
    err = np.abs(inv.force_n[loaded, 0] - f[loaded])
    within = float(np.mean(err <= 0.1))
    print(f"\nround trip: {100 * within:.1f} % of settled samples within 0.1 N (max error {err.max():.3f} N)")
    assert within >= 0.95
    unloaded = settled & (f == 0)
    assert np.all(inv.status[unloaded, 0] == ForceStatus.NO_CONTACT)


def test_calibrate_bad_inputs_are_clear(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,resistance_ohm\n0,1\n")
    result = CliRunner().invoke(main, ["calibrate", str(bad)])
    assert result.exit_code == 2
    assert "missing required column 'force_n'" in result.output
    result = CliRunner().invoke(main, ["calibrate", str(bad), "--effects", "creeep"])
    assert result.exit_code == 2 and "did you mean 'creep'" in result.output
    assert "Traceback" not in result.output


def test_a_record_too_short_to_hold_out_is_refused() -> None:
    from gateway.analysis.records import parse_record

    rec = parse_record("time_s,resistance_ohm,force_n\n0,1e5,1\n")
    try:
        calibrate(rec.channel(), PAPER)
    except ValueError as exc:
        assert "not enough usable rows" in str(exc)
    else:
        raise AssertionError("a one-row record was calibrated")


def test_a_line_with_a_negative_intercept_is_written_to_read_from_above_its_zero() -> None:
    """C = m F + n with n = -1e-5 S, m = 2e-5 S/N reaches zero conductance at 0.5 N; a record
    that starts at 0.3 N would give a channel reading ~0.5 N at rest, which the gateway refuses.
    The [line] table calibrate writes (``line_channel``) then carries force_min_n = 1.1 x 0.5 N,
    and loads to a channel that reads an open sensor as no contact."""
    import math

    from gateway.model.calibrated import line_channel
    from gateway.model.conversion import conversion_from_table
    from gateway.model.static_curves import LineCurve
    from gateway.model.tracker import track_series

    line = LineCurve(2e-5, -1e-5)
    written = line_channel(line, 0.3, 8.0)
    table = written.table()
    assert table["force_min_n"] == pytest.approx(0.55)
    conv = conversion_from_table("line", table, 0.3, 8.0)  # the channel's range is the record's
    assert conv == written
    force, _ = track_series(conv, [math.inf, 1e12], [0.0, 1.0])
    assert force.tolist() == [0.0, 0.0]
    # without the table's own minimum the same line is refused, with the reason
    with pytest.raises(ValueError, match=r"zero conductance at 0\.5 N"):
        conversion_from_table("line", {"slope_s_per_n": 2e-5, "intercept_s": -1e-5}, 0.3, 8.0)
    # a positive intercept, or a record that starts well above the zero, keeps the record's start
    assert line_channel(LineCurve(2e-5, 1e-6), 0.05, 8.0).force_min_n == 0.05
    assert line_channel(line, 0.6, 8.0).force_min_n == 0.6


def test_a_channel_calibrated_on_half_to_five_newtons_reads_beyond_it_flagged_extrapolated(
    tmp_path: Path,
) -> None:
    """calibrate on 0.5-5 N holds writes the calibrated range as calibrated_min_n/max_n and the
    model's range from light touch to 3 x the top; the gateway then reads 0.3 N and 8 N holds
    as forces flagged extrapolated (not 0 N no_contact and 5 N saturated), and rest as
    no_contact. The report says what happens outside the range."""
    import tomllib

    from gateway.modbus.image import RawSample
    from gateway.runtime.processor import DeviceProcessor
    from gateway.runtime.snapshot import ChannelStatus

    bench = tmp_path / "bench.csv"
    _write(bench, [0.0, 0.5, 1.0, 0.0, 2.0, 5.0, 0.5, 3.0, 0.0, 4.0, 1.5, 0.0], 150.0, seed=31)
    cal_path = tmp_path / "cal.toml"
    args = ["calibrate", str(bench), "--out", str(cal_path), "--model", "physics"]
    result = CliRunner().invoke(main, [*args, "--objective", "log-r", "--force-offset", "none"])
    assert result.exit_code == 0, result.output
    table = tomllib.loads(cal_path.read_text())["channel"]["tip"]
    low, high = table["calibrated_min_n"], table["calibrated_max_n"]
    # the record's 0.5-5 N, widened by the reading noise at each end (checked against the
    # readings' own spread below): a few percent of the range, not a blindfold
    assert 0.45 < low < 0.5 and 5.0 < high < 5.5, (low, high)
    assert (
        f"outside the calibrated range: below {low:.3g} N and above {high:.4g} N the channel reads forces "
        "extrapolated along its curve, flagged `extrapolated`; at or below 0 N it reads no_contact"
    ) in result.output
    assert (table["force_min_n"], table["force_max_n"]) == (0.01, 3 * high)
    config = parse_config(
        f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
encoding = "float32"
channels = 1
calibration = "{cal_path}"
[[bus.device.channel]]
index = 0
name = "tip"
""",
        tmp_path / "gateway.toml",
    )
    device = config.buses[0].devices[0]
    assert device.channels[0].calibrated_range_n == (low, high)
    proc = DeviceProcessor(device, "bench", 0.5)
    holds = tmp_path / "holds.csv"
    t, f = _write(holds, [0.0, 0.3, 0.5, 2.0, 5.0, 8.0, 0.0], 100.0, seed=32)
    r = read_record(holds).channel("tip").resistance_ohm
    state = proc.initial_state()
    seen: dict[float, list[tuple[str, float]]] = {}
    for k in range(t.size):
        raw = RawSample(resistance_ohm=r[k : k + 1], open_bits=np.array([False]))  # +inf: open at rest
        snap, state = proc.process(state, raw, 1e9 + t[k], t[k])
        if t[k] % 100.0 >= 5.0:  # settled
            seen.setdefault(float(f[k]), []).append(
                (ChannelStatus(int(snap.status[0])).label, snap.force_n[0])
            )
    # the record's own end forces read ok: a reading of 5 N is noisy, and about half of them
    # lie above 5 N, inside the noise of a calibrated one
    at_top = np.array([v for _, v in seen[5.0]])
    assert np.mean(at_top > 5.0) > 0.2
    # the margin is 3 standard deviations of what a reading at the top actually scatters by
    assert 2.0 < (high - 5.0) / np.std(at_top) < 4.5, (high, np.std(at_top))
    for load, label, tolerance_n in (
        (0.3, "extrapolated", 0.02),
        (0.5, "ok", 0.02),
        (2.0, "ok", 0.05),
        (5.0, "ok", 0.1),
        (8.0, "extrapolated", 0.2),
    ):
        assert {s for s, _ in seen[load]} == {label}, (load, seen[load][:3])
        forces = np.array([v for _, v in seen[load]])
        assert np.median(np.abs(forces - load)) < tolerance_n, (load, np.median(forces))
    assert {s for s, _ in seen[0.0]} == {"no_contact"}
