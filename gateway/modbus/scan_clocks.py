"""Clock candidates of the scan (pure): 1, 2 or 4 registers read as a big-endian counter that
rises steadily with host time, its rate and unit, and the check that a "clock" is not rather
ADC channels under a ramp.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .scan_frames import _frame
from .scan_stats import _present
from .scan_types import (
    CLOCK_STEADINESS,
    CLOCK_UNITS,
    CLOCK_WIDTHS,
    MAX_CLOCK_RATE_PER_S,
    MIN_CLOCK_STEPS,
    ClockCandidate,
)


@dataclass(frozen=True)
class _Group:
    address: int
    width: int
    rate: float
    total: int
    top_zero: bool
    top_changes: bool


def _clocks(
    table: str, series: Mapping[int, list[int | None]], times: Sequence[float]
) -> list[ClockCandidate]:
    """Clock candidates of one table: for each register that could be a counter's low word
    the best reading (the widest whose top register is zero or moving: a uint64 of small
    value reads as zeros above a uint16), then no two overlapping, wider ones first
    (``analyse`` then drops those inside an ADC frame)."""
    by_low: dict[int, list[_Group]] = {}
    for width in CLOCK_WIDTHS:
        for address in series:
            group = _group(series, address, width, times)
            if group is not None:
                by_low.setdefault(address + width - 1, []).append(group)
    chosen: list[_Group] = []
    for groups in by_low.values():
        fitting = [g for g in groups if g.width == 1 or g.top_zero or g.top_changes]
        chosen.append(fitting[0] if fitting else groups[-1])
    chosen.sort(key=lambda g: (-g.width, g.address))
    taken: set[int] = set()
    accepted: list[_Group] = []
    for g in chosen:
        span = set(range(g.address, g.address + g.width))
        if not span & taken:
            accepted.append(g)
            taken |= span
    return [ClockCandidate(table, g.address, g.width, g.rate, _unit(g.rate, g.total)) for g in accepted]


def _adc_channels(clock: ClockCandidate, series: Mapping[int, list[int | None]], n_snapshots: int) -> bool:
    """Whether a rising "clock" is rather ADC channels under a steady ramp (or whose noise
    happened to rise): it lies in a run of readable registers that is an ADC frame, and
    either the registers on both sides of it make a frame without it, or it is a wider
    group whose top word moves in several intervals (a counter's upper word moves only by
    a rare carry; a ramping channel's every interval) next to a moving register."""

    def side(start: int, step: int) -> list[int]:
        found: list[int] = []
        a = start
        while a in series and _present(series[a]):
            found.append(a)
            a += step
        return found

    left, right = side(clock.address - 1, -1), side(clock.end + 1, 1)
    if not (left or right):
        return False
    run = sorted([*left, *range(clock.address, clock.end + 1), *right])
    if _frame(clock.table, run, series, n_snapshots) is None:
        return False
    if left and right and _frame(clock.table, sorted(left + right), series, n_snapshots) is not None:
        return True
    top = [v for v in series[clock.address] if v is not None]
    if bool(left) != bool(right) and clock.registers == 1:
        # the first or last register of a frame whose noise happened to rise at every round:
        # the rest of the frame is a frame by itself and the "clock" reads inside its codes
        rest = sorted(left or right)
        codes = [v for a in rest for v in series[a] if v is not None]
        if (
            codes
            and top
            and _frame(clock.table, rest, series, n_snapshots) is not None
            and min(codes) <= min(top)
            and max(top) <= max(codes)
        ):
            return True
    top_moves = sum(1 for a, b in itertools.pairwise(top) if a != b)
    neighbours = (series.get(clock.address - 1), series.get(clock.end + 1))
    return clock.registers > 1 and top_moves >= 2 and any(_moving(v) for v in neighbours)


def _moving(values: Sequence[int | None] | None) -> bool:
    return values is not None and len({v for v in values if v is not None}) > 1


def _group(
    series: Mapping[int, list[int | None]], address: int, width: int, times: Sequence[float]
) -> _Group | None:
    """``width`` registers from ``address`` as a big-endian counter, if they rise steadily."""
    columns = [series.get(address + k) for k in range(width)]
    cols = [c for c in columns if c is not None]
    if len(cols) < width:
        return None
    rows: list[tuple[float, list[int]]] = []
    for i, t in enumerate(times):
        row = [c[i] for c in cols]
        if all(v is not None for v in row):
            rows.append((t, [int(v or 0) for v in row]))
    if len(rows) < 3:
        return None
    words = [w for _, w in rows]
    if len({w[-1] for w in words}) < 2:
        return None  # the low word must move
    modulus = 1 << (16 * width)
    values = [_combine(w) for w in words]
    steps: list[int] = []
    spans: list[float] = []
    for i in range(1, len(rows)):
        dt = rows[i][0] - rows[i - 1][0]
        if not (math.isfinite(dt) and dt > 0):
            return None
        step = values[i] - values[i - 1]
        if step < 0:
            if -step <= modulus // 2:
                return None  # a fall, not a wrap
            step += modulus
        steps.append(step)
        spans.append(dt)
    total = sum(steps)
    elapsed = sum(spans)
    if sum(1 for step in steps if step > 0) < MIN_CLOCK_STEPS or not elapsed > 0:
        return None
    rate = _slope([t for t, _ in rows], list(itertools.accumulate(steps, initial=0)))
    if not 0.0 < rate <= MAX_CLOCK_RATE_PER_S:
        return None
    for step, dt in zip(steps, spans, strict=True):
        if abs(step - rate * dt) > CLOCK_STEADINESS * rate * dt + 2:
            return None
    if width > 1 and not _carries_fit(words, rate * max(spans)):
        return None
    top = [w[0] for w in words]
    return _Group(address, width, rate, total, all(v == 0 for v in top), len(set(top)) > 1)


def _slope(x: Sequence[float], y: Sequence[int]) -> float:
    """Least-squares slope of y over x: a counter's rate, less sensitive than its end points
    to the counts it had not yet reached at the first or last reading."""
    mx, my = sum(x) / len(x), sum(y) / len(y)
    sxx = sum((a - mx) ** 2 for a in x)
    return sum((a - mx) * (b - my) for a, b in zip(x, y, strict=True)) / sxx if sxx > 0 else 0.0


def _combine(words: Sequence[int]) -> int:
    value = 0
    for w in words:
        value = (value << 16) | (w & 0xFFFF)
    return value


def _carries_fit(words: Sequence[Sequence[int]], max_step: float) -> bool:
    """Where the lower part of a reading moves less than half its range per interval, the
    part above may only change by a carry: +1 exactly when the lower part wrapped. Two
    unrelated slow counters side by side fail this."""
    width = len(words[0])
    for low_words in range(1, width):
        modulus = 1 << (16 * low_words)
        if max_step >= modulus / 2:
            continue
        for prev, cur in itertools.pairwise(words):
            low_prev, low_cur = _combine(prev[-low_words:]), _combine(cur[-low_words:])
            high_step = _combine(cur[:-low_words]) - _combine(prev[:-low_words])
            if high_step != (1 if low_cur < low_prev else 0):
                return False
    return True


def _unit(rate: float, total: int) -> str | None:
    """The unit whose counts per second match ``rate``, allowing for the quantisation of a
    counter that moved only ``total`` counts; None for anything else (a tick counter)."""
    tolerance = 0.15 + 2.0 / total
    matches = [
        (abs(math.log(rate / per_s)), name)
        for name, per_s in CLOCK_UNITS.items()
        if abs(rate / per_s - 1.0) <= tolerance
    ]
    return min(matches)[1] if matches else None
