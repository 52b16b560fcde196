"""Recorded samples replayed through a ``DeviceProcessor``, each channel at its own times.

The input is one series per enabled channel of the processor (in its order): times (s,
non-decreasing), resistances (ohm; ``inf`` for no current), and optionally the reference
force and the temperature. The poller converts every channel of a device at each poll; a
record's channels may each have been sampled at their own times (a row per channel, each
with its own time), so the replay converts each channel at its own samples:

* **Device samples.** Samples of equal time across channels are one device sample; a
  channel's k-th sample at a time goes into the k-th device sample at that time (repeated
  times step by 0 s). ``replay`` returns how many there are; ``held_snapshots`` gives the
  device's snapshot at each of them.
* **Each channel at its own samples.** A channel's state steps only at its own samples, by
  its recorded time step (``DeviceProcessor.process``'s ``step_s``, one step per channel),
  and the processor converts every channel's k-th sample in one call (``DeviceProcessor.process``
  once per sample rank, not once per device sample: a record whose rows each have their own
  time costs what the same rows with shared times cost). A channel with fewer samples reads
  NaN in the calls after its last one, with a step of 0 s; those readings are not returned.
  This is what stepping the device at every device sample would read, to rounding: a channel
  without a sample there would read NaN (an invalid value: its held force kept and its state
  relaxed over the step with that force held), and relaxing with a constant held force is
  exact (``SensorModel.relax``, the curves' Kelvin steps), so relaxing over dt1 then dt2 equals
  relaxing over dt1 + dt2, and the hysteresis play does not move with the same force recorded
  again. A channel's results are those it reads replayed alone.
* **Clock.** A channel's first step is from the first time of all; each call carries the
  latest time replayed so far, less the first time of all, as the device clock's reading
  (``device_time_s``, and as the host clock); a held snapshot carries its device sample's.
* **Span.** Times spanning more than ``MAX_REPLAY_SPAN_S`` (584 years: a 64-bit nanosecond
  clock), or not finite, are a ``ReplayError``: no device clock counts them.
* **Fault bitmaps.** Every sample reports open and short bitmaps with no channel faulty, so
  a rail is a reading, as the gateway reads it from a device with bitmaps: ``inf`` (no
  current: the contact open at rest) reads no contact, 0 N.
* **What a device sample shows** (``held_snapshots``, the frames ``view`` plays back): each
  channel's last reading at or before it, sample-and-hold: the force, static force, status,
  resistance, reference force and temperature of its latest sample; a channel with no sample
  yet reads no value (``error``). The array quantities (total force, centre of pressure,
  contact area, peak: ``snapshot.array_quantities``, for all device samples at once) are those
  of the held readings. ``apply``'s per-sample outputs are
  ``replay``'s: what each channel read at each of its own samples.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import NDArray

from ..modbus.image import RawSample
from .processor import DeviceProcessor
from .rois import roi_quantities, roi_slots
from .snapshot import IN_CONTACT, ChannelStatus, DeviceSnapshot, StaticEstimate, read_only

__all__ = [
    "MAX_REPLAY_SPAN_S",
    "ChannelSeries",
    "ReplayError",
    "ReplayedChannel",
    "held_snapshots",
    "replay",
]

#: The longest time a replay spans (s): what a 64-bit nanosecond clock counts, 584 years
MAX_REPLAY_SPAN_S = 2**64 * 1e-9


class ReplayError(ValueError):
    """Series a replay cannot step through (the message is one line for the user)."""


FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class ChannelSeries:
    """One channel's recorded samples (arrays of one length; times non-decreasing)."""

    time_s: FloatArray
    resistance_ohm: FloatArray
    reference_force_n: FloatArray | None = None
    temperature_c: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class ReplayedChannel:
    """Per sample of a series: the snapshot's force (drift-corrected, N), its static estimate
    (``DeviceSnapshot.force_static_n``, N), the ``ChannelStatus`` code and the resistance the
    snapshot reports (ohm); NaN forces where the status carries none, NaN resistance where
    there is none (invalid, or no current)."""

    force_n: FloatArray
    force_static_n: FloatArray
    status: NDArray[np.int8]
    resistance_ohm: FloatArray


