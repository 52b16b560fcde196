"""The FSR emulator's presets and real-like protocols against numbers worked out by hand.

The preset's shapes are computed here from its creep chain alone, by the held-step formula of
section 2b of ``sim_device.fsr_emulator`` (``x -> a F + (x - a F) exp(-t / tau)``, tau the
loading time constant while ``|a F| > |x|``, else the recovery one) applied hold after hold,
with instantaneous steps; the emulator runs the same protocol with 0.2 ms ramps. With ideal
instruments the static reading (``static_force_n``) of a sample is its effective force.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.measurement import time_is_real
from gateway.analysis.records import read_record
from sim_device.cli import main
from sim_device.fsr_emulator import (
    PROTOCOLS,
    REAL_LIKE_SAMPLE_INTERVAL_S,
    CreepElement,
    EmulatedRecord,
    FsrEmulator,
    FsrParams,
    alternating_holds,
    calibration_ramp,
    fast_creep_fsr,
    hold_protocol,
    real_like_fsr,
    write_record,
)

FULL_SCALE_N = 49.0
FAST_RATE = 1e5  # N/s: steps of 0.03-0.2 ms


def chain_force_n(elements: tuple[CreepElement, ...], history: list[tuple[float, float]]) -> float:
    """Sum of the chain's states after holds ``(force_n, duration_s)`` from rest, by hand."""
    total = 0.0
    for e in elements:
        x = 0.0
        for force, duration in history:
            target = e.amplitude * force
            tau = e.tau_load_s if abs(target) > abs(x) else e.tau_recovery_s
            x = target + (x - target) * math.exp(-duration / tau)
        total += x
    return total


def ideal(params: FsrParams) -> FsrParams:
    """The preset's sensor, read by ideal instruments, gain 1, its nominal exponent, no bursts."""
    return replace(params.ideal_instruments(), run_gains=(1.0,), exponent_sigma=0.0, burst_size=0)


def static_at(rec: EmulatedRecord, time_s: float) -> tuple[float, float]:
    """The static reading (N) of the sample nearest ``time_s``, and that sample's time."""
    i = int(np.argmin(np.abs(rec.time_s - time_s)))
    return float(rec.static_force_n()[i]), float(rec.time_s[i])


# ------------------------------------------------------------------------------ real-like


def test_real_like_high_hold_creeps_a_little() -> None:
    """25.5 N after 13 s at 3.3 N: the static reading rises by 0.34 N (0.69 % of 49 N) from
    2 s to 20 s into the hold; ln G by 1.45 ln(24.827 / 24.489) = 0.020."""
    params = ideal(real_like_fsr())
    proto = alternating_holds(cycles=1, rate_n_per_s=FAST_RATE)
    rec = FsrEmulator(params, seed=1).run(proto, sample_interval_s=0.01)
    start = 3.3 / FAST_RATE + 13.0 + 22.2 / FAST_RATE
    chain = params.creep_chain
    readings = []
    for u in (2.0, 20.0):
        got, t = static_at(rec, start + u)
        expected = 25.5 + chain_force_n(chain, [(3.3, 13.0), (25.5, t - start)])
        assert got == pytest.approx(expected, abs=2e-3)
        readings.append(expected)
    assert readings == pytest.approx([24.4886, 24.8272], abs=2e-3)
    drift_fs = 100.0 * (readings[1] - readings[0]) / FULL_SCALE_N
    assert drift_fs == pytest.approx(0.691, abs=0.01)
    assert 0.3 < drift_fs < 1.5  # the preset's target: creep of under 2 % FS in a high hold


