"""Zero: taking a channel's unloaded baseline off its readings.

A channel that reads ``R_b`` unloaded where the model expects ``R_0 = R(0 N)`` has a parallel
path of conductance ``1/R_b - 1/R_0`` (board leakage, a preloaded cell, an amplifier offset
seen as one). It is taken off every reading, so a reading at the baseline is the model's
unloaded sensor: 0 N, no contact; below it (less conductance) the same.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .snapshot import frozen_copy

__all__ = ["BaselineCorrection"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class BaselineCorrection:
    """For the channels with a baseline (``positions``): the excess conductance (S), the
    model's unloaded conductance (S) and resistance (ohm)."""

    positions: NDArray[np.intp]
    excess_s: FloatArray
    unloaded_s: FloatArray
    unloaded_ohm: FloatArray

    @classmethod
    def of(cls, baselines_ohm: Sequence[float | None], unloaded_ohm: FloatArray) -> BaselineCorrection | None:
        """From each channel's baseline (None: none) and the model's R(0 N) per channel; None
        when no channel has a baseline."""
        positions = [k for k, b in enumerate(baselines_ohm) if b is not None]
        if not positions:
            return None
        pos = np.array(positions, dtype=np.intp)
        baseline = np.array([baselines_ohm[k] for k in positions], dtype=np.float64)
        r0 = np.asarray(unloaded_ohm, dtype=np.float64)[pos]
        g0 = np.where(np.isinf(r0), 0.0, 1.0 / r0)
        with np.errstate(divide="ignore"):
            excess = np.where(np.isinf(baseline), 0.0, 1.0 / baseline) - g0
        return cls(frozen_copy(pos), frozen_copy(excess), frozen_copy(g0), frozen_copy(r0))

    def apply(self, r_model: FloatArray) -> FloatArray:
        """``r_model`` (ohm, every channel) with the excess conductance taken off; NaN stays NaN."""
        r = np.array(r_model, dtype=np.float64, copy=True)
        measured = r[self.positions]
        with np.errstate(divide="ignore", invalid="ignore"):
            g = 1.0 / measured - self.excess_s
            r[self.positions] = np.where(
                np.isnan(measured), np.nan, np.where(g > self.unloaded_s, 1.0 / g, self.unloaded_ohm)
            )
        return r