@dataclass(frozen=True, eq=False)
class _Replay:
    """A replay's per-sample results with what ``held_snapshots`` needs: each sample's device
    sample (per channel, increasing), the device samples' times, the first time of all (s) and
    the last snapshot (the device's fixed fields)."""

    channels: tuple[ReplayedChannel, ...]
    device_sample: tuple[IntArray, ...]
    sample_time_s: FloatArray
    t0_s: float
    last: DeviceSnapshot | None


@dataclass(frozen=True, eq=False)
class _HeldStatic(StaticEstimate):
    """The static forces a held snapshot shows, already evaluated (N)."""

    values_n: FloatArray

    def evaluate(self) -> FloatArray:
        return self.values_n


def _occurrence(time_s: FloatArray) -> IntArray:
    """For each sample, how many earlier samples of its series have the same time."""
    first = np.searchsorted(time_s, time_s, side="left")
    return np.arange(time_s.size, dtype=np.int64) - first.astype(np.int64)


def _check_span(series: Sequence[ChannelSeries]) -> None:
    """``ReplayError`` for times that span more than ``MAX_REPLAY_SPAN_S`` (or are not finite):
    no device clock counts them, and their steps would not be the recorded ones."""
    times = [np.asarray(s.time_s, dtype=np.float64) for s in series if len(s.time_s)]
    if not times:
        return
    first = min(float(t[0]) for t in times)
    last = max(float(t[-1]) for t in times)
    if not (math.isfinite(first) and math.isfinite(last) and last - first <= MAX_REPLAY_SPAN_S):
        raise ReplayError(
            f"time_s runs from {first:g} to {last:g} s: a span of more than {MAX_REPLAY_SPAN_S:.3g} s "
            "(584 years, what a 64-bit nanosecond clock counts) is not seconds since a record's start"
        )


def _device_samples(times: Sequence[FloatArray]) -> tuple[tuple[IntArray, ...], FloatArray]:
    """Each sample's device sample (numbered in time order) and the device samples' times."""
    which = np.concatenate([np.full(t.size, j, dtype=np.int64) for j, t in enumerate(times)])
    joined = np.concatenate(times)
    occurrence = np.concatenate([_occurrence(t) for t in times])
    order = np.lexsort((which, occurrence, joined))
    t_sorted, o_sorted = joined[order], occurrence[order]
    new = np.ones(order.size, dtype=bool)
    new[1:] = (t_sorted[1:] != t_sorted[:-1]) | (o_sorted[1:] != o_sorted[:-1])
    number = np.empty(order.size, dtype=np.int64)
    number[order] = np.cumsum(new) - 1
    bounds = np.cumsum([0, *(t.size for t in times)]).tolist()
    per_channel = tuple(number[lo:hi] for lo, hi in itertools.pairwise(bounds))
    return per_channel, t_sorted[new]