def test_real_like_low_hold_after_a_high_one_reads_low_and_recovers() -> None:
    """3.3 N after 20 s at 25.5 N: the reading starts 0.55 in ln G below the rested 3.3 N and
    recovers to 0.19 below within 10 s (+0.61 N, 1.24 % of 49 N): the set's recovery."""
    params = ideal(real_like_fsr())
    proto = alternating_holds(cycles=1, rate_n_per_s=FAST_RATE)
    rec = FsrEmulator(params, seed=2).run(proto, sample_interval_s=0.01)
    chain, n = params.creep_chain, params.exponent
    lead = [(3.3, 13.0)]
    rested, t_rest = static_at(rec, 13.0)
    assert rested == pytest.approx(3.3 + chain_force_n(chain, [(3.3, t_rest - 3.3 / FAST_RATE)]), abs=2e-3)
    assert rested == pytest.approx(3.2068, abs=2e-3)
    start = 3.3 / FAST_RATE + 13.0 + 22.2 / FAST_RATE + 20.0 + 22.2 / FAST_RATE
    readings = []
    for u in (0.5, 10.0):
        got, t = static_at(rec, start + u)
        expected = 3.3 + chain_force_n(chain, [*lead, (25.5, 20.0), (3.3, t - start)])
        assert got == pytest.approx(expected, abs=2e-3)
        readings.append(expected)
    assert readings == pytest.approx([2.1982, 2.8067], abs=2e-3)
    below_rest = [n * math.log(rested / r) for r in readings]  # ln G below the rested reading
    assert below_rest == pytest.approx([0.548, 0.193], abs=0.005)
    assert 100.0 * (readings[1] - readings[0]) / FULL_SCALE_N == pytest.approx(1.24, abs=0.02)


def test_real_like_sensitivity_changes_up_to_twice_between_runs() -> None:
    emu = FsrEmulator(real_like_fsr(), seed=3)
    gains = np.array([emu.conditions(i).gain for i in range(60)])
    # ln g = clip(0.3 z, +-ln(2)/2): |z| > 1.155 in a quarter of the runs, on each side 12 %
    assert gains.max() / gains.min() == pytest.approx(2.0, rel=1e-9)
    assert np.all((gains >= 2**-0.5 - 1e-12) & (gains <= 2**0.5 + 1e-12))


def test_real_like_record_reads_with_the_gateway_reader(tmp_path: Path) -> None:
    emu = FsrEmulator(real_like_fsr(), seed=4)
    proto = alternating_holds(cycles=2)
    rec = emu.run(proto, 0, REAL_LIKE_SAMPLE_INTERVAL_S)
    path = write_record(tmp_path / "slow.csv", [rec], metadata={"preset": "real-like"})
    record = read_record(path, require_force=True)
    meta = record.metadata
    assert time_is_real(meta) and meta["preset"] == "real-like" and meta["protocol"] == "slow-loading"
    assert "a=-0.04 tau_load=0.3 s tau_recovery=12 s" in meta["creep_chain"]
    assert "lag 0.4 s" in meta["force_reference"] and "bursts of 5 samples" in meta["sample_interval_s"]
    ch = record.channel("0")
    # bursts: 4 intervals of 0.02 s +- 50 % and one of 0.12 s +- 0.01 s: 0.04 s on average
    assert ch.n_samples == pytest.approx(proto.duration_s / 0.04, rel=0.01)
    assert np.median(np.diff(ch.time_s)) == pytest.approx(0.02, abs=0.003)
    # unloaded, the sensor reads its 270 kohm leakage (+ 1 ohm lead, +- 0.3 % and 60 ohm noise)
    assert ch.resistance_ohm[0] == pytest.approx(270e3, rel=0.02)


# ------------------------------------------------------------------------------ fast creep


def test_fast_creep_high_hold_drifts_20_to_40_percent_of_full_scale() -> None:
    """25.5 N from rest: 36.06 N read on the static curve 2 s into the hold, 48.34 N at 20 s:
    +12.27 N, 25.0 % of 49 N."""
    params = ideal(fast_creep_fsr())
    proto = hold_protocol([25.5], hold_s=20.0, rest_s=60.0, rate_n_per_s=FAST_RATE, lead_s=5.0)
    rec = FsrEmulator(params, seed=5).run(proto, sample_interval_s=0.01)
    start = 5.0 + 25.5 / FAST_RATE
    readings = []
    for u in (2.0, 20.0):
        got, t = static_at(rec, start + u)
        expected = 25.5 + chain_force_n(params.creep_chain, [(25.5, t - start)])
        assert got == pytest.approx(expected, abs=2e-3)
        readings.append(expected)
    assert readings == pytest.approx([36.063, 48.337], abs=3e-3)
    drift_fs = 100.0 * (readings[1] - readings[0]) / FULL_SCALE_N
    assert 20.0 <= drift_fs <= 40.0
    assert drift_fs == pytest.approx(25.05, abs=0.02)


