"""``leakage``: a constant resistance in parallel (surface leakage), in ohm.

R = R_core || R_leak = R_core R_leak / (R_core + R_leak): it caps the unloaded resistance at
R_leak (an unloaded sensor reads R_leak instead of open) and scales the slope by
(R_leak / (R_core + R_leak))^2. The null variant is an infinite parallel path.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..params import ChannelParams
from .base import ParallelPath


class Leakage(ParallelPath):
    effect: ClassVar[str] = "leakage"
    description: ClassVar[str] = "a constant resistance in parallel that caps the unloaded resistance"
    parameters: ClassVar[tuple[str, ...]] = ("leakage_resistance_ohm",)

    def __init__(self, params: ChannelParams) -> None:
        super().__init__(params)
        self.ohm = params.leakage_resistance_ohm


class NoLeakage(ParallelPath):
    """``leakage`` switched off: an infinite parallel path (a sibling of ``Leakage``)."""

    effect: ClassVar[str] = Leakage.effect
    active: ClassVar[bool] = False
    description: ClassVar[str] = Leakage.description
    parameters: ClassVar[tuple[str, ...]] = Leakage.parameters

    def __init__(self, params: ChannelParams) -> None:
        super().__init__(params)
        self.ohm = np.full(params.r0_ohm.shape, np.inf)