def _run(processor: DeviceProcessor, series: Sequence[ChannelSeries]) -> _Replay:
    k = len(series)
    if k != len(processor.channels):
        raise ValueError(f"{k} series for a processor of {len(processor.channels)} channels")
    times = [np.asarray(s.time_s, dtype=np.float64) for s in series]
    for t in times:
        if bool(np.any(np.diff(t) < 0.0)):
            raise ValueError("a series' times go backwards")
    _check_span(series)
    device_sample, sample_time_s = _device_samples(times) if k else ((), np.zeros(0))
    n_device = processor.device.n_channels
    lengths = np.array([t.size for t in times], dtype=np.int64)
    t0 = float(sample_time_s[0]) if sample_time_s.size else 0.0
    # each sample's clock reading, and the step since the channel's previous sample (the first:
    # since the first time of all), as a clock's readings step
    clock = [t - t0 for t in times]
    steps = [np.diff(c, prepend=0.0) for c in clock]
    resistance = [np.asarray(s.resistance_ohm, dtype=np.float64) for s in series]
    reference = None if any(s.reference_force_n is None for s in series) else [
        np.asarray(s.reference_force_n, dtype=np.float64) for s in series
    ]  # fmt: skip
    temps = None if any(s.temperature_c is None for s in series) else [
        np.asarray(s.temperature_c, dtype=np.float64) for s in series
    ]  # fmt: skip
    force = [np.full(n, np.nan) for n in lengths.tolist()]
    static = [np.full(n, np.nan) for n in lengths.tolist()]
    reported = [np.full(n, np.nan) for n in lengths.tolist()]
    status = [np.full(n, int(ChannelStatus.ERROR), dtype=np.int8) for n in lengths.tolist()]
    no_fault = np.zeros(n_device, dtype=bool)
    state = processor.initial_state()
    snap: DeviceSnapshot | None = None
    clock_s = 0.0
    for rank in range(int(lengths.max(initial=0))):
        active = np.flatnonzero(lengths > rank).tolist()
        slots = processor.index[active]
        r = np.full(n_device, np.nan)
        r[slots] = [resistance[j][rank] for j in active]
        ref = temp = None
        if reference is not None:
            ref = np.full(n_device, np.nan)
            ref[slots] = [reference[j][rank] for j in active]
        if temps is not None:
            temp = np.full(n_device, np.nan)
            temp[slots] = [temps[j][rank] for j in active]
        step = np.zeros(k)
        step[active] = [steps[j][rank] for j in active]
        clock_s = max(clock_s, *(float(clock[j][rank]) for j in active))
        raw = RawSample(
            resistance_ohm=r,
            open_bits=no_fault,
            short_bits=no_fault,
            temperature_c=temp,
            reference_force_n=ref,
            device_time_s=clock_s,
        )
        snap, state = processor.process(
            state, raw, wall_time_s=t0 + clock_s, host_time_s=clock_s, step_s=step
        )
        f, fs, st, ro = snap.force_n, snap.force_static_n, snap.status, snap.resistance_ohm
        for j in active:
            force[j][rank], static[j][rank], status[j][rank], reported[j][rank] = f[j], fs[j], st[j], ro[j]
    channels = tuple(ReplayedChannel(*arrays) for arrays in zip(force, static, status, reported, strict=True))
    return _Replay(channels, device_sample, sample_time_s, t0, snap)


def replay(
    processor: DeviceProcessor, series: Sequence[ChannelSeries]
) -> tuple[tuple[ReplayedChannel, ...], int]:
    """Run ``processor`` over ``series`` (one per enabled channel, in the processor's order;
    see the module docstring): what it read at each sample, and the number of device samples."""
    run = _run(processor, series)
    return run.channels, int(run.sample_time_s.size)


