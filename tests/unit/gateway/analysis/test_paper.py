"""``analysis.paper.fit_hold``: eq. 17 fitted to one creep test, robust to the reading taken
across the load step."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.analysis.paper import fit_hold
from gateway.analysis.records import ChannelRecord
from gateway.model import PAPER_EFFECTS, SensorModel, SensorParams


def _creep_record(level_n: float, torn: bool) -> ChannelRecord:
    """0 N, then ``level_n`` held for 20 minutes, sampled every 10 s (the paper replay's 400x
    clock); the step at t = 20.5 s. With ``torn`` the sample at 20 s reads the reference
    already at the level but the resistance from before the step (open), as a poll whose
    force block is read after the step and its counts before does."""
    params = SensorParams()
    t = np.arange(0.0, 1220.0, 10.0)
    step = 20.5
    force = np.where(t > step, level_n, 0.0)
    held = SensorModel(PAPER_EFFECTS, params).held_step(np.full(t.size, level_n), np.maximum(t - step, 0.0))
    r = np.where(t > step, held.total_ohm, np.inf)
    if torn:
        first = int(np.flatnonzero(t > step)[0])
        force[first - 1] = level_n  # the sample at 10 s: reference after the step, counts before
    return ChannelRecord("0", t, r, force, None, np.arange(t.size, dtype=np.int64))


@pytest.mark.parametrize("torn", [False, True])
def test_the_hold_fit_recovers_the_spec_moduli_even_with_a_torn_first_reading(torn: bool) -> None:
    """docs/parameters.md: E0 = e0_pa + slope * F at the level (constant within the hold)."""
    params = SensorParams()
    level = 6.0
    fit = fit_hold(_creep_record(level, torn), level, params)
    e0_true = params.e0_pa + params.e0_slope_pa_per_n * level
    e1_true = params.e1_pa + params.e1_slope_pa_per_n * level
    assert fit.e0_pa == pytest.approx(e0_true, rel=0.02)
    assert fit.e1_pa == pytest.approx(e1_true, rel=0.05)
    assert np.all(np.isfinite(fit.resistance_ohm))
