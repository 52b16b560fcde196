"""What ``calibrate`` ranks is what ``apply`` (and so the gateway) reads: for every calibration
in the ranking, its held-out force RMS equals ``apply``'s on the same rows to 1e-9 N, and its
hold drift in both groups is the one ``apply`` reports for those rows."""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from gateway.analysis.apply import apply_calibration
from gateway.analysis.calibration import Calibration, calibrate, write_calibration
from gateway.analysis.fitting import FitData
from gateway.analysis.holds import drift_groups_pct, hold_drifts, hold_tolerance_n
from gateway.analysis.records import ChannelRecord, format_record, read_record, write_record

K, N, A, TAU, TAU_REC = 1e-4, 0.8, 0.15, 4.0, 12.0


@cache
def _record(folder: Path) -> tuple[Path, ChannelRecord]:
    """A power-law FSR (G = k F^0.8) with one Kelvin element that recovers 3 x slower than it
    creeps: rest, then holds of 12 s at falling and rising levels, 0.1 s steps, 0.5 % noise."""
    levels = [4.0, 1.0, 3.0, 0.5, 5.0, 1.5, 2.0, 4.5, 0.8, 3.5]
    t = np.arange(0.0, 12.0 * (len(levels) + 1), 0.1)
    force = np.concatenate([[0.0] * 120] + [[lv] * 120 for lv in levels])[: t.size]
    z, x = 0.0, np.empty(t.size)
    for k in range(t.size):
        held = force[k - 1] if k else 0.0
        tau = TAU if held > z / A else TAU_REC
        z = A * held + (z - A * held) * math.exp(-(t[k] - t[k - 1]) / tau) if k else 0.0
        x[k] = force[k] + z
    with np.errstate(divide="ignore"):
        r = 1.0 / (K * x**N)
    r = r * np.exp(0.005 * np.random.default_rng(5).standard_normal(t.size))
    path = folder / "bench.csv"
    write_record(path, format_record({"time": "real"}, ["tip"], t, r[:, None], force_n=force[:, None]))
    return path, read_record(path, require_force=True).channel()


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ChannelRecord, Calibration]:
    path, channel = _record(tmp_path_factory.mktemp("rank"))
    return path, channel, calibrate(channel, record_name=str(path), metadata={"time": "real"})


def test_every_calibration_in_the_ranking_reads_as_apply_reads_it(
    calibrated: tuple[Path, ChannelRecord, Calibration], tmp_path: Path
) -> None:
    path, channel, cal = calibrated
    data = FitData.from_channel(channel)
    record = read_record(path, require_force=True)
    kinds = {s.name.split(" + ")[0] for s in cal.scores}
    assert kinds == {"physics", "line", "lookup", "power_law"}, kinds  # every kind of candidate
    assert len(cal.scores) >= 15
    full_scale = float(np.max(channel.force_n[data.usable]))  # type: ignore[index]
    for score in cal.scores:
        out = tmp_path / "cal.toml"
        write_calibration(out, [cal], chosen={cal.channel: score.name})
        applied = apply_calibration(out, record).channel("tip")
        err = (applied.force_tracked_n - channel.force_n)[data.test]
        err = err[np.isfinite(err)]
        apply_rms = float(np.sqrt(np.mean(err * err)))
        assert apply_rms == pytest.approx(score.held_out_force_rms_n, abs=1e-9), score.name
        assert channel.force_n is not None
        drifts = hold_drifts(
            channel.time_s, channel.force_n, applied.force_tracked_n, data.test, None,
            hold_tolerance_n(channel.force_n),
        )  # fmt: skip
        groups = drift_groups_pct(drifts, full_scale)
        for mine, theirs in zip(score.drift.all_pct_fs, groups.all_pct_fs, strict=True):
            assert (math.isnan(mine) and math.isnan(theirs)) or mine == pytest.approx(theirs, abs=1e-9)


def test_a_dynamic_calibration_that_drifts_more_than_static_is_never_written(
    calibrated: tuple[Path, ChannelRecord, Calibration],
) -> None:
    _, _, cal = calibrated
    writable = {s.name for s in cal.writable()}
    rivals = [cal.score("lookup"), cal.best_static()]
    for s in cal.scores:
        # the lookup's, and for a dynamic calibration also the best static rival's, in each group
        references = rivals if s.dynamic else rivals[:1]
        worse = any(
            math.isfinite(r) and math.isfinite(v) and v > r
            for rival in references
            if rival is not None
            for v, r in zip(s.drift.all_pct_fs, rival.drift.all_pct_fs, strict=True)
        )
        assert (s.name in writable) == (s.name == "lookup" or not worse), s.name
    assert cal.best in writable
    # this sensor creeps: a drift correction reads its holds flatter than any static curve
    best = cal.score(cal.best)
    assert best is not None and best.dynamic, cal.best
    assert best.held_out_force_rms_n < 0.5 * min(s.held_out_force_rms_n for s in cal.scores if not s.dynamic)
