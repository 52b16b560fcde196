"""Per-device counters: reads, read errors by reason, polls and a poll-duration histogram.

``Tally`` is the one accumulator (mutable, inside a bus task); ``freeze`` gives the immutable
``DeviceCounters`` a snapshot carries. ``HistogramData`` is cumulative with Prometheus
semantics (``bucket_counts[k]`` counts durations <= ``bounds[k]`` seconds, the last entry
is +Inf); a NaN duration counts as a poll but is not observed.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

__all__ = ["DEFAULT_DURATION_BUCKETS_S", "READ_ERROR_REASONS", "DeviceCounters", "HistogramData", "Tally"]

READ_ERROR_REASONS: tuple[str, ...] = ("timeout", "exception", "connection", "decode", "mismatch")

DEFAULT_DURATION_BUCKETS_S: tuple[float, ...] = (
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0,
)  # fmt: skip


@dataclass(frozen=True)
class HistogramData:
    """A cumulative histogram (Prometheus semantics): ``bucket_counts[k]`` counts values
    <= ``bounds[k]``; the last entry (bound +inf) equals ``count``."""

    bounds: tuple[float, ...] = DEFAULT_DURATION_BUCKETS_S
    bucket_counts: tuple[int, ...] = (0,) * (len(DEFAULT_DURATION_BUCKETS_S) + 1)
    sum: float = 0.0
    count: int = 0


@dataclass(frozen=True)
class DeviceCounters:
    """Cumulative counters of one device since the gateway started."""

    reads_total: int = 0
    read_errors_total: Mapping[str, int] = field(
        default_factory=lambda: MappingProxyType(dict.fromkeys(READ_ERROR_REASONS, 0))
    )
    polls_total: int = 0
    poll_duration: HistogramData = field(default_factory=HistogramData)


class Tally:
    """Mutable counters of one device inside its bus task; ``freeze()`` gives the immutable
    ``DeviceCounters`` that snapshots carry (cached until the next change)."""

    def __init__(self, base: DeviceCounters | None = None) -> None:
        base = base or DeviceCounters()
        self.reads_total = base.reads_total
        self.errors = dict(base.read_errors_total)
        self.polls_total = base.polls_total
        h = base.poll_duration
        self.bounds = h.bounds
        # per-bucket (not cumulative) counts, the last one for +Inf
        self.buckets = [c - p for c, p in zip(h.bucket_counts, (0, *h.bucket_counts[:-1]), strict=True)]
        self.duration_sum = h.sum
        self._frozen: DeviceCounters | None = base
        self._errors_view: Mapping[str, int] = base.read_errors_total

    def read(self) -> None:
        self.reads_total += 1
        self._frozen = None

    def error(self, reason: str) -> None:
        if reason not in self.errors:
            raise ValueError(f"unknown read error reason {reason!r}")
        self.errors[reason] += 1
        self._errors_view = MappingProxyType(dict(self.errors))
        self._frozen = None

    def poll(self, duration_s: float) -> None:
        self.polls_total += 1
        if math.isfinite(duration_s):
            self.buckets[bisect.bisect_left(self.bounds, duration_s)] += 1
            self.duration_sum += duration_s
        self._frozen = None

    def freeze(self) -> DeviceCounters:
        if self._frozen is None:
            cumulative = tuple(itertools.accumulate(self.buckets))
            self._frozen = DeviceCounters(
                reads_total=self.reads_total,
                read_errors_total=self._errors_view,
                polls_total=self.polls_total,
                poll_duration=HistogramData(self.bounds, cumulative, self.duration_sum, cumulative[-1]),
            )
        return self._frozen
