"""The read-out of the paper's Fig. 4b (eq. 18) and its conductance line.

The divider itself, ``Divider`` (sensor r from the supply V+ to the output node, R_ref to
ground, ``V_o = R_ref / (R_ref + r) * V+``, ``r = R_ref (V+ / V_o - 1)``), now lives with the
other read-out front ends in ``frontend``; it and ``DividerStatus`` are re-exported here so
``gateway.model.divider.Divider`` keeps working. ``ConductanceLine`` is the paper's
calibration line C = m F + n on the resistance a front end reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .frontend import Divider, DividerStatus

__all__ = ["ConductanceLine", "Divider", "DividerStatus", "FloatArray"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ConductanceLine:
    """The paper's calibration line C = m F + n (conductance C = 1/r in siemens)."""

    slope_s_per_n: float
    intercept_s: float

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """F = (1/r - n) / m; an open sensor (inf) gives F at C = 0."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.where(np.isinf(r), 0.0, 1.0 / r)
        return np.asarray((c - self.intercept_s) / self.slope_s_per_n)

    def conductance(self, force_n: ArrayLike) -> FloatArray:
        return np.asarray(self.slope_s_per_n * np.asarray(force_n, dtype=np.float64) + self.intercept_s)

    @classmethod
    def fit(cls, force_n: ArrayLike, resistance_ohm: ArrayLike) -> ConductanceLine:
        """Least-squares line through (F, 1/r) over finite, positive resistances."""
        f = np.asarray(force_n, dtype=np.float64).ravel()
        r = np.asarray(resistance_ohm, dtype=np.float64).ravel()
        use = np.isfinite(f) & np.isfinite(r) & (r > 0.0)
        if np.count_nonzero(use) < 2 or np.ptp(f[use]) == 0.0:
            raise ValueError("a conductance line needs at least two distinct forces")
        slope, intercept = np.polyfit(f[use], 1.0 / r[use], 1)
        return cls(float(slope), float(intercept))
