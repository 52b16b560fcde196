"""The Prometheus custom collector over the latest snapshot.

``SnapshotCollector`` builds fresh metric families from the immutable ``GatewaySnapshot``
at every scrape (no state of its own, no timestamps: Prometheus stamps the scrape), with base
units in the names (``tactile_force_newtons``, ``tactile_resistance_ohms``, ...) and a
per-device ``tactile_device_up``. It is registered into a registry the caller passes in.
Absent values (open or stale-without-data channels, no contact for the centre of pressure)
are left out, never exported as NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.metrics_core import Metric

from ..runtime.counters import READ_ERROR_REASONS
from ..runtime.snapshot import STATUS_LABELS, ChannelStatus, GatewaySnapshot

SnapshotSource = Callable[[], GatewaySnapshot]


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)


def _bucket_label(bound: float) -> str:
    return "+Inf" if math.isinf(bound) else repr(float(bound))


class SnapshotCollector:
    """Custom collector: every scrape reads the latest snapshot from ``source``."""

    def __init__(self, source: SnapshotSource) -> None:
        self._source = source

    def describe(self) -> Iterable[Metric]:
        return self._families(GatewaySnapshot())

    def collect(self) -> Iterable[Metric]:
        return self._families(self._source())

    @staticmethod
    def _families(snap: GatewaySnapshot) -> list[Metric]:
        from_poll = "from the last poll"
        force = GaugeMetricFamily(
            "tactile_force_newtons",
            f"Drift-corrected force on the channel in newtons (N), {from_poll}; absent when the "
            "channel has no valid value (open, short, error)",
            labels=["device", "channel"],
        )
        static = GaugeMetricFamily(
            "tactile_force_static_newtons",
            f"Force in newtons (N) by static inversion without creep state (diagnostic; overestimates "
            f"held forces as the sensor creeps), {from_poll}",
            labels=["device", "channel"],
        )
        reference = GaugeMetricFamily(
            "tactile_reference_force_newtons",
            f"Reference force of the channel in newtons (N) where the device reports one (a bench's load "
            f"cell, the simulator's truth), {from_poll}",
            labels=["device", "channel"],
        )
        resistance = GaugeMetricFamily(
            "tactile_resistance_ohms",
            f"Sensor resistance in ohms, {from_poll}; absent when open or invalid",
            labels=["device", "channel"],
        )
        status = GaugeMetricFamily(
            "tactile_channel_status",
            f"Channel status, 1 for the current status and 0 for the others (dimensionless), {from_poll}: "
            + ", ".join(STATUS_LABELS),
            labels=["device", "channel", "status"],
        )
        position = GaugeMetricFamily(
            "tactile_channel_position_mm",
            "Position of the channel on the array in millimetres (mm), from the configuration",
            labels=["device", "channel", "axis"],
        )
        up = GaugeMetricFamily(
            "tactile_device_up",
            f"1 if the device answered, 0 if not (dimensionless), {from_poll}",
            labels=["device"],
        )
        last_ok = GaugeMetricFamily(
            "tactile_last_poll_success_timestamp_seconds",
            "Unix time in seconds (s) of the last successful poll of the device",
            labels=["device"],
        )
        duration = HistogramMetricFamily(
            "tactile_poll_duration_seconds",
            "Duration in seconds (s) of successful polls of the device "
            "(all reads plus the CPU time of the conversion)",
            labels=["device"],
        )
        interval = GaugeMetricFamily(
            "tactile_poll_interval_seconds",
            "Configured poll interval of the device's bus in seconds (s)",
            labels=["device"],
        )
        reads = CounterMetricFamily(
            "tactile_reads_total",
            "Modbus read requests attempted for the device (count), retries included, up to the last poll",
            labels=["device"],
        )
        errors = CounterMetricFamily(
            "tactile_read_errors_total",
            "Failed Modbus read requests of the device by reason (count), up to the last poll: "
            "timeout, exception, connection, decode, mismatch (the device is not the configured one)",
            labels=["device", "reason"],
        )
        total = GaugeMetricFamily(
            "tactile_array_total_force_newtons",
            f"Sum of the drift-corrected forces of the channels in contact in newtons (N), {from_poll}",
            labels=["device"],
        )
        cop = GaugeMetricFamily(
            "tactile_array_center_of_pressure_mm",
            f"Force-weighted centre of pressure on the array in millimetres (mm), {from_poll}; "
            "absent when no channel is in contact",
            labels=["device", "axis"],
        )
        area = GaugeMetricFamily(
            "tactile_array_contact_area_square_mm",
            "Contact area in square millimetres (mm^2): channels in contact times pitch squared, "
            + from_poll,
            labels=["device"],
        )
        in_contact = GaugeMetricFamily(
            "tactile_array_channels_in_contact",
            f"Number of channels in contact (count), {from_poll}",
            labels=["device"],
        )
        clock_host = GaugeMetricFamily(
            "tactile_device_clock_fallback",
            "1 if the device's map names a clock but the host clock times the creep (the clock stalled, "
            "went back or could not be read), else 0 (dimensionless)",
            labels=["device"],
        )
        clock_faults = CounterMetricFamily(
            "tactile_device_clock_faults",
            "Device clock faults seen since the device was configured (count), by kind: stuck, backwards",
            labels=["device", "kind"],
        )
        for name in sorted(snap.devices):
            dev = snap.devices[name]
            clock_host.add_metric([name], 1.0 if dev.clock_fallback is not None else 0.0)
            for kind, count in dev.clock_faults:
                clock_faults.add_metric([name, kind], float(count))
            for ch in dev.channels():
                labels = [name, ch.name]
                if _finite(ch.force_n):
                    force.add_metric(labels, float(ch.force_n))  # type: ignore[arg-type]
                if _finite(ch.force_static_n):
                    static.add_metric(labels, float(ch.force_static_n))  # type: ignore[arg-type]
                if _finite(ch.reference_force_n):
                    reference.add_metric(labels, float(ch.reference_force_n))  # type: ignore[arg-type]
                if _finite(ch.resistance_ohm):
                    resistance.add_metric(labels, float(ch.resistance_ohm))  # type: ignore[arg-type]
                for s in ChannelStatus:
                    status.add_metric([*labels, s.label], 1.0 if ch.status == s else 0.0)
                position.add_metric([*labels, "x"], ch.x_mm)
                position.add_metric([*labels, "y"], ch.y_mm)
            up.add_metric([name], 1.0 if dev.up else 0.0)
            if _finite(dev.last_success_timestamp_s):
                last_ok.add_metric([name], float(dev.last_success_timestamp_s))  # type: ignore[arg-type]
            interval.add_metric([name], dev.poll_interval_s)
            total.add_metric([name], dev.total_force_n)
            if dev.center_of_pressure_mm is not None:
                x, y = dev.center_of_pressure_mm
                if math.isfinite(x) and math.isfinite(y):
                    cop.add_metric([name, "x"], x)
                    cop.add_metric([name, "y"], y)
            area.add_metric([name], dev.contact_area_mm2)
            in_contact.add_metric([name], float(dev.channels_in_contact))
            counters = snap.counters.get(name)
            if counters is not None:
                reads.add_metric([name], float(counters.reads_total))
                for reason in READ_ERROR_REASONS:
                    errors.add_metric([name, reason], float(counters.read_errors_total.get(reason, 0)))
                h = counters.poll_duration
                buckets = [
                    (_bucket_label(b), float(c))
                    for b, c in zip((*h.bounds, math.inf), h.bucket_counts, strict=True)
                ]
                duration.add_metric([name], buckets, h.sum)
        return [
            force,
            static,
            reference,
            resistance,
            status,
            position,
            up,
            last_ok,
            duration,
            interval,
            reads,
            errors,
            total,
            cop,
            area,
            in_contact,
            clock_host,
            clock_faults,
        ]


def make_registry(source: SnapshotSource, registry: CollectorRegistry | None = None) -> CollectorRegistry:
    """Register a ``SnapshotCollector`` into ``registry`` (a new one if None) and return it."""
    reg = registry if registry is not None else CollectorRegistry(auto_describe=False)
    reg.register(SnapshotCollector(source))
    return reg
