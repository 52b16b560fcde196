"""Recorded samples replayed through a ``DeviceProcessor``, one device sample at a time.

The input is one series per enabled channel of the processor (in its order): times (s,
non-decreasing), resistances (ohm; ``inf`` for no current), and optionally the reference
force and the temperature. ``replay`` groups them into device samples and runs
``DeviceProcessor.process`` on each, as the poller does on each poll:

* **Grouping.** Samples of equal time across channels are one device sample; a channel's
  k-th sample at a time goes into the k-th device sample at that time (repeated times step
  by 0 s).
* **Clock.** Each sample carries its time, less the first time of all, as the device clock's
  reading (``device_time_s``, and as the host clock), so ``clock.time_step`` steps the state
  by the recorded time step when the device names a clock (``config.calibration_file``'s
  device has a 64-bit nanosecond one: the step is the recorded one to 1 ns).
* **A channel without a sample at a device sample** reads NaN there. The processor reads NaN
  as an invalid value: status ``error``, no force, the held force kept and the state relaxed
  over the step with that force held. Relaxing with a constant held force is exact
  (``SensorModel.relax``, the curves' Kelvin steps), so relaxing over dt1 then dt2 equals
  relaxing over dt1 + dt2 (to rounding), and the hysteresis play does not move with the
  same force recorded again: at its next sample the channel's state is the one it would have
  had sampled alone. These NaN readings are not samples and are not returned. (``stale``
  keeps every channel's state, but it marks a device that did not answer at all; it cannot
  keep one channel's state while another's advances.)
* **Span.** Times spanning more than ``MAX_REPLAY_SPAN_S`` (584 years: a 64-bit nanosecond
  clock), or not finite, are a ``ReplayError``: no device clock counts them.
* **Fault bitmaps.** Every sample reports open and short bitmaps with no channel faulty, so
  a rail is a reading, as the gateway reads it from a device with bitmaps: ``inf`` (no
  current: the contact open at rest) reads no contact, 0 N.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..modbus.image import RawSample
from .processor import DeviceProcessor
from .snapshot import ChannelStatus, DeviceSnapshot

__all__ = ["MAX_REPLAY_SPAN_S", "ChannelSeries", "ReplayError", "ReplayedChannel", "replay"]

#: The longest time a replay spans (s): what a 64-bit nanosecond clock counts, 584 years
MAX_REPLAY_SPAN_S = 2**64 * 1e-9


class ReplayError(ValueError):
    """Series a replay cannot step through (the message is one line for the user)."""


FloatArray = NDArray[np.float64]


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
    (``DeviceSnapshot.force_static_n``, N) and the ``ChannelStatus`` code; NaN forces where
    the status carries none."""

    force_n: FloatArray
    force_static_n: FloatArray
    status: NDArray[np.int8]


def _occurrence(time_s: FloatArray) -> NDArray[np.int64]:
    """For each sample, how many earlier samples of its series have the same time."""
    first = np.searchsorted(time_s, time_s, side="left")
    return np.arange(time_s.size, dtype=np.int64) - first.astype(np.int64)


def _joined(series: Sequence[ChannelSeries], field: str) -> FloatArray | None:
    parts = [getattr(s, field) for s in series]
    if any(p is None for p in parts):
        return None
    return np.concatenate([np.asarray(p, dtype=np.float64) for p in parts])


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


def replay(
    processor: DeviceProcessor,
    series: Sequence[ChannelSeries],
    on_snapshot: Callable[[DeviceSnapshot], None] | None = None,
) -> tuple[tuple[ReplayedChannel, ...], int]:
    """Run ``processor`` over ``series`` (one per enabled channel, in the processor's order;
    see the module docstring): what it read at each sample, and the number of device samples.
    ``on_snapshot`` is given each device sample's snapshot, in time order."""
    k = len(series)
    if k != len(processor.channels):
        raise ValueError(f"{k} series for a processor of {len(processor.channels)} channels")
    for s in series:
        steps = np.diff(np.asarray(s.time_s, dtype=np.float64))
        if bool(np.any(steps < 0.0)):
            raise ValueError("a series' times go backwards")
    _check_span(series)
    n_device = processor.device.n_channels
    which = np.concatenate([np.full(len(s.time_s), j, dtype=np.intp) for j, s in enumerate(series)])
    times = np.concatenate([np.asarray(s.time_s, dtype=np.float64) for s in series])
    occurrence = np.concatenate([_occurrence(np.asarray(s.time_s, dtype=np.float64)) for s in series])
    resistance = np.concatenate([np.asarray(s.resistance_ohm, dtype=np.float64) for s in series])
    reference, temps = _joined(series, "reference_force_n"), _joined(series, "temperature_c")
    # the processor reads channel j of the device at its enabled position j
    position = processor.index[which] if which.size else which
    order = np.lexsort((which, occurrence, times))
    t_sorted, o_sorted = times[order], occurrence[order]
    new = np.ones(order.size, dtype=bool)
    new[1:] = (t_sorted[1:] != t_sorted[:-1]) | (o_sorted[1:] != o_sorted[:-1])
    starts = np.flatnonzero(new)
    stops = np.append(starts[1:], order.size)
    force = np.full(order.size, np.nan)
    static = np.full(order.size, np.nan)
    status = np.full(order.size, int(ChannelStatus.ERROR), dtype=np.int8)
    no_fault = np.zeros(n_device, dtype=bool)
    t0 = float(t_sorted[0]) if order.size else 0.0
    state = processor.initial_state()
    for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
        rows = order[a:b]
        slots = position[rows]
        r = np.full(n_device, np.nan)
        r[slots] = resistance[rows]
        ref = temp = None
        if reference is not None:
            ref = np.full(n_device, np.nan)
            ref[slots] = reference[rows]
        if temps is not None:
            temp = np.full(n_device, np.nan)
            temp[slots] = temps[rows]
        t = float(t_sorted[a])
        clock_s = t - t0
        raw = RawSample(
            resistance_ohm=r,
            open_bits=no_fault,
            short_bits=no_fault,
            temperature_c=temp,
            reference_force_n=ref,
            device_time_s=clock_s,
        )
        snap, state = processor.process(state, raw, wall_time_s=t, host_time_s=clock_s)
        if on_snapshot is not None:
            on_snapshot(snap)
        mine = which[rows]
        force[rows] = snap.force_n[mine]
        static[rows] = snap.force_static_n[mine]
        status[rows] = snap.status[mine]
    bounds = np.cumsum([0, *(len(s.time_s) for s in series)]).tolist()
    out = tuple(
        ReplayedChannel(force[lo:hi].copy(), static[lo:hi].copy(), status[lo:hi].copy())
        for lo, hi in itertools.pairwise(bounds)
    )
    return out, int(starts.size)
