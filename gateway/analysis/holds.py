"""Holds of a reference force: runs of rows where the load stays at one level.

A hold is a run of consecutive rows whose reference force spans at most twice the tolerance
(every row within the tolerance of the run's mid-range level), whose level lies more than the
tolerance above 0 N (a loaded hold, never the unloaded sensor's noise about zero) and that
lasts at least ``MIN_HOLD_S`` from its first row to its last. Runs are taken greedily from
the start of the record, each as long as it goes; a row that is not a finite number ends a
run. The default tolerance is ``HOLD_TOLERANCE_FS`` of the record's full scale (its largest
reference force): a ramp slower than 2 x tolerance per ``MIN_HOLD_S`` therefore reads as a
hold, which it is to within the tolerance.

``Hold.edges`` gives the first and the last 10 % of a hold's rows (at least one row each):
where creep drift shows as the difference between the start and the end of a hold.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Final

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["EDGE_FRACTION", "HOLD_TOLERANCE_FS", "MIN_HOLD_S", "Hold", "find_holds", "hold_tolerance_n"]

#: The shortest hold, s (first row to last row).
MIN_HOLD_S: Final = 3.0
#: The default tolerance about a hold's level, as a fraction of the full scale.
HOLD_TOLERANCE_FS: Final = 0.02
#: The part of a hold's rows at its start and at its end that ``Hold.edges`` gives.
EDGE_FRACTION: Final = 0.1


@dataclass(frozen=True)
class Hold:
    """Rows ``start`` to ``stop - 1`` of a record (times in s, level in N: the mean reference
    force over the hold's rows)."""

    start: int
    stop: int
    start_s: float
    end_s: float
    level_n: float

    @property
    def n_rows(self) -> int:
        return self.stop - self.start

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def edge_rows(self, fraction: float = EDGE_FRACTION) -> int:
        """Rows in each edge: ``fraction`` of the hold's rows, rounded down, at least one."""
        return max(1, math.floor(fraction * self.n_rows + 1e-9))

    def settled(self, force_n: ArrayLike, tolerance_n: float) -> Hold:
        """The hold without its leading and trailing rows more than half ``tolerance_n`` off
        its level (the end of the ramp into it, the start of the ramp out of it), whose
        errors are those of a moving load; itself when nothing is left."""
        f = np.asarray(force_n, dtype=np.float64)[self.start : self.stop]
        near = np.flatnonzero(np.abs(f - self.level_n) <= 0.5 * tolerance_n)
        if near.size < 2:
            return self
        first, last = int(near[0]), int(near[-1])
        return replace(self, start=self.start + first, stop=self.start + last + 1)

    def edges(self, fraction: float = EDGE_FRACTION) -> tuple[slice, slice]:
        """The rows of the first and of the last ``fraction`` of the hold (record indices)."""
        k = self.edge_rows(fraction)
        return slice(self.start, self.start + k), slice(self.stop - k, self.stop)


def hold_tolerance_n(force_n: ArrayLike, fraction: float = HOLD_TOLERANCE_FS) -> float:
    """The default tolerance: ``fraction`` of the largest finite force (0 without one), N."""
    f = np.asarray(force_n, dtype=np.float64)
    finite = f[np.isfinite(f)]
    return float(fraction * finite.max()) if finite.size else 0.0


def find_holds(
    time_s: ArrayLike,
    force_n: ArrayLike,
    tolerance_n: float | None = None,
    min_duration_s: float = MIN_HOLD_S,
) -> tuple[Hold, ...]:
    """The holds of a reference force series (see the module docstring), in row order.

    ``time_s`` in s (a step back in time ends a run, as between two records put end to end);
    ``tolerance_n`` defaults to ``hold_tolerance_n(force_n)``.
    """
    t = np.asarray(time_s, dtype=np.float64)
    f = np.asarray(force_n, dtype=np.float64)
    if t.ndim != 1 or t.shape != f.shape:
        raise ValueError(f"time_s and force_n must be 1-D and of one length, got {t.shape} and {f.shape}")
    tol = hold_tolerance_n(f) if tolerance_n is None else float(tolerance_n)
    if not (math.isfinite(tol) and tol >= 0.0):
        raise ValueError(f"tolerance_n must be a finite number >= 0, got {tolerance_n!r}")
    if not (math.isfinite(min_duration_s) and min_duration_s >= 0.0):
        raise ValueError(f"min_duration_s must be a finite number >= 0, got {min_duration_s!r}")
    forces, times = f.tolist(), t.tolist()
    n, span = len(forces), 2.0 * tol
    holds: list[Hold] = []
    # the run [i, j) as long as it goes from i; its largest and smallest rows in monotone queues
    high: deque[int] = deque()
    low: deque[int] = deque()
    i = j = 0
    while i < n:
        while high and high[0] < i:
            high.popleft()
        while low and low[0] < i:
            low.popleft()
        while j < n:
            x = forces[j]
            if not math.isfinite(x) or (j > i and times[j] < times[j - 1]):
                break
            top = max(forces[high[0]], x) if high else x
            bottom = min(forces[low[0]], x) if low else x
            if top - bottom > span:
                break
            while high and forces[high[-1]] <= x:
                high.pop()
            high.append(j)
            while low and forces[low[-1]] >= x:
                low.pop()
            low.append(j)
            j += 1
        if j == i:  # row i is not a number: no run contains it
            i = j = i + 1
            high.clear()
            low.clear()
            continue
        level = 0.5 * (forces[high[0]] + forces[low[0]])
        if level > tol and times[j - 1] - times[i] >= min_duration_s:
            holds.append(Hold(i, j, times[i], times[j - 1], float(np.mean(f[i:j]))))
            i = j
            high.clear()
            low.clear()
        else:
            i += 1
    return tuple(holds)
