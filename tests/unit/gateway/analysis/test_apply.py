"""``apply_calibration``: a calibration read by the runtime's tracker over a record.

Records are made by the gateway's own forward model (``SensorModel.simulate``, creep on) at
known forces, or by hand; the expected forces are those forces, or numbers worked out here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gateway.analysis.apply import (
    ApplyError,
    apply_calibration,
    apply_report,
    channel_errors,
    channel_mapping,
    overall_errors,
    write_applied,
)
from gateway.analysis.records import Record, format_record, parse_record, read_record
from gateway.errors import ConfigError
from gateway.model import SensorModel, SensorParams
from gateway.model.effects import PAPER_EFFECTS
from gateway.runtime.snapshot import STATUS_LABELS

#: A sensor unlike the defaults, creeping fast (tau1 = mu1 / E1 = 75 s at rest).
TRUE = SensorParams(r0_ohm=150e3, e0_pa=1.8e7, e1_pa=1.2e8, mu1_pa_s=9e9)
TRUE_TABLE = "r0_ohm = 150e3\ne0_pa = 1.8e7\ne1_pa = 1.2e8\nmu1_pa_s = 9e9\n"
#: 0 N, holds at 1 N and 3 N for 60 s each, a step down to 2 N for 40 s, then 0 N.
PROFILE = ((10.0, 0.0), (60.0, 1.0), (60.0, 3.0), (40.0, 2.0), (20.0, 0.0))


def _profile(dt: float, start: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(start, sum(d for d, _ in PROFILE), dt)
    edges = np.cumsum([0.0] + [d for d, _ in PROFILE])
    f = np.zeros_like(t)
    for (_, level), lo, hi in zip(PROFILE, edges[:-1], edges[1:], strict=True):
        f[(t >= lo) & (t < hi)] = level
    return t, f


def _simulate(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    breakdown, _ = SensorModel(PAPER_EFFECTS, [TRUE]).simulate(f[:, None], t)
    return np.asarray(breakdown.total_ohm[:, 0])


def _calibration(tmp_path: Path, text: str, name: str = "cal.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _record(text: str) -> Record:
    return parse_record(text, Path("rec.csv"))


def test_the_true_parameters_give_the_true_forces_while_the_static_force_drifts(tmp_path: Path) -> None:
    t, f = _profile(0.5)
    r = _simulate(t, f)
    assert np.isinf(r[f == 0]).all()  # contact open at rest: the record says inf
    record = _record(format_record({}, ["pad"], t, r[:, None], f[:, None]))
    cal = _calibration(tmp_path, f'[channel."pad"]\n{TRUE_TABLE}')
    applied = apply_calibration(cal, record)
    (ch,) = applied.channels
    assert (ch.name, ch.calibration_channel, ch.model) == ("pad", "pad", "physics")
    assert applied.device_samples == t.size
    np.testing.assert_allclose(ch.force_tracked_n, f, rtol=0, atol=1e-6)
    assert set(ch.status_counts()) == {"ok", "no_contact"}
    assert ch.status_counts()["no_contact"] == int((f == 0).sum())

    err = channel_errors(ch)
    assert err is not None
    levels = [round(h.hold.level_n, 6) for h in err.holds]
    assert levels == [1.0, 3.0, 2.0]
    for h in err.holds:
        assert abs(h.tracked_start_n) < 1e-6 and abs(h.tracked_end_n) < 1e-6
    one, three, two = err.holds
    # loaded from rest, the static estimate reads the creep as force: more at each hold's end
    assert 0.0 <= one.static_start_n < 0.02 and one.static_end_n > 0.05
    assert three.static_end_n - three.static_start_n > 0.1
    # after a step down from 3 N the strain still exceeds 2 N's: the static force starts high
    # and creeps back only partly
    assert two.static_start_n > 0.1 and two.static_end_n > 0.1
    assert err.overall.rows == t.size and err.overall.full_scale_n == 3.0
    assert err.overall.tracked_rms_n < 1e-6 < 0.05 < err.overall.static_rms_n


def test_channels_sampled_at_different_times_keep_their_own_state(tmp_path: Path) -> None:
    """Channel a every 0.5 s, channel b every 0.7 s from 0.2 s, one time of a twice: each
    reads its true force, as it does alone (its state is relaxed exactly across the device
    samples where it has no row)."""
    ta, fa = _profile(0.5)
    ta = np.insert(ta, 41, ta[40])  # a repeated time: a step of 0 s
    fa = np.insert(fa, 41, fa[40])
    tb, fb = _profile(0.7, start=0.2)
    ra, rb = _simulate(ta, fa), _simulate(tb, fb)
    rows = sorted(
        [(t, "a", r, f) for t, r, f in zip(ta, ra, fa, strict=True)]
        + [(t, "b", r, f) for t, r, f in zip(tb, rb, fb, strict=True)],
        key=lambda row: row[0],
    )
    text = "time_s,channel,resistance_ohm,force_n\n" + "".join(
        f"{float(t)!r},{c},{float(r)!r},{float(f)!r}\n" for t, c, r, f in rows
    )
    cal = _calibration(tmp_path, f'[channel."ch00"]\n{TRUE_TABLE}[channel."ch01"]\n{TRUE_TABLE}')
    applied = apply_calibration(cal, _record(text), rename={"a": "ch00", "b": "ch01"})
    assert applied.device_samples == len(set(ta.tolist()) | set(tb.tolist())) + 1
    a, b = applied.channel("a"), applied.channel("b")
    np.testing.assert_allclose(a.force_tracked_n, fa, rtol=0, atol=1e-6)
    np.testing.assert_allclose(b.force_tracked_n, fb, rtol=0, atol=1e-6)
    # the same as each channel read alone, to rounding
    only_b = _record(format_record({}, ["ch01"], tb, rb[:, None], fb[:, None]))
    alone = apply_calibration(cal, only_b).channels[0]
    np.testing.assert_allclose(b.force_tracked_n, alone.force_tracked_n, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b.force_static_n, alone.force_static_n, rtol=1e-12, atol=1e-12)


LINE = """
[line."tip"]
slope_s_per_n = 1e-5
intercept_s = 2e-6
"""


def test_a_line_calibration_reads_f_from_the_conductance_line(tmp_path: Path) -> None:
    # F = (1/R - n) / m with m = 1e-5 S/N, n = 2e-6 S, inside the default 0.05-10 N
    text = (
        "time_s,channel,resistance_ohm\n0,tip,1e5\n1,tip,2.5e4\n2,tip,5e4\n3,tip,1e4\n4,tip,1e7\n5,tip,inf\n"
    )
    applied = apply_calibration(_calibration(tmp_path, LINE), _record(text))
    (ch,) = applied.channels
    assert ch.model == "line"
    expected = [0.8, 3.8, 1.8, 9.8, 0.0, 0.0]  # 1e-7 S < n: below the line's zero, no contact
    np.testing.assert_allclose(ch.force_tracked_n, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ch.force_static_n, expected, rtol=1e-12, atol=1e-12)
    assert [STATUS_LABELS[int(s)] for s in ch.status] == ["ok"] * 4 + ["no_contact"] * 2
    assert channel_errors(ch) is None and overall_errors(applied) is None


def _hold_record() -> str:
    """0 N for two rows, 2 N for 20 rows (t = 1 ... 10.5 s), 0 N for two rows."""
    # with F = 1e5 / R: 1.6, 1.6, 2.5, 2.0 ..., 2.5, 1.0, 1.0
    hold_r = [6.25e4, 6.25e4, 4e4] + [5e4] * 14 + [4e4, 1e5, 1e5]
    rows = [(0.0, "inf", 0.0), (0.5, "inf", 0.0)]
    rows += [(1.0 + 0.5 * k, repr(r), 2.0) for k, r in enumerate(hold_r)]
    rows += [(11.0, "inf", 0.0), (11.5, "inf", 0.0)]
    return "# bench: hand\ntime_s,resistance_ohm,force_n\n" + "".join(f"{t},{r},{f}\n" for t, r, f in rows)


def test_hold_start_and_end_errors_by_hand(tmp_path: Path) -> None:
    cal = _calibration(tmp_path, '[line."0"]\nslope_s_per_n = 1e-5\nintercept_s = 0.0\n')
    applied = apply_calibration(cal, _record(_hold_record()))
    (ch,) = applied.channels
    err = channel_errors(ch)
    assert err is not None
    (hold,) = err.holds
    # the hold without 0.5 s at each end (``holds.EDGE_GUARD_S``): rows 3-20, 1.5-10 s
    assert (hold.hold.start, hold.hold.stop, hold.hold.start_s, hold.hold.end_s) == (3, 21, 1.5, 10.0)
    assert hold.edge_rows == 1  # 10 % of 18 rows
    assert not hold.after_higher
    # its first row: 1.6 - 2; its last: 1.0 - 2
    assert hold.tracked_start_n == pytest.approx(-0.4)
    assert hold.tracked_end_n == pytest.approx(-1.0)
    assert (hold.static_start_n, hold.static_end_n) == (hold.tracked_start_n, hold.tracked_end_n)
    assert err.drift_tracked is not None and err.drift_tracked.others_pct_fs == pytest.approx(100 * 0.6 / 2.0)
    # RMS over all 24 rows (the four unloaded rows read 0 N: no error)
    rms = math.sqrt((2 * 0.4**2 + 2 * 0.5**2 + 2 * 1.0**2) / 24)
    assert err.overall.tracked_rms_n == pytest.approx(rms)
    assert err.overall.full_scale_n == 2.0
    assert err.overall.pct(err.overall.tracked_rms_n) == pytest.approx(100 * rms / 2.0)

    report = apply_report(applied, [err])
    (channel,) = report["channels"]
    assert channel["holds"][0]["tracked"] == {
        "start_error_n": pytest.approx(-0.4),
        "end_error_n": pytest.approx(-1.0),
    }
    assert report["overall"]["tracked"]["rms_n"] == pytest.approx(rms)


def test_the_written_record_reads_back_with_the_added_columns(tmp_path: Path) -> None:
    cal = _calibration(tmp_path, '[line."0"]\nslope_s_per_n = 1e-5\nintercept_s = 0.0\n')
    applied = apply_calibration(cal, _record(_hold_record()))
    out = tmp_path / "out.csv"
    write_applied(out, applied, {"calibration": "cal.toml"})
    back = read_record(out, require_force=True)
    assert back.metadata == {"bench": "hand", "calibration": "cal.toml"}
    assert back.extra_columns == ("force_tracked_n", "force_static_n", "status")
    ch = back.channel("0")
    np.testing.assert_array_equal(ch.time_s, applied.channels[0].record.time_s)
    lines = out.read_text().splitlines()
    assert lines[2] == "time_s,channel,resistance_ohm,force_n,force_tracked_n,force_static_n,status"
    assert lines[3] == "0.0,0,inf,0.0,0.0,0.0,no_contact"
    first = lines[5].split(",")  # the first row of the hold: 1e5 / 62500 ohm = 1.6 N
    assert first[:4] == ["1.0", "0", "62500.0", "2.0"] and first[6] == "ok"
    assert float(first[4]) == pytest.approx(1.6) and float(first[5]) == pytest.approx(1.6)


def test_rows_keep_the_record_order_and_a_reading_without_value_is_empty(tmp_path: Path) -> None:
    cal = _calibration(tmp_path, LINE + '[line."pad"]\nslope_s_per_n = 1e-5\nintercept_s = 2e-6\n')
    text = "time_s,channel,resistance_ohm\n0,pad,1e5\n0,tip,2.5e4\n1,tip,5e4\n2,pad,5e4\n"
    applied = apply_calibration(cal, _record(text), channels=["tip", "pad"])
    assert [c.name for c in applied.channels] == ["tip", "pad"]
    out = tmp_path / "o.csv"
    write_applied(out, applied)
    body = out.read_text().splitlines()[1:]
    assert [line.split(",")[:2] for line in body] == [
        ["0.0", "pad"],
        ["0.0", "tip"],
        ["1.0", "tip"],
        ["2.0", "pad"],
    ]
    assert applied.device_samples == 3


def test_mapping_errors_name_both_lists() -> None:
    with pytest.raises(ApplyError) as exc:
        channel_mapping(["a", "b"], ["ch00", "b"])
    assert "'a' has no calibration table" in str(exc.value)
    assert "record channels: a, b; calibration channels: ch00, b" in str(exc.value)
    with pytest.raises(ApplyError, match="no channel 'c' in the record"):
        channel_mapping(["a"], ["a"], selected=["c"])
    with pytest.raises(ApplyError, match="'a' is mapped to 'x', which has no calibration table"):
        channel_mapping(["a"], ["a"], rename={"a": "x"})
    with pytest.raises(ApplyError, match="both map to calibration channel 'a'"):
        channel_mapping(["a", "b"], ["a"], rename={"b": "a"})
    assert channel_mapping(["a", "b"], ["ch00", "b"], rename={"a": "ch00"}) == {"a": "ch00", "b": "b"}
    assert channel_mapping(["a", "b"], ["b"], selected=["b"]) == {"b": "b"}


def test_a_calibration_the_gateway_refuses_is_refused_with_its_message(tmp_path: Path) -> None:
    record = _record("time_s,channel,resistance_ohm\n0,ch00,1e5\n")
    bad = _calibration(tmp_path, '[channel."ch00"]\nr0_ohm = -5\n')
    with pytest.raises(ConfigError, match=r"channel\.ch00\.r0_ohm: .*-5"):
        apply_calibration(bad, record)
    wrong_line = _calibration(tmp_path, '[line."ch00"]\nslope_s_per_n = 0\nintercept_s = 0\n', "l.toml")
    with pytest.raises(ConfigError, match=r"line\.ch00\.slope_s_per_n"):
        apply_calibration(wrong_line, record)
    with pytest.raises(ConfigError, match="no such file"):
        apply_calibration(tmp_path / "none.toml", record)


def test_the_calibrations_own_record_is_reported_as_in_sample(tmp_path: Path) -> None:
    from gateway.analysis.apply import format_apply_report

    text = "time_s,channel,resistance_ohm,force_n\n0,tip,1e5,0.8\n1,tip,2.5e4,3.8\n2,tip,5e4,1.8\n"
    own = tmp_path / "rec.csv"
    other = tmp_path / "other.csv"
    own.write_text(text)
    other.write_text(text)
    cal = _calibration(tmp_path, f'[meta]\nrecord = "{own}"\n' + LINE)
    for path, in_sample in ((own, True), (other, False)):
        applied = apply_calibration(cal, read_record(path))
        errors = [channel_errors(c) for c in applied.channels]
        report = format_apply_report(applied, errors)
        assert ("in-sample" in report) is in_sample, report
        assert apply_report(applied, errors)["in_sample"] is in_sample
