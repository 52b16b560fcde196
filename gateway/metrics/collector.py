"""The Prometheus custom collector over the latest snapshot.

``SnapshotCollector`` builds fresh metric families from the immutable ``GatewaySnapshot``
at every scrape (no state of its own, no timestamps: Prometheus stamps the scrape), one per
entry of ``families.FAMILIES`` (names with base units: ``tactile_force_newtons``,
``tactile_resistance_ohms``, ..., and a per-device ``tactile_device_up``), with the samples
that table's samplers take from the snapshot. It is registered into a registry the caller
passes in. Absent values (open or stale-without-data channels, no contact for the centre of
pressure) are left out, never exported as NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.metrics_core import Metric

from ..runtime.snapshot import GatewaySnapshot
from .families import FAMILIES, Family

SnapshotSource = Callable[[], GatewaySnapshot]


def _bucket_label(bound: float) -> str:
    """The ``le`` label of an upper bound (s, for the poll durations): ``repr`` or ``+Inf``."""
    return "+Inf" if math.isinf(bound) else repr(float(bound))


def family_metric(family: Family, snap: GatewaySnapshot) -> Metric:
    """The prometheus_client family of ``family`` with its samples from ``snap``, device by device
    in the order of their names."""
    labels = list(family.labels)
    devices = [(name, snap.devices[name], snap.counters.get(name)) for name in sorted(snap.devices)]
    if family.type == "histogram":
        histogram = HistogramMetricFamily(family.family_name, family.help, labels=labels)
        assert family.histograms is not None, family.name
        les = [_bucket_label(b) for b in (*family.buckets, math.inf)]
        for device in devices:
            for values, data in family.histograms(*device):
                buckets = [(le, float(c)) for le, c in zip(les, data.bucket_counts, strict=True)]
                histogram.add_metric(list(values), buckets, data.sum)
        return histogram
    metric: GaugeMetricFamily | CounterMetricFamily
    if family.type == "counter":
        metric = CounterMetricFamily(family.family_name, family.help, labels=labels)
    else:
        metric = GaugeMetricFamily(family.family_name, family.help, labels=labels)
    assert family.samples is not None, family.name
    for device in devices:
        for values, value in family.samples(*device):
            metric.add_metric(list(values), value)
    return metric


class SnapshotCollector:
    """Custom collector: every scrape reads the latest snapshot from ``source`` and yields one
    family per entry of ``FAMILIES``."""

    def __init__(self, source: SnapshotSource) -> None:
        self._source = source

    def describe(self) -> Iterable[Metric]:
        return self._families(GatewaySnapshot())

    def collect(self) -> Iterable[Metric]:
        return self._families(self._source())

    @staticmethod
    def _families(snap: GatewaySnapshot) -> list[Metric]:
        return [family_metric(family, snap) for family in FAMILIES]


def make_registry(source: SnapshotSource, registry: CollectorRegistry | None = None) -> CollectorRegistry:
    """Register a ``SnapshotCollector`` into ``registry`` (a new one if None) and return it."""
    reg = registry if registry is not None else CollectorRegistry(auto_describe=False)
    reg.register(SnapshotCollector(source))
    return reg
