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

``hold_drifts`` is the one per-hold measure of a force read against the reference, used by
``apply``'s report and ``calibrate``'s ranking alike: per hold, its settled rows (``Hold.settled``)
within the rows measured, the mean error over their first and last 10 %, the change between
them, and whether the hold comes *right after a higher load* (the reference rose more than
twice the tolerance above the hold's level since the previous hold began): where a sensor's
recovery shows. ``drift_groups_pct`` sums them up in the two groups a user feels apart.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "EDGE_FRACTION",
    "EDGE_GUARD_S",
    "HOLD_TOLERANCE_FS",
    "MIN_HOLD_S",
    "DriftGroups",
    "Hold",
    "HoldDrift",
    "drift_groups_pct",
    "find_holds",
    "hold_drifts",
    "hold_tolerance_n",
]

#: The shortest hold, s (first row to last row).
MIN_HOLD_S: Final = 3.0
#: The default tolerance about a hold's level, as a fraction of the full scale.
HOLD_TOLERANCE_FS: Final = 0.02
#: The part of a hold's rows at its start and at its end that ``Hold.edges`` gives.
EDGE_FRACTION: Final = 0.1
#: ``hold_drifts`` leaves out this long at each end of a hold (s): a reference interpolated onto
#: the meter's times lags the resistance (about 0.4 s on the real FSR bench records), so the
#: sensor has already left a hold's load while the reference still reads it.
EDGE_GUARD_S: Final = 0.5


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


@dataclass(frozen=True)
class HoldDrift:
    """One hold's error drift (N): the mean error (force - reference) over the first and the
    last ``EDGE_FRACTION`` of its measured settled rows, and the change between them."""

    hold: Hold
    after_higher: bool
    start_error_n: float
    end_error_n: float

    @property
    def change_n(self) -> float:
        return self.end_error_n - self.start_error_n


def _mean(values: NDArray[np.float64]) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else math.nan


def hold_drifts(
    time_s: ArrayLike,
    reference_n: ArrayLike,
    force_n: ArrayLike,
    rows: ArrayLike | None = None,
    holds: tuple[Hold, ...] | None = None,
    tolerance_n: float | None = None,
) -> tuple[HoldDrift, ...]:
    """Every hold's drift (module docstring) measured on ``rows`` (default: all): a hold is
    cut to its settled rows, then to its longest run of measured rows, which must last
    ``MIN_HOLD_S``, less ``EDGE_GUARD_S`` at each end. ``holds``: the reference's holds when
    already found."""
    t = np.asarray(time_s, dtype=np.float64)
    ref = np.asarray(reference_n, dtype=np.float64)
    err = np.asarray(force_n, dtype=np.float64) - ref
    measured = np.ones(t.size, dtype=np.bool_) if rows is None else np.asarray(rows, dtype=np.bool_)
    tol = hold_tolerance_n(ref) if tolerance_n is None else tolerance_n
    found = find_holds(t, ref, tol) if holds is None else holds
    out: list[HoldDrift] = []
    previous_start = 0
    for h in found:
        before = ref[previous_start : h.start]
        before = before[np.isfinite(before)]
        after_higher = bool(before.size and before.max() > h.level_n + 2.0 * tol)
        previous_start = h.start
        s = h.settled(ref, tol)
        inside = measured[s.start : s.stop]
        if not inside.any():
            continue
        # the longest run of measured rows within the settled hold
        edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
        starts, stops = edges[::2], edges[1::2]
        k = int(np.argmax(stops - starts))
        a, b = s.start + int(starts[k]), s.start + int(stops[k])
        if t[b - 1] - t[a] < MIN_HOLD_S:
            continue
        inner = np.flatnonzero((t[a:b] >= t[a] + EDGE_GUARD_S) & (t[a:b] <= t[b - 1] - EDGE_GUARD_S))
        if inner.size < 2:
            continue
        a, b = a + int(inner[0]), a + int(inner[-1]) + 1
        part = Hold(a, b, float(t[a]), float(t[b - 1]), s.level_n)
        first, last = part.edges()
        out.append(HoldDrift(part, after_higher, _mean(err[first]), _mean(err[last])))
    return tuple(out)


@dataclass(frozen=True)
class DriftGroups:
    """The RMS hold drift (% of full scale) of the holds right after a higher load and of the
    others (NaN: no such hold), and how many holds each has."""

    after_higher_pct_fs: float
    others_pct_fs: float
    after_higher_holds: int
    other_holds: int

    @property
    def all_pct_fs(self) -> tuple[float, float]:
        return self.after_higher_pct_fs, self.others_pct_fs

    @property
    def worst_pct_fs(self) -> float:
        """The larger of the two groups' drifts (% FS; NaN without a hold)."""
        values = [v for v in self.all_pct_fs if math.isfinite(v)]
        return max(values) if values else math.nan


def drift_groups_pct(drifts: tuple[HoldDrift, ...], full_scale_n: float) -> DriftGroups:
    """``drifts`` in two groups: the RMS of their changes, % of ``full_scale_n``."""

    def pct(group: list[float]) -> float:
        if not group or not full_scale_n > 0:
            return math.nan
        return 100.0 * math.sqrt(sum(v * v for v in group) / len(group)) / full_scale_n

    after = [d.change_n for d in drifts if d.after_higher and math.isfinite(d.change_n)]
    others = [d.change_n for d in drifts if not d.after_higher and math.isfinite(d.change_n)]
    return DriftGroups(pct(after), pct(others), len(after), len(others))
