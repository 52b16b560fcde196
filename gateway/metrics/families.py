"""Every metric family the gateway exports, in one table (``FAMILIES``).

Each ``Family`` declares what Prometheus shows of it (name with its base unit, type, HELP
text, label names, histogram buckets) and how its samples are taken from the immutable
snapshot: ``samples(device, snapshot, counters)`` yields ``(label values, value)`` pairs for one
device, the label values in the order of ``labels`` (the device name first). Both writers read
this table and nothing else: ``collector.SnapshotCollector`` (prometheus_client families, for
``generate_latest``) and ``exposition`` (the text format written directly, fast); a family
added here appears in both, with the same samples.

Values are floats in the unit the name ends with: newtons (N), ohms, millimetres (mm), square
millimetres (mm^2), seconds (s); counts, 0/1 flags and ratios (``_ratio``: a ratio front end's
r / R_ref) are dimensionless. A value that is
absent (NaN or infinite: an open or stale channel, no contact for the centre of pressure, a
device never polled) is left out, never exported as NaN. Devices are exported in the order of
their names, family by family in the order of ``FAMILIES``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from typing import Final, Literal

from ..runtime.counters import DEFAULT_DURATION_BUCKETS_S, READ_ERROR_REASONS, DeviceCounters, HistogramData
from ..runtime.snapshot import STATUS_LABELS, DeviceSnapshot, FloatArray, RoiQuantities

__all__ = ["FAMILIES", "Family", "HistogramSample", "Sample"]

MetricType = Literal["gauge", "counter", "histogram"]
#: One sample of a gauge or counter: label values (in the family's label order) and the value.
Sample = tuple[tuple[str, ...], float]
#: One series of a histogram: label values (without ``le``) and the device's cumulative data.
HistogramSample = tuple[tuple[str, ...], HistogramData]
#: ``(device name, device snapshot, device counters or None)`` to the family's samples.
Sampler = Callable[[str, DeviceSnapshot, DeviceCounters | None], Iterable[Sample]]
HistogramSampler = Callable[[str, DeviceSnapshot, DeviceCounters | None], Iterable[HistogramSample]]

_FROM_POLL: Final = "from the last poll"


@dataclass(frozen=True)
class Family:
    """One metric family: what Prometheus shows of it and how its samples are taken.

    ``name`` is the name as exposed (a counter's ends in ``_total``, a histogram's is the base
    of its ``_bucket``/``_sum``/``_count`` series); ``labels`` are the label names in the order
    the samples give their values (the exposition sorts them by name, as the client library
    does). A gauge or counter has ``samples``; a histogram has ``histograms`` and ``buckets``
    (upper bounds in the unit of the name, +Inf implied).
    """

    name: str
    type: MetricType
    help: str
    labels: tuple[str, ...]
    samples: Sampler | None = None
    histograms: HistogramSampler | None = None
    buckets: tuple[float, ...] = ()

    @property
    def family_name(self) -> str:
        """The name as prometheus_client names the family: a counter's without ``_total``."""
        return self.name.removesuffix("_total") if self.type == "counter" else self.name


# ---------------------------------------------------------------- samplers, per channel


