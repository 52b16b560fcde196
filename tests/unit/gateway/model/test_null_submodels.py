"""Each null submodel is a sibling of its effect, not a subclass that overrides it back.

As PyBaMM's ``no_convection`` subclasses the convection base model and not the full one,
``NoCreep`` subclasses ``StrainState`` (not ``Creep``), ``NoContact`` ``SeriesTerm``, and so
on: the base class's defaults are the null behaviour. These tests pin that structure and the
numbers it gives (zero strain and unchanged state, 0 ohm in series, an infinite parallel path,
a unit temperature factor).
"""

from __future__ import annotations

import numpy as np
import pytest

from gateway.model import EFFECTS, SensorModel, SensorParams
from gateway.model.params import ChannelParams
from gateway.model.physics import polymer_resistance_ohm
from gateway.model.state import ModelState
from gateway.model.submodels import (
    Factor,
    NoContact,
    NoCreep,
    NoCreep2,
    NoHysteresis,
    NoLeakage,
    NoSeriesResistance,
    NoTemperature,
    ParallelPath,
    SeriesTerm,
    StrainState,
    Tunneling,
)

NULLS = {name: off for name, (_, off) in EFFECTS.items() if off is not None}
FORCES_N = np.array([0.5, 1.0, 2.0, 5.0])  # hand-chosen, inside the default calibrated range


def _params(n: int = 1) -> ChannelParams:
    return ChannelParams.stack([SensorParams()] * n)


@pytest.mark.parametrize("effect", list(NULLS))
def test_a_null_variant_is_a_sibling_of_its_effect(effect: str) -> None:
    on, off = EFFECTS[effect]
    assert off is not None
    assert not issubclass(off, on), f"{off.__name__} subclasses {on.__name__}"
    assert off.__bases__ == on.__bases__  # both are children of the effect's kind
    assert off.effect == on.effect == effect and on.active and not off.active
    assert off.parameters == on.parameters and off.description == on.description


def test_the_kinds_of_the_null_variants() -> None:
    assert NoContact.__bases__ == (SeriesTerm,) and NoSeriesResistance.__bases__ == (SeriesTerm,)
    assert NoLeakage.__bases__ == (ParallelPath,) and NoTemperature.__bases__ == (Factor,)
    for null in (NoCreep, NoCreep2, NoHysteresis):
        assert null.__bases__ == (StrainState,) and null.fields == ()
        # nothing of the state machinery is redefined: the null behaviour is StrainState's own
        assert not {"strain", "relax", "record", "series", "held_step"} & set(vars(null))


def test_series_and_parallel_nulls_add_nothing() -> None:
    p = _params(3)
    assert np.array_equal(NoContact(p).coefficient, np.zeros(3))
    assert np.array_equal(NoSeriesResistance(p).coefficient, np.zeros(3))
    assert np.all(np.isposinf(NoLeakage(p).ohm)) and NoLeakage(p).ohm.shape == (3,)
    assert NoTemperature(p).factor(None) == 1.0
    assert NoTemperature(p).factor(np.array([-10.0, 25.0, 80.0])) == 1.0


@pytest.mark.parametrize("null", [NoCreep, NoCreep2, NoHysteresis])
def test_state_nulls_add_no_strain_and_change_no_state(null: type[StrainState]) -> None:
    p = _params(2)
    effect = null(p)
    state = ModelState.zeros(2)
    held = np.array([2.0, 4.0])
    assert effect.strain(state) is None
    assert effect.relax(state, held, 10.0) == {}
    assert effect.record(state, held) == {}
    forces = np.tile(FORCES_N[:, None], (1, 2))
    assert effect.series(forces, forces, np.ones_like(forces), state) == (None, {})
    assert effect.held_step(FORCES_N, np.full(4, 600.0)) is None


def test_no_creep_keeps_the_creep_state_at_zero_and_reads_the_static_tunneling_resistance() -> None:
    """The baseline model (every effect off, so ``NoCreep`` in the creep slot): a load history of
    holds at the hand-chosen forces leaves ``kv1_strain`` at zero, and every sample reads
    R0 (1 - eps) exp(-gamma s0 eps) with eps = F / (A E0 + A E0' F), whatever time it is held."""
    sp = SensorParams()
    model = SensorModel(("tunneling",), sp)
    assert isinstance(model.submodels["creep"], NoCreep) and model.state_effects == ()
    t = np.arange(0.0, 4 * 600.0, 10.0)
    force = np.repeat(FORCES_N, t.size // FORCES_N.size)[:, None]
    out, final = model.simulate(force, t)
    assert np.array_equal(final.kv1_strain, np.zeros(1))
    assert np.array_equal(final.kv2_strain, np.zeros(1)) and np.array_equal(final.direction, np.zeros(1))

    tunneling = Tunneling(_params())
    eps = FORCES_N / (sp.area_m2 * sp.e0_pa + sp.area_m2 * sp.e0_slope_pa_per_n * FORCES_N)
    by_hand = polymer_resistance_ohm(sp.r0_ohm, eps, tunneling.gamma_s0[0])
    per_sample = np.repeat(by_hand, t.size // FORCES_N.size)
    np.testing.assert_allclose(out.total_ohm[:, 0], per_sample, rtol=1e-12)
    # the same numbers with creep switched on and nothing held yet (t = 0 of each step)
    creep_on = SensorModel(("tunneling", "creep"), sp).held_step(FORCES_N[:, None], np.zeros((4, 1)))
    np.testing.assert_allclose(creep_on.total_ohm[:, 0], by_hand, rtol=1e-12)