def test_fast_creep_reads_high_long_after_unloading() -> None:
    """After 20 s at 25.5 N, a 3.3 N load reads 20.89 N 10 s later and 14.55 N 59.9 s later."""
    params = ideal(fast_creep_fsr())
    proto = alternating_holds(cycles=1, low_s=60.0, lead_s=0.0, rate_n_per_s=FAST_RATE)
    rec = FsrEmulator(params, seed=6).run(proto, sample_interval_s=0.01)
    start = 3.3 / FAST_RATE + 22.2 / FAST_RATE + 20.0 + 22.2 / FAST_RATE
    for u, value in ((10.0, 20.888), (59.9, 14.547)):
        got, t = static_at(rec, start + u)
        history = [(3.3, 3.3 / FAST_RATE), (25.5, 20.0), (3.3, t - start)]
        assert got == pytest.approx(3.3 + chain_force_n(params.creep_chain, history), abs=3e-3)
        assert got == pytest.approx(value, abs=5e-3)


# ------------------------------------------------------------------------------- protocols


def test_real_like_protocols() -> None:
    slow = alternating_holds()
    # 3.3 / 40 + 13 + 12 x (22.2 / 40 + 20 + 22.2 / 40 + 10) = 0.0825 + 13 + 373.32 s
    assert slow.duration_s == pytest.approx(386.4025)
    t = np.array([5.0, 13.5, 30.0, 34.5, 386.0])
    np.testing.assert_allclose(slow.force_at(t), [3.3, 20.0, 25.5, 3.3, 3.3])  # 3.3 + 40 x 0.4175
    assert slow.loading_cycles(0.05) == 1  # never unloaded
    assert PROTOCOLS["slow-loading"]().name == "slow-loading"
    ramp = calibration_ramp()
    # 5 + 49 / 0.125 + 24 + 49 / 50 + 2 = 423.98 s
    assert ramp.duration_s == pytest.approx(423.98)
    np.testing.assert_allclose(ramp.force_at(np.array([5.0, 205.0, 410.0, 423.0])), [0.0, 25.0, 49.0, 0.0])
    assert PROTOCOLS["calibration-ramp"]().name == "calibration-ramp"
    with pytest.raises(ValueError, match="need 0 < low_n < high_n"):
        alternating_holds(high_n=3.0, low_n=3.3)
    with pytest.raises(ValueError, match="cycles must be >= 1"):
        alternating_holds(cycles=0)


# ---------------------------------------------------------------------------------- the CLI


def test_cli_writes_a_real_like_record(tmp_path: Path) -> None:
    out = tmp_path / "slow.csv"
    args = ["fsr-record", str(out), "--preset", "real-like", "--protocol", "slow-loading", "--runs", "1"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "preset real-like" in result.output
    record = read_record(out, require_force=True)
    assert record.metadata["preset"] == "real-like"
    assert np.median(np.diff(record.channel("0").time_s)) == pytest.approx(0.02, abs=0.003)
    coarse = tmp_path / "coarse.csv"
    args = ["fsr-record", str(coarse), "--preset", "fast-creep", "--protocol", "holds", "--runs", "1"]
    result = CliRunner().invoke(main, [*args, "--sample-interval-s", "0.05"])
    assert result.exit_code == 0, result.output
    assert "0.05 (jitter" in read_record(coarse, require_force=True).metadata["sample_interval_s"]
    # 0.5 s: the +-50 % jitter (0.25 s) would let the 0.12 s gap between bursts go negative
    result = CliRunner().invoke(main, [*args, "--sample-interval-s", "0.5"])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert "burst_gap_s must be > jitter_fraction x sample_interval_s = 0.25 s" in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--preset", "nosuch"], "nosuch"), (["--sample-interval-s", "0"], "--sample-interval-s")],
)
def test_cli_refuses_bad_presets_and_intervals(tmp_path: Path, args: list[str], message: str) -> None:
    result = CliRunner().invoke(main, ["fsr-record", str(tmp_path / "o.csv"), *args])
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "o.csv").exists()