def _channel_values(
    array: Callable[[DeviceSnapshot], FloatArray], of: Callable[[DeviceSnapshot], bool] | None = None
) -> Sampler:
    """Samples ``(device, channel)`` of a per-channel array of the snapshot, finite values only;
    with ``of``, only of the devices it is true for."""

    def samples(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
        if of is not None and not of(dev):
            return
        values: list[float] = array(dev).tolist()
        for channel, value in zip(dev.channel_names, values, strict=True):
            if math.isfinite(value):
                yield (device, channel), value

    return samples


@lru_cache(maxsize=4096)
def _status_labels(device: str, channels: tuple[str, ...]) -> tuple[tuple[tuple[str, str, str], ...], ...]:
    """Per channel, the label values of its status series, one per status in code order (kept
    per device layout: the status family is most of a scrape's series)."""
    return tuple(tuple((device, channel, label) for label in STATUS_LABELS) for channel in channels)


def _channel_status(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """Per channel, one sample per status: 1.0 for the channel's status, 0.0 for the others."""
    for series, code in zip(_status_labels(device, dev.channel_names), dev.status.tolist(), strict=True):
        for status, labels in enumerate(series):
            yield labels, 1.0 if code == status else 0.0


def _channel_position(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """Per channel its x then its y position on the array, mm."""
    for channel, x, y in zip(dev.channel_names, dev.x_mm.tolist(), dev.y_mm.tolist(), strict=True):
        yield (device, channel, "x"), x
        yield (device, channel, "y"), y


# ---------------------------------------------------------------- samplers, per device


def _device_value(value: Callable[[DeviceSnapshot], float | None]) -> Sampler:
    """Samples ``(device,)`` of one number of the device snapshot, if finite."""

    def samples(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
        v = value(dev)
        if v is not None and math.isfinite(v):
            yield (device,), float(v)

    return samples


def _center_of_pressure(
    device: str, dev: DeviceSnapshot, counters: DeviceCounters | None
) -> Iterator[Sample]:
    """x then y of the centre of pressure, mm; nothing when no channel is in contact."""
    if dev.center_of_pressure_mm is not None:
        x, y = dev.center_of_pressure_mm
        if math.isfinite(x) and math.isfinite(y):
            yield (device, "x"), float(x)
            yield (device, "y"), float(y)


def _roi_value(value: Callable[[RoiQuantities], float], scale: float = 1.0) -> Sampler:
    """Samples ``(device, roi)`` of one quantity of each region of interest, times ``scale``."""

    def samples(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
        for roi in dev.rois:
            v = value(roi)
            if math.isfinite(v):
                yield (device, roi.name), float(v) * scale

    return samples


def _roi_center_of_pressure(
    device: str, dev: DeviceSnapshot, counters: DeviceCounters | None
) -> Iterator[Sample]:
    """x then y of each region's centre of pressure, m; nothing for a region not in contact."""
    for roi in dev.rois:
        if roi.cop_mm is not None and math.isfinite(roi.cop_mm[0]) and math.isfinite(roi.cop_mm[1]):
            yield (device, roi.name, "x"), roi.cop_mm[0] * 1e-3
            yield (device, roi.name, "y"), roi.cop_mm[1] * 1e-3


def _clock_faults(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """Device clock faults by kind, count."""
    for kind, count in dev.clock_faults:
        yield (device, kind), float(count)


def _dead_taxels(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """Dead taxels by region (every region, 0 included), count; nothing when not tracked."""
    for region, count in dev.dead_by_region:
        yield (device, region), float(count)


def _status_bits(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """Each named bit of each status word read: 1 set, 0 clear."""
    for word in dev.status_words:
        if word.value is not None:
            for _, label, on, _ in word.bits:
                yield (device, word.name, label), 1.0 if on else 0.0


def _status_codes(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """The value of each enumerated status word read, labelled with its code's name."""
    for word in dev.status_words:
        if word.value is not None and word.code is not None:
            yield (device, word.name, word.code), float(word.value)


def _status_errors(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """1 where a status word read has an error bit set or an error code, else 0."""
    for word in dev.status_words:
        if word.value is not None:
            yield (device, word.name), 1.0 if word.error else 0.0


def _reads(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """Read requests attempted, count; nothing for a device without counters."""
    if counters is not None:
        yield (device,), float(counters.reads_total)


def _read_errors(device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> Iterator[Sample]:
    """Failed read requests by reason (every reason, 0 included), count."""
    if counters is not None:
        errors = counters.read_errors_total
        for reason in READ_ERROR_REASONS:
            yield (device, reason), float(errors.get(reason, 0))


def _poll_durations(
    device: str, dev: DeviceSnapshot, counters: DeviceCounters | None
) -> Iterator[HistogramSample]:
    """The device's poll-duration histogram (s); nothing for a device without counters."""
    if counters is not None:
        histogram = counters.poll_duration
        if histogram.bounds != DEFAULT_DURATION_BUCKETS_S:
            raise ValueError(f"poll durations of {device!r} counted in other buckets: {histogram.bounds}")
        yield (device,), histogram


# ---------------------------------------------------------------- the table

#: Every family, in the order of the exposition.
FAMILIES: Final[tuple[Family, ...]] = (
    Family(
        "tactile_force_newtons",
        "gauge",
        f"Drift-corrected force on the channel in newtons (N), {_FROM_POLL}; absent when the "
        "channel has no valid value (open, short, error)",
        ("device", "channel"),
        _channel_values(lambda dev: dev.force_n),
    ),
    Family(
        "tactile_force_static_newtons",
        "gauge",
        "Force in newtons (N) by static inversion without creep state (diagnostic; overestimates "
        f"held forces as the sensor creeps), {_FROM_POLL}",
        ("device", "channel"),
        _channel_values(lambda dev: dev.force_static_n),
    ),
    Family(
        "tactile_reference_force_newtons",
        "gauge",
        "Reference force of the channel in newtons (N) where the device reports one (a bench's load "
        f"cell, the simulator's truth), {_FROM_POLL}",
        ("device", "channel"),
        _channel_values(lambda dev: dev.reference_force_n),
    ),
    Family(
        "tactile_resistance_ohms",
        "gauge",
        f"Sensor resistance in ohms, {_FROM_POLL}; absent when open or invalid, and for a ratio "
        "front end (see tactile_resistance_ratio)",
        ("device", "channel"),
        _channel_values(lambda dev: dev.resistance_ohm, lambda dev: not dev.resistance_relative),
    ),
    Family(
        "tactile_resistance_ratio",
        "gauge",
        "Sensor resistance relative to the board's reference resistor, r / R_ref (dimensionless), "
        f"of a ratio front end, whose R_ref is unknown, {_FROM_POLL}; absent when open or invalid",
        ("device", "channel"),
        _channel_values(lambda dev: dev.resistance_ohm, lambda dev: dev.resistance_relative),
    ),
    Family(
        "tactile_channel_status",
        "gauge",
        f"Channel status, 1 for the current status and 0 for the others (dimensionless), {_FROM_POLL}: "
        + ", ".join(STATUS_LABELS),
        ("device", "channel", "status"),
        _channel_status,
    ),
    Family(
        "tactile_channel_position_mm",
        "gauge",
        "Position of the channel on the array in millimetres (mm), from the configuration",
        ("device", "channel", "axis"),
        _channel_position,
    ),
    Family(
        "tactile_device_up",
        "gauge",
        f"1 if the device answered, 0 if not (dimensionless), {_FROM_POLL}",
        ("device",),
        _device_value(lambda dev: 1.0 if dev.up else 0.0),
    ),
    Family(
        "tactile_last_poll_success_timestamp_seconds",
        "gauge",
        "Unix time in seconds (s) of the last successful poll of the device",
        ("device",),
        _device_value(lambda dev: dev.last_success_timestamp_s),
    ),
    Family(
        "tactile_poll_duration_seconds",
        "histogram",
        "Duration in seconds (s) of successful polls of the device "
        "(all reads plus the CPU time of the conversion)",
        ("device",),
        histograms=_poll_durations,
        buckets=DEFAULT_DURATION_BUCKETS_S,
    ),
    Family(
        "tactile_poll_interval_seconds",
        "gauge",
        "Configured poll interval of the device's bus in seconds (s)",
        ("device",),
        _device_value(lambda dev: dev.poll_interval_s),
    ),
    Family(
        "tactile_reads_total",
        "counter",
        "Modbus read requests attempted for the device (count), retries included, up to the last poll",
        ("device",),
        _reads,
    ),
    Family(
        "tactile_read_errors_total",
        "counter",
        "Failed Modbus read requests of the device by reason (count), up to the last poll: "
        "timeout, exception, connection, decode, mismatch (the device is not the configured one)",
        ("device", "reason"),
        _read_errors,
    ),
    Family(
        "tactile_array_total_force_newtons",
        "gauge",
        f"Sum of the drift-corrected forces of the channels in contact in newtons (N), {_FROM_POLL}",
        ("device",),
        _device_value(lambda dev: dev.total_force_n),
    ),
    Family(
        "tactile_array_center_of_pressure_mm",
        "gauge",
        f"Force-weighted centre of pressure on the array in millimetres (mm), {_FROM_POLL}; "
        "absent when no channel is in contact",
        ("device", "axis"),
        _center_of_pressure,
    ),
    Family(
        "tactile_array_contact_area_square_mm",
        "gauge",
        "Contact area in square millimetres (mm^2): channels in contact times pitch squared, " + _FROM_POLL,
        ("device",),
        _device_value(lambda dev: dev.contact_area_mm2),
    ),
    Family(
        "tactile_array_channels_in_contact",
        "gauge",
        f"Number of channels in contact (count), {_FROM_POLL}",
        ("device",),
        _device_value(lambda dev: dev.channels_in_contact),
    ),
    Family(
        "tactile_roi_force_newtons",
        "gauge",
        "Sum of the forces of a region of interest's channels in contact in newtons (N), " + _FROM_POLL,
        ("device", "roi"),
        _roi_value(lambda roi: roi.force_n),
    ),
    Family(
        "tactile_roi_peak_force_newtons",
        "gauge",
        "Largest force of a region of interest's channels in newtons (N; 0 when none is in contact), "
        + _FROM_POLL,
        ("device", "roi"),
        _roi_value(lambda roi: roi.peak_n),
    ),
    Family(
        "tactile_roi_contact_area_square_metres",
        "gauge",
        "Contact area of a region of interest in square metres (m^2): the cells of its channels in contact, "
        + _FROM_POLL,
        ("device", "roi"),
        _roi_value(lambda roi: roi.area_mm2, 1e-6),
    ),
    Family(
        "tactile_roi_center_of_pressure_metres",
        "gauge",
        f"Force-weighted centre of pressure of a region of interest in metres (m), {_FROM_POLL}; "
        "absent when none of its channels is in contact",
        ("device", "roi", "axis"),
        _roi_center_of_pressure,
    ),
    Family(
        "tactile_dead_taxels",
        "gauge",
        "Dead taxels (count) by region: frozen while the rest of their region moves, for "
        f"dead_after_s; their status is error, {_FROM_POLL}",
        ("device", "region"),
        _dead_taxels,
    ),
    Family(
        "tactile_device_clock_fallback",
        "gauge",
        "1 if the device's map names a clock but the host clock times the creep (the clock stalled, "
        "went back or could not be read), else 0 (dimensionless)",
        ("device",),
        _device_value(lambda dev: 1.0 if dev.clock_fallback is not None else 0.0),
    ),
    Family(
        "tactile_device_clock_faults_total",
        "counter",
        "Device clock faults seen since the device was configured (count), by kind: stuck, backwards",
        ("device", "kind"),
        _clock_faults,
    ),
    Family(
        "tactile_device_status_bit",
        "gauge",
        f"1 if the named bit of the device's status word is set, else 0 (dimensionless), {_FROM_POLL}",
        ("device", "word", "bit"),
        _status_bits,
    ),
    Family(
        "tactile_device_status_code",
        "gauge",
        f"The value of the device's enumerated status word, labelled with its name (code), {_FROM_POLL}",
        ("device", "word", "code"),
        _status_codes,
    ),
    Family(
        "tactile_device_status_error",
        "gauge",
        "1 if the device's status word has an error bit set or an error code, else 0 "
        f"(dimensionless), {_FROM_POLL}",
        ("device", "word"),
        _status_errors,
    ),
)
