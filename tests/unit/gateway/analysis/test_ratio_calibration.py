"""Calibrating straight from ADC counts: a ``ratio`` front end reports r / R_ref with R_ref
unknown, so a calibration must read the same forces whatever R_ref is.

A record of the independent FSR emulator (``sim_device.fsr_emulator``: power-law sensor,
creep, hysteresis, an ohmmeter; nothing of the gateway's model) is calibrated as it is (ohm)
and with its resistance column divided by a reference, as a ratio front end on a board whose
unknown pull-up is that reference would report it. The line, the lookup and every curve with
every drift form (what ``calibration.calibrate`` ranks beside the physical model) are fitted
on both and must read the same force on every held-out row.

- R_ref = 4096 ohm (a power of two): dividing by it is exact in floating point, so any
  difference would come from a unit the fits assume; the forces agree to 1e-9 N (the
  rescaled curve parameters round at 1e-16 relative; 1e-9 N is 2e-11 of the 50 N full scale).
- R_ref = 4700 ohm: the division rounds each resistance at 1e-16 relative. The line, the
  lookup, the static curves and every lookup with drift still agree to 1e-6 N. The power law
  and the line with drift stop at ``least_squares``' tolerances (ftol = xtol = 1e-8) and their
  play switches branch at a threshold, so a rounding-level change of the input may move them
  by up to the solver's tolerance: 2e-3 N here (4e-5 of full scale, against the ~1 N the
  calibrations read held-out force to).

The physical model is not compared: its parameters are in ohm, it starts from the ohm
defaults and is bounded within a factor 1000 of them, so on relative readings it is a
different fit (docs/front-ends.md, "Ratio").
"""

from __future__ import annotations

import dataclasses
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from gateway.analysis.candidates import rank_candidates
from gateway.analysis.fit_data import FitData
from gateway.analysis.records import ChannelRecord, read_record
from gateway.analysis.rivals import Rivals
from sim_device.fsr_emulator import FsrEmulator, FsrParams, calibration_run, write_record

FloatArray = np.typing.NDArray[np.float64]


@cache
def _record(folder: Path) -> ChannelRecord:
    emu = FsrEmulator(FsrParams(), seed=3)
    path = write_record(folder / "fsr.csv", [emu.run(calibration_run(hold_s=10.0), 0)])
    return read_record(path, require_force=True).channel()


def _held_out_forces(channel: ChannelRecord, reference_ohm: float) -> dict[str, FloatArray]:
    """Every calibration's force (N) on the held-out rows, fitted on ``resistance / reference``."""
    data = FitData.from_channel(
        dataclasses.replace(channel, resistance_ohm=channel.resistance_ohm / reference_ohm)
    )
    test = data.test
    rivals = Rivals.fit(data.force_n, data.resistance_ohm, data.train, test)
    out = {c.name: c.force_n[test] for c in rank_candidates(data)}
    out["line"] = rivals.line_force_n[test]
    out["lookup"] = rivals.lookup_force_n[test]
    return out


@pytest.fixture(scope="module")
def ohm(tmp_path_factory: pytest.TempPathFactory) -> tuple[ChannelRecord, dict[str, FloatArray]]:
    channel = _record(tmp_path_factory.mktemp("ratio"))
    return channel, _held_out_forces(channel, 1.0)


def _max_difference(a: FloatArray, b: FloatArray) -> float:
    assert np.array_equal(np.isnan(a), np.isnan(b))
    return float(np.nanmax(np.abs(a - b)))


def test_every_calibration_reads_the_same_forces_in_units_of_an_exact_reference(
    ohm: tuple[ChannelRecord, dict[str, FloatArray]],
) -> None:
    channel, in_ohm = ohm
    relative = _held_out_forces(channel, 4096.0)
    # every curve kind with every drift form was fitted on both, plus the line and the lookup
    assert set(relative) == set(in_ohm) and len(in_ohm) >= 20
    assert float(np.nanmax(in_ohm["lookup"])) > 40.0  # forces in newtons: the test can fail
    for name, force in in_ohm.items():
        assert _max_difference(force, relative[name]) <= 1e-9, name


def test_every_calibration_reads_the_same_forces_in_units_of_a_4k7_pull_up(
    ohm: tuple[ChannelRecord, dict[str, FloatArray]],
) -> None:
    channel, in_ohm = ohm
    relative = _held_out_forces(channel, 4700.0)
    assert set(relative) == set(in_ohm)
    for name, force in in_ohm.items():
        drifting_fit = name.split(" + ")[0] in ("power_law", "line") and not name.endswith("static")
        tolerance = 2e-3 if drifting_fit else 1e-6
        assert _max_difference(force, relative[name]) <= tolerance, name
