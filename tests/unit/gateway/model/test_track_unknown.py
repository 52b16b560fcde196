"""Tracking with a channel whose reading stays invalid (a special code, a fault: NaN ohm): it
stays unknown and holds no force, the other channels read exactly what they read without it,
and it costs no equilibrium sweep on every sample (a 1,062-taxel hand with one such taxel took
17 ms a poll instead of 6)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.model import SensorModel, SensorParams


def test_an_invalid_channel_stays_unknown_without_a_sweep_per_sample(monkeypatch: pytest.MonkeyPatch) -> None:
    model = SensorModel("tunneling,contact,creep", [SensorParams()] * 3)
    alone = SensorModel("tunneling,contact,creep", [SensorParams()] * 2)
    forces = np.array([0.5, 2.0])
    r_good = alone.resistance(forces)
    state, state_alone = model.unknown_state(), alone.unknown_state()
    sweeps = []
    real = SensorModel.equilibrium_state

    def counted(self: SensorModel, *args: object, **kwargs: object) -> object:
        sweeps.append(1)
        return real(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(SensorModel, "equilibrium_state", counted)
    for _ in range(5):
        inv, state = model.track(np.array([r_good[0], np.nan, r_good[1]]), state, 0.1)
        inv_alone, state_alone = alone.track(r_good, state_alone, 0.1)
        assert np.isnan(inv.force_n[1]) and np.isnan(state.last_force_n[1])
        assert np.array_equal(inv.force_n[[0, 2]], inv_alone.force_n)
    # one sweep each: the first sample starts the readable channels, none after
    assert len(sweeps) == 2
    assert np.all(inv.force_n[[0, 2]] > 0.0)
