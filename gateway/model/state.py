"""The per-channel state a sensor model carries from one sample to the next.

Each state-carrying effect owns its fields (``creep``: ``kv1_strain``; ``creep2``:
``kv2_strain``; ``hysteresis``: ``play_n`` and ``direction``); ``last_force_n`` is the
force held since the last sample (N). Strains are dimensionless, forces in N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ModelState:
    """Per-channel state carried between samples (arrays of shape (N,))."""

    kv1_strain: FloatArray
    kv2_strain: FloatArray
    play_n: FloatArray  # hysteresis dead-band play output, N
    direction: FloatArray  # hysteresis load direction in [-1, 1]
    last_force_n: FloatArray

    @classmethod
    def zeros(cls, n_channels: int) -> ModelState:
        z = np.zeros(n_channels)
        return cls(z, z.copy(), z.copy(), z.copy(), z.copy())

    def select(self, index: ArrayLike) -> ModelState:
        """The state of a subset of channels."""
        idx = np.asarray(index)
        return ModelState(
            self.kv1_strain[idx],
            self.kv2_strain[idx],
            self.play_n[idx],
            self.direction[idx],
            self.last_force_n[idx],
        )

    def updated(self, changes: dict[str, FloatArray]) -> ModelState:
        """A state with some fields replaced (the fields an effect owns)."""
        if not changes:
            return self
        get = changes.get
        return ModelState(
            get("kv1_strain", self.kv1_strain),
            get("kv2_strain", self.kv2_strain),
            get("play_n", self.play_n),
            get("direction", self.direction),
            get("last_force_n", self.last_force_n),
        )
