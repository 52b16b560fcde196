"""Wiring the simulated array to the gateway: the one place the two meet.

The simulator (``sim_device``) is an independent witness with its own parameter type; what
the two share is the contract's parameter names (``docs/parameters.md``). A channel's true
parameters become the gateway's ``SensorParams`` through those names.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from ..model import SensorParams


class _TrueParams(Protocol):
    def as_dict(self) -> dict[str, float]: ...


def gateway_params(true_params: Sequence[_TrueParams]) -> list[SensorParams]:
    """The gateway's parameters of each simulated channel, by the contract's names."""
    return [SensorParams.from_mapping(p.as_dict()) for p in true_params]