def held_snapshots(
    processor: DeviceProcessor,
    series: Sequence[ChannelSeries],
    keep: Callable[[int], Sequence[int]] | None = None,
) -> tuple[list[DeviceSnapshot], int]:
    """The device's snapshot at each device sample that ``keep(n_samples)`` names (default
    all; indices in time order), each channel showing its last reading (sample-and-hold, see
    the module docstring), and the number of device samples."""
    run = _run(processor, series)
    n_samples = int(run.sample_time_s.size)
    if run.last is None or n_samples == 0:
        return [], n_samples
    chosen = np.asarray(list(keep(n_samples)) if keep is not None else range(n_samples), dtype=np.int64)
    n, m = len(series), chosen.size
    force, static, resistance = np.full((m, n), np.nan), np.full((m, n), np.nan), np.full((m, n), np.nan)
    status = np.full((m, n), int(ChannelStatus.ERROR), dtype=np.int8)
    has_reference = all(s.reference_force_n is not None for s in series)
    has_temperature = all(s.temperature_c is not None for s in series)
    reference = np.full((m, n), np.nan)
    temperature = np.full((m, n), np.nan)
    for j, (numbers, got, s) in enumerate(zip(run.device_sample, run.channels, series, strict=True)):
        latest = np.searchsorted(numbers, chosen, side="right") - 1
        shown = latest >= 0
        rows = latest[shown]
        force[shown, j] = got.force_n[rows]
        static[shown, j] = got.force_static_n[rows]
        status[shown, j] = got.status[rows]
        resistance[shown, j] = got.resistance_ohm[rows]
        if has_reference and s.reference_force_n is not None:
            reference[shown, j] = np.asarray(s.reference_force_n, dtype=np.float64)[rows]
        if has_temperature and s.temperature_c is not None:
            temperature[shown, j] = np.asarray(s.temperature_c, dtype=np.float64)[rows]
    template = run.last
    # the snapshot's fixed fields (device, layout, clock) as the last replayed one has them
    fixed = {f.name: getattr(template, f.name) for f in fields(DeviceSnapshot) if f.init}
    empty = np.zeros(0)
    no_static = (), empty, None, np.zeros(0, dtype=bool), empty
    q = _quantities(force, status, processor.x_mm, processor.y_mm, processor.cell_areas_mm2)
    names = processor.names
    rois = roi_slots(processor.device.rois, processor.index)
    out: list[DeviceSnapshot] = []
    columns = zip(run.sample_time_s[chosen].tolist(), *(a.tolist() for a in q), strict=True)
    for i, (t, total, x, y, n_contact, peak, area_mm2) in enumerate(columns):
        fixed.update(
            resistance_ohm=read_only(resistance[i]),
            force_n=read_only(force[i]),
            static_estimate=_HeldStatic(*no_static, read_only(static[i])),
            reference_force_n=read_only(reference[i]) if has_reference else template.reference_force_n,
            status=read_only(status[i]),
            timestamp_s=t,
            last_success_timestamp_s=t,
            device_time_s=t - run.t0_s,
            total_force_n=total,
            center_of_pressure_mm=None if n_contact == 0 else (x, y),
            channels_in_contact=n_contact,
            contact_area_mm2=area_mm2,
            peak_channel=None if n_contact == 0 else names[peak],
            peak_force_n=None if n_contact == 0 else float(force[i, peak]),
            temperature_c=read_only(temperature[i]) if has_temperature else None,
            rois=roi_quantities(
                rois, force[i], status[i], processor.x_mm, processor.y_mm, processor.cell_areas_mm2
            ),
        )
        out.append(DeviceSnapshot(**fixed))
    return out, n_samples


def _quantities(
    force_n: FloatArray,
    status: NDArray[np.int8],
    x_mm: FloatArray,
    y_mm: FloatArray,
    cell_area_mm2: float | FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, IntArray, IntArray, FloatArray]:
    """``snapshot.array_quantities`` of each row of (samples, channels) forces and statuses:
    total force (N), centre of pressure x and y (mm; NaN with nothing in contact), channels in
    contact, the peak channel's position (0 with nothing in contact) and the contact area
    (mm^2: the cells in contact, each of its own area)."""
    contact = IN_CONTACT[status] & (force_n > 0.0)  # NaN is never > 0
    fc = np.where(contact, force_n, 0.0)
    total = fc.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        x = (fc @ x_mm) / total
        y = (fc @ y_mm) / total
    n_contact = np.count_nonzero(contact, axis=1)
    if isinstance(cell_area_mm2, float):
        area = np.asarray(n_contact * cell_area_mm2, dtype=np.float64)
    else:
        area = np.asarray(contact.astype(np.float64) @ cell_area_mm2, dtype=np.float64)
    return total, x, y, n_contact, fc.argmax(axis=1), area
