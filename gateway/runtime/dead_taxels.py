"""Dead taxels: a taxel frozen while its region's other taxels move.

A taxel whose raw value stays exactly the same (at a rail or anywhere: a converter that no
longer updates it, a broken trace read as 0) while the other taxels of its region keep
changing is dead once it has been frozen for ``dead_after_s`` seconds, provided its region
changed at least ``MIN_NEIGHBOUR_MOVES`` times since it froze, the last time within half of
``dead_after_s`` (so whatever the poll rate against the device's refresh rate). A region
whose taxels are all still (nothing touches it, a noise-free idle reading) has no dead
taxel: a whole dead region cannot be told from an idle one. A dead taxel is alive again as
soon as its value changes.

Per poll the work is a handful of vectorised numpy operations on the channel arrays (one
comparison, one ``bincount`` over the regions, a few ``where``): tens of microseconds for a
1,062-taxel hand (``bench/bench_gateway.py``). The tracker is configuration; its state is
immutable and carried from poll to poll by the device's conversion state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ..config import DeviceConfig
from ..config.limits import DEFAULT_DEAD_AFTER_S
from ..modbus.image import RawSample

__all__ = [
    "DEFAULT_DEAD_AFTER_S",
    "MIN_NEIGHBOUR_MOVES",
    "NO_COUNTS",
    "DeadState",
    "DeadTaxelTracker",
    "tracker_for",
]

#: A frozen taxel's region must have changed at least this many polls since it froze, the
#: last within half of ``dead_after_s``: neighbours that moved once, long ago, do not make a
#: still taxel dead.
MIN_NEIGHBOUR_MOVES: Final = 3

#: Dead taxels by region of a device that tracks none.
NO_COUNTS: Final[tuple[tuple[str, int], ...]] = ()

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class DeadState:
    """What the tracker carries between polls (one entry per tracked channel): the last
    value, when it last changed (s) and the region's moving-poll count then; per region the
    polls in which some taxel changed and when one last did (s)."""

    last: FloatArray
    still_since_s: FloatArray
    moving_at_change: IntArray
    region_moving: IntArray
    region_moved_s: FloatArray
    polls: int = 0


class DeadTaxelTracker:
    """Finds dead taxels among channels grouped in regions (module docstring).

    ``region_of`` gives each tracked channel's region (an index into ``region_names``)."""

    def __init__(
        self, region_of: NDArray[np.intp], region_names: tuple[str, ...], dead_after_s: float
    ) -> None:
        if not dead_after_s > 0.0:
            raise ValueError(f"dead_after_s = {dead_after_s!r} must be > 0 s")
        self.region_of = np.asarray(region_of, dtype=np.intp)
        self.region_of.setflags(write=False)
        self.region_names = region_names
        self.dead_after_s = float(dead_after_s)
        self._n_regions = len(region_names)
        # the regions are runs of channels in order (as a device's regions are): per-region
        # sums are ``reduceat`` over the runs' starts, without a scatter
        present = np.unique(self.region_of)
        self._runs = bool(np.all(np.diff(self.region_of) >= 0))
        self._present = present
        self._starts = np.searchsorted(self.region_of, present)

    def initial_state(self, n: int) -> DeadState:
        return DeadState(
            np.full(n, np.nan),
            np.full(n, np.nan),
            np.zeros(n, dtype=np.int64),
            np.zeros(self._n_regions, dtype=np.int64),
            np.full(self._n_regions, np.nan),
        )

    def update(
        self, state: DeadState, values: NDArray[np.generic], now_s: float
    ) -> tuple[DeadState, BoolArray]:
        """The state after a poll of raw ``values`` at ``now_s`` (s, monotonic), and which
        channels are dead. The first poll only records the values."""
        v = np.asarray(values, dtype=np.float64)
        changed = v != state.last  # NaN (the first poll) compares unequal: everything "changed"
        polls = state.polls + 1
        moved = np.zeros(self._n_regions, dtype=np.int64)
        if len(v) == 0:
            pass
        elif self._runs:
            moved[self._present] = np.logical_or.reduceat(changed, self._starts)
        else:
            moved[np.unique(self.region_of[changed])] = 1
        region_moving = state.region_moving + moved
        region_moved_s = np.where(moved > 0, now_s, state.region_moved_s)
        # the region's moving polls since each channel last changed, counted by its neighbours
        still_since = np.where(changed, now_s, state.still_since_s)
        moving_now = region_moving[self.region_of]
        moving_at = np.where(changed, moving_now, state.moving_at_change)
        new = DeadState(v, still_since, moving_at, region_moving, region_moved_s, polls)
        if state.polls == 0:
            return new, np.zeros(len(v), dtype=np.bool_)
        lively = (now_s - region_moved_s) <= self.dead_after_s / 2.0  # a region that moves lately
        dead = (now_s - still_since >= self.dead_after_s) & (moving_now - moving_at >= MIN_NEIGHBOUR_MOVES)
        return new, dead & lively[self.region_of]

    def step(
        self, state: DeadState | None, raw: RawSample, pick: slice | NDArray[np.int64], now_s: float | None
    ) -> tuple[DeadState, BoolArray, tuple[tuple[str, int], ...]]:
        """``update`` on a poll's raw values (counts, resistances or the device's own output) of
        the tracked channels ``pick``, with the dead taxels counted by region."""
        values = next(
            v
            for v in (raw.counts, raw.resistance_ohm, raw.output_force_n, raw.output_pressure_kpa)
            if v is not None
        )[pick]
        start = state or self.initial_state(len(self.region_of))
        new, dead = self.update(start, values, 0.0 if now_s is None else now_s)
        return new, dead, tuple(self.counts(dead).items())

    def counts(self, dead: BoolArray) -> dict[str, int]:
        """Dead taxels per region name (every region, 0 included)."""
        per = np.bincount(self.region_of[dead], minlength=self._n_regions)
        return {name: int(c) for name, c in zip(self.region_names, per, strict=True)}


def tracker_for(device: DeviceConfig, index: NDArray[np.int64]) -> DeadTaxelTracker | None:
    """The tracker of a device's enabled channels ``index``, by region (a device without
    regions is one region, ``all``); None when the device tracks none (``dead_after_s = 0``)."""
    if not device.dead_after_s > 0.0:
        return None
    if not device.regions:
        return DeadTaxelTracker(np.zeros(len(index), dtype=np.intp), ("all",), device.dead_after_s)
    region_of = np.empty(device.n_channels, dtype=np.intp)
    for k, region in enumerate(device.regions):
        region_of[region.channel_slice] = k
    names = tuple(r.name for r in device.regions)
    return DeadTaxelTracker(region_of[index], names, device.dead_after_s)
