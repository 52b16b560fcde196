"""The calibration ranking on the real records (tests/data/real): every calibration and every
curve candidate on the same held-out rows, the best never worse than the line and the lookup,
and the file ``calibration_toml`` writes reads back as the winner.

``calibrate`` takes one to three seconds per record: each record is calibrated once per module.
"""

from __future__ import annotations

import math
import tomllib
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from gateway.analysis.calibration import Calibration, calibrate, calibration_toml
from gateway.analysis.calibration_result import Score
from gateway.analysis.candidates import Candidate
from gateway.analysis.discrepancy import decimate
from gateway.analysis.fitting import FitData
from gateway.analysis.records import read_record
from gateway.model.curves import CURVE_KINDS, DRIFT_FORMS, curve_from_table, track_series

REAL = Path(__file__).resolve().parents[3] / "data" / "real"
RECORDS = sorted(p.name for p in REAL.glob("*.csv"))


@cache
def calibrated(name: str) -> tuple[Calibration, FitData]:
    """The record's calibration and the rows it was fitted and scored on."""
    record = read_record(REAL / name, require_force=True)
    cal = calibrate(record.channel(), record_name=name, metadata=record.metadata)
    return cal, FitData.from_channel(decimate(record.channel()))


def test_there_are_real_records() -> None:
    assert len(RECORDS) == 3


@pytest.mark.parametrize("name", RECORDS)
def test_the_best_reads_no_worse_than_the_lookup_nor_a_line_that_holds_as_well(
    name: str,
) -> None:
    cal, _ = calibrated(name)
    rms = cal.force_rms()
    assert all(math.isfinite(v) for v in rms.values()), rms
    best = cal.best
    lookup, line = cal.score("lookup"), cal.score("line")
    assert lookup is not None and line is not None

    def drifts_more(s: Score, than: Score) -> bool:
        return any(
            math.isfinite(mine) and math.isfinite(ref) and mine > ref
            for mine, ref in zip(s.drift.all_pct_fs, than.drift.all_pct_fs, strict=True)
        )

    assert rms[best] <= rms["lookup"]
    # the line is beaten on held-out force unless its holds drift more than the lookup's
    assert rms[best] <= rms["line"] or drifts_more(line, lookup)
    # the best of what may be written: the lookup, every other static calibration whose holds drift
    # no more than the lookup's, and the dynamic ones whose holds drift no more than the best
    # static rival's and the lookup's, in both groups
    writable = {s.name for s in cal.writable()}
    rival = cal.best_static()
    assert rival is not None
    for s in cal.scores:
        references = [lookup, rival] if s.dynamic else [lookup]
        held = s.name == "lookup" or not any(drifts_more(s, r) for r in references)
        assert (s.name in writable) == held, s.name
    assert rms[best] == min(rms[n] for n in writable)
    assert cal.candidates, "no curve candidate was fitted"
    # the best candidate is the first, and each one's RMS is what its tracked force reads
    assert cal.candidates[0].held_out_force_rms_n == min(c.held_out_force_rms_n for c in cal.candidates)
    for c in cal.candidates:
        assert rms[c.name] == c.held_out_force_rms_n


@pytest.mark.parametrize("name", RECORDS)
def test_the_ranking_is_sorted_and_holds_every_calibration(name: str) -> None:
    cal, _ = calibrated(name)
    ranking = cal.as_dict()["ranking"]
    names = [row["name"] for row in ranking]
    assert len(names) == len(set(names))
    assert {"physics", "line", "lookup"} <= set(names)
    assert {c.name for c in cal.candidates} <= set(names)
    assert set(names) == {"physics", "line", "lookup"} | {c.name for c in cal.candidates}
    rms = [row["held_out_force_rms_n"] for row in ranking]
    assert rms == sorted(rms)
    assert cal.as_dict()["best"] == cal.best == next(row["name"] for row in ranking if row["writable"])
    for row in ranking:
        assert row["parameters"] >= 2
        drift = row["hold_drift_pct_fs"]
        assert drift is None or (math.isfinite(drift) and drift >= 0.0)
    # these records have no real time: no candidate with creep (a time constant) is ranked
    kinds = {c.kind for c in cal.candidates}
    assert kinds <= set(CURVE_KINDS) and "power_law" in kinds
    assert not any(DRIFT_FORMS[c.drift_form].time_driven for c in cal.candidates)


def _winner_table(text: str, channel: str) -> tuple[str, dict[str, object]] | None:
    """The one rival table a calibration file gives the channel: (kind, table), or None."""
    data = tomllib.loads(text)
    found = [
        (kind, data[kind][channel]) for kind in ("line", "lookup", "curve") if channel in data.get(kind, {})
    ]
    assert len(found) <= 1, found
    return found[0] if found else None


def _same_curve(cand: Candidate, table: dict[str, object], data: FitData) -> None:
    loaded = curve_from_table(table)
    assert loaded.curve == cand.channel.curve
    assert loaded.drift == cand.channel.drift
    assert (loaded.gain, loaded.offset_n) == (cand.channel.gain, cand.channel.offset_n)
    assert table["held_out_force_rms_n"] == cand.held_out_force_rms_n
    # the channel the file gives reads the record exactly as the candidate was scored
    force, _ = track_series(loaded, data.resistance_ohm, data.time_s)
    np.testing.assert_array_equal(force, cand.force_n)


@pytest.mark.parametrize("name", RECORDS)
def test_the_auto_file_reads_back_as_the_winner(name: str) -> None:
    cal, data = calibrated(name)
    text = calibration_toml([cal], model="auto")
    parsed = tomllib.loads(text)
    assert cal.channel in parsed["channel"]
    found = _winner_table(text, cal.channel)
    best = cal.best
    if best == "physics":
        assert found is None
    elif best in ("line", "lookup"):
        assert found is not None and found[0] == best
        assert found[1]["held_out_force_rms_n"] == cal.force_rms()[best]
    else:
        cand = cal.candidate(best)
        assert cand is not None and found is not None and found[0] == "curve"
        assert found[1]["kind"] == cand.kind
        _same_curve(cand, found[1], data)


@pytest.mark.parametrize("name", RECORDS)
def test_the_curve_file_reads_back_as_the_best_candidate(name: str) -> None:
    cal, data = calibrated(name)
    found = _winner_table(calibration_toml([cal], model="curve"), cal.channel)
    assert found is not None and found[0] == "curve"
    # the best writable curve (``--model curve``), read back exactly as it was scored
    curves = {c.name: c for c in cal.candidates}
    name = next(s.name for s in cal.writable() if s.name in curves)
    _same_curve(curves[name], found[1], data)
