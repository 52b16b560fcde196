"""Wiring the simulated array to the gateway: the one place the two meet.

The simulator (``sim_device``) is an independent witness with its own parameter type; what
the two share is the contract's parameter names (``docs/parameters.md``). A channel's true
parameters become the gateway's ``SensorParams`` through those names.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Protocol

from ..model import SensorParams


class _TrueParams(Protocol):
    def as_dict(self) -> dict[str, float]: ...


def gateway_params(true_params: Sequence[_TrueParams]) -> list[SensorParams]:
    """The gateway's parameters of each simulated channel, by the contract's names."""
    return [SensorParams.from_mapping(p.as_dict()) for p in true_params]


class PacedClock:
    """A wall clock (s) for a simulated array that must not outrun the gateway recording it.

    The array's device time is ``speed x (clock() - start)`` and the array calls its clock
    whenever a register read advances it. This clock follows ``time.monotonic`` but gives out
    at most ``max_step_s`` per call: when a busy machine delays the gateway's polls, the
    simulated device slows down for that gap instead of letting more than
    ``max_step_s x speed`` device seconds pass between two reads. Time not given out is not
    made up later: the device runs behind the wall clock, as a simulation whose real-time
    factor drops under load.
    """

    def __init__(self, max_step_s: float, wall: Callable[[], float] = time.monotonic) -> None:
        if not (math.isfinite(max_step_s) and max_step_s > 0.0):
            raise ValueError(f"max_step_s must be a finite number > 0, got {max_step_s!r}")
        self._max_step_s = max_step_s
        self._wall = wall
        self._wall_last = wall()
        self._paced = self._wall_last

    def __call__(self) -> float:
        now = self._wall()
        self._paced += min(max(now - self._wall_last, 0.0), self._max_step_s)
        self._wall_last = now
        return self._paced
