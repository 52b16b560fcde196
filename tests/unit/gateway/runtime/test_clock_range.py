"""Issue 33 §11: a time no clock counter can hold (``time_s`` of 1e300 in ``apply``, 1e308 in
``view``) once gave an ``OverflowError`` traceback from ``runtime.clock``. The clock now reads
such a value as no clock reading (the host step, flagged as not from the device), and a record
whose times span more than a 64-bit nanosecond clock counts is refused by ``apply`` and
``view`` with one line naming the span."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from click.testing import CliRunner

from gateway.cli import main
from gateway.cli.view_cmd import ViewError, load_playback
from gateway.modbus.register_map import DeviceClock, RegisterKind
from gateway.runtime.clock import NO_CLOCK_HISTORY, ClockHealth, time_step
from gateway.runtime.replay import MAX_REPLAY_SPAN_S

NS64 = DeviceClock(0, 4, 1e-9, RegisterKind.INPUT)
MS64 = DeviceClock(0, 4, 1e-3, RegisterKind.INPUT)
MS16 = DeviceClock(0, 1, 1e-3, RegisterKind.INPUT)


@pytest.mark.parametrize("clock", [NS64, MS64, MS16], ids=["ns64", "ms64", "ms16"])
@pytest.mark.parametrize("device_time_s", [1e300, 1e308, math.inf, math.nan, -1.0])
def test_a_reading_no_counter_holds_is_not_a_clock_reading(clock: DeviceClock, device_time_s: float) -> None:
    health = ClockHealth(last_ticks=5, advanced_host_time_s=10.0)
    step_s, _, from_device, after = time_step(clock, health, device_time_s, None, 1.0, 10.0, True, 12.5)
    # the host clock's step (12.5 - 10.0 s) for this sample, flagged as not the device's
    assert step_s == 2.5 and not from_device
    assert after == health  # nothing learnt about the device's clock
    # at the first sample too
    step_s, _, from_device, after = time_step(
        clock, NO_CLOCK_HISTORY, device_time_s, None, None, None, True, 0.0
    )
    assert step_s == 0.0 and not from_device and after == NO_CLOCK_HISTORY


def test_a_reading_at_the_top_of_a_64_bit_counter_is_still_one() -> None:
    # 2^64 - 1 ns (584 years) is the largest a 64-bit ns counter holds: still a clock reading
    top_s = (2**64 - 1) * 1e-9
    first = time_step(NS64, NO_CLOCK_HISTORY, 0.0, None, None, None, True, 0.0)
    step_s, _, from_device, _ = time_step(NS64, first[3], top_s * 0.5, None, 0.0, 0.0, True, 1.0)
    assert from_device and step_s == pytest.approx(top_s * 0.5, rel=1e-12)
    assert abs(MAX_REPLAY_SPAN_S - 2**64 * 1e-9) <= 1e-12 * MAX_REPLAY_SPAN_S


LINE = '[line."tip"]\nslope_s_per_n = 1e-5\nintercept_s = 0.0\n'


@pytest.mark.parametrize("late_s", ["1e300", "1e308", "2e10"])
def test_apply_refuses_a_record_spanning_more_than_the_clock_in_one_line(tmp_path: Path, late_s: str) -> None:
    cal = tmp_path / "cal.toml"
    cal.write_text(LINE, encoding="utf-8")
    rec = tmp_path / "rec.csv"
    rec.write_text(f"time_s,channel,resistance_ohm,force_n\n0,tip,50000,2\n{late_s},tip,50000,2\n")
    result = CliRunner().invoke(main, ["apply", str(cal), str(rec), "--out", str(tmp_path / "out.csv")])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and not isinstance(result.exception, OverflowError)
    assert f"{float(late_s):g}" in result.output and "584 years" in result.output
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("late_s", ["1e300", "1e308"])
def test_view_refuses_a_record_spanning_more_than_the_clock_in_one_line(tmp_path: Path, late_s: str) -> None:
    rec = tmp_path / "rec.csv"
    rec.write_text(f"time_s,channel,resistance_ohm\n0,tip,50000\n{late_s},tip,50000\n")
    # refused before anything is served (accepted, the command below would serve until stopped)
    with pytest.raises(ViewError, match="584 years"):
        load_playback(rec, None, None)
    result = CliRunner().invoke(main, ["view", str(rec)])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and not isinstance(result.exception, OverflowError)
    assert f"{float(late_s):g}" in result.output and "584 years" in result.output
    assert len([line for line in result.output.splitlines() if line.startswith("tactile-gateway:")]) == 1


def test_a_record_within_the_span_still_applies(tmp_path: Path) -> None:
    # 1e9 s (31.7 years) between two rows: a clock reading, the step taken as recorded
    cal = tmp_path / "cal.toml"
    cal.write_text(LINE, encoding="utf-8")
    rec = tmp_path / "rec.csv"
    rec.write_text("time_s,channel,resistance_ohm,force_n\n0,tip,50000,2\n1e9,tip,50000,2\n")
    result = CliRunner().invoke(main, ["apply", str(cal), str(rec), "--out", str(tmp_path / "out.csv")])
    assert result.exit_code == 0, result.output
