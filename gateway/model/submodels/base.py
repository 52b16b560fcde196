"""What a submodel is: one named effect of the sensor model, in an "on" and an "off" form.

Every effect of ``docs/record-format.md`` is a module here with two classes: the effect and
its null variant (``No...``), which adds nothing (zero resistance, zero strain, an infinite
parallel path, a unit factor), so switching an effect off reduces the model exactly to the
model without it. The two are siblings, as PyBaMM's ``no_convection`` is of its full model:
both subclass the effect's kind below (``SeriesTerm``, ``ParallelPath``, ``Factor``,
``StrainState``), whose defaults are the null behaviour; the null variant never subclasses
the effect only to override its methods back. ``gateway.model.effects.EFFECTS`` is the
table of both forms; adding an effect is one new module and one row there.

Kinds of effect, by what they change (SI units, arrays over N channels):

* ``SeriesTerm``: a resistance in series with the polymer, R_term(F) with its log-slope;
* ``ParallelPath``: a resistance in parallel with everything;
* ``Factor``: a factor on the polymer resistance (temperature);
* ``StrainState``: a strain added to the polymer's, carried as state between samples
  (creep, creep2, hysteresis): it relaxes over time with the force held, records each new
  force, runs over a whole series at once, and has the closed form of a step held from t = 0.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..params import ChannelParams
from ..state import ModelState

FloatArray = NDArray[np.float64]
StateChanges = dict[str, FloatArray]


class Submodel:
    """One effect for N channels; ``active`` is False for the null variant."""

    effect: ClassVar[str]
    active: ClassVar[bool] = True
    description: ClassVar[str]
    #: the sensor parameters this effect brings into a fit
    parameters: ClassVar[tuple[str, ...]] = ()

    def __init__(self, params: ChannelParams) -> None:
        self.params = params


class SeriesTerm(Submodel):
    """A resistance in series with the polymer (ohm); its ``coefficient`` is per channel."""

    #: 0 (contact: k / sqrt(F)), or 1 for a constant resistance
    coefficient: FloatArray


class ParallelPath(Submodel):
    """A resistance in parallel with the sensor (ohm, +inf when there is none)."""

    ohm: FloatArray


class Factor(Submodel):
    """A factor on the polymer resistance, from the sensor temperature (degC)."""

    def factor(self, temperature_c: ArrayLike | None) -> FloatArray | float:
        return 1.0


class StrainState(Submodel):
    """A strain added to the polymer's, carried between samples in ``ModelState`` fields.

    The null variant adds no strain and changes no state. ``held`` forces are those held
    over an interval (the previous sample's, >= 0), ``dt_s`` its length in s.
    """

    #: the ``ModelState`` fields this effect owns, and its name in ``ResistanceBreakdown``
    fields: ClassVar[tuple[str, ...]] = ()
    term: ClassVar[str]
    #: every ``ChannelParams`` field that ``state_series`` reads: equal values give the same
    #: series (``ForceSeries`` reuses it; a field missing here would reuse a stale one)
    series_parameters: ClassVar[tuple[str, ...]] = ()

    def strain(self, state: ModelState) -> FloatArray | None:
        """The strain this effect adds in ``state`` (None: none)."""
        return None

    def relax(self, state: ModelState, held_n: FloatArray, dt_s: ArrayLike) -> StateChanges:
        """The owned fields after ``dt_s`` seconds with ``held_n`` applied."""
        return {}

    def record(self, state: ModelState, force_n: FloatArray) -> StateChanges:
        """The owned fields after ``force_n`` (>= 0) becomes the held force."""
        return {}

    def series(
        self, force_n: FloatArray, held_n: FloatArray, dt_s: FloatArray, state0: ModelState
    ) -> tuple[FloatArray | None, StateChanges]:
        """Over a series (T, N): the strain before each sample (relaxed, not yet recording
        it), and the owned fields at the end (after the last sample's relax for time-driven
        state, after its record for force-driven state)."""
        path, end = self.state_series(force_n, held_n, dt_s, state0)
        return (None if path is None else self.path_strain(path)), end

    def state_series(
        self, force_n: FloatArray, held_n: FloatArray, dt_s: FloatArray, state0: ModelState
    ) -> tuple[FloatArray | None, StateChanges]:
        """``series`` before its last step: the state variable the strain is made of, before
        each sample (None: none), and the owned fields at the end. The costly part; it reads
        the parameters of ``series_parameters`` only."""
        return None, {}

    def path_strain(self, path: FloatArray) -> FloatArray:
        """The strain from ``state_series``'s path, as ``strain`` makes it from a state (by
        default the path is the strain)."""
        return path

    def held_step(self, force_n: FloatArray, time_s: FloatArray) -> FloatArray | None:
        """The strain ``time_s`` after a step to ``force_n`` from rest (None: none)."""
        return None


def zeros_like(params: ChannelParams) -> FloatArray:
    """0.0 per channel."""
    return np.zeros(params.r0_ohm.shape)
