"""A force history the forward model is driven with, and what of it the parameters do not change.

``SensorModel.simulate`` drives the model with forces (T, N) at times (T,) from a state. A fit
drives it with one history for thousands of parameter sets, most of which differ from an
earlier one in one or two parameters only (a finite-difference Jacobian moves one at a time).
``ForceSeries`` holds the history as the model reads it (forces >= 0, the force held before
each sample, the time steps, the contact term's sqrt F) and remembers the last few strain
series of each state-carrying effect by the values of the parameters that series reads
(``StrainState.series_parameters``): a parameter set that changes, say, only R0, the
contact's resistivity or the hysteresis strain reuses the creep series and the hysteresis's
load direction instead of solving them again. The terms that depend on the force alone (the
elastic strain, the contacts' k / sqrt F) are kept the same way, by the arrays they are made
of. A reused array is the very one a new computation would give, so the resistance is the
same bit for bit.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .state import ModelState
from .submodels.base import StateChanges, StrainState

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: strain series remembered per history: the base point of a Jacobian, and the columns that move it
KEPT_SERIES = 4


class ForceSeries:
    """A load history of N channels: ``force_n`` (T, N) >= 0 N, ``dt_s`` (T,) the time in s
    from the previous sample (from the state's time for the first), and the state before it."""

    def __init__(self, force_n: FloatArray, dt_s: FloatArray, state0: ModelState) -> None:
        self.force_n = force_n
        self.state0 = state0
        #: the force held over the interval before each sample (the previous one, >= 0)
        self.held_n = np.maximum(np.vstack([state0.last_force_n[None, :], force_n[:-1]]), 0.0)
        self.dt_s = np.broadcast_to(dt_s.reshape(-1, 1), force_n.shape)
        self._root: tuple[BoolArray, FloatArray] | None = None
        self._terms: dict[tuple[object, ...], FloatArray] = {}
        self._solved: OrderedDict[tuple[object, ...], tuple[FloatArray | None, StateChanges]] = OrderedDict()

    @classmethod
    def of(
        cls,
        force_n: ArrayLike,
        time_s: ArrayLike,
        n_channels: int,
        state0: ModelState | None = None,
        t0_s: float | None = None,
    ) -> ForceSeries:
        """A history as ``SensorModel.simulate`` reads its arguments: forces (T, N) or (T,)
        clamped at 0 N, broadcast to ``n_channels``; times (T,) in s, the first step from
        ``t0_s`` (default: the first sample time); ``state0`` (default: unloaded, at rest)."""
        f = np.maximum(np.atleast_2d(np.asarray(force_n, dtype=np.float64)), 0.0)
        f = np.broadcast_to(f, (f.shape[0], n_channels)).copy()
        t = np.asarray(time_s, dtype=np.float64).reshape(-1)
        dt = np.diff(t, prepend=t[0] if t0_s is None else t0_s)
        return cls(f, dt, state0 or ModelState.zeros(n_channels))

    def contact_root(self) -> tuple[BoolArray, FloatArray]:
        """F > 0, and sqrt(F) there (1 elsewhere): what the contact term k / sqrt(F) divides by."""
        if self._root is None:
            positive = self.force_n > 0.0
            self._root = positive, np.sqrt(np.where(positive, self.force_n, 1.0))
        return self._root

    def term(self, key: tuple[str | FloatArray, ...], make: Callable[[], FloatArray]) -> FloatArray:
        """A term of the resistance that depends on the force and on the arrays in ``key`` alone
        (``key[0]`` names the term): ``make()``, or what it gave for equal arrays among the
        last few terms. Shared: callers must not write into it."""
        full = tuple(k.tobytes() if isinstance(k, np.ndarray) else k for k in key)
        found = self._terms.pop(full, None)
        if found is None:
            found = make()
        self._terms[full] = found
        if len(self._terms) > 2 * KEPT_SERIES:
            del self._terms[next(iter(self._terms))]
        return found

    def solve(self, effect: StrainState) -> tuple[FloatArray | None, StateChanges]:
        """``effect.series`` over this history: its strain before each sample and its fields at
        the end. Its ``state_series`` is reused when the parameters it reads have not changed
        since one of the last ``KEPT_SERIES`` solves. The arrays may be shared: callers must not
        write into them."""
        p = effect.params
        key = (type(effect), *(getattr(p, name).tobytes() for name in effect.series_parameters))
        found = self._solved.pop(key, None)
        if found is None:
            found = effect.state_series(self.force_n, self.held_n, self.dt_s, self.state0)
        self._solved[key] = found
        if len(self._solved) > KEPT_SERIES:
            self._solved.popitem(last=False)
        path, end = found
        return (None if path is None else effect.path_strain(path)), end
