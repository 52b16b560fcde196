"""Conversion of one poll of a device: registers -> resistance -> drift-corrected force.

Pure (no I/O, no clocks: times are passed in). Per channel:

1. Resistance. ``adc`` devices report divider counts; eq. 18 gives the sensor resistance
   ``r = R_ref (full_scale / counts - 1)`` (``Divider.resistance``), 0 counts meaning an open
   sensor and full scale a short. ``float32`` devices report the resistance in ohm directly
   (+inf open, 0 short). The device's open/short/saturated bitmaps, when configured, take
   precedence over what the values say.
2. Force. Channels are grouped by their effect set; each group has one ``SensorModel`` with
   per-channel parameters. ``SensorModel.track`` inverts the resistance with the creep state
   relaxed over the time since the channel's last sample (the device clock when the device
   reports one, else the host's), so a held force reads constant although the resistance
   keeps falling by creep. ``invert_static`` (no creep state) is kept for diagnostics: its
   error grows with hold time (about +10 % after 10 min at 2 N for the default sensor).
   It is evaluated when first asked for (``DeviceSnapshot.force_static_n``, e.g. at a
   scrape or by the MQTT frame), once, by that thread under the snapshot's lock, so the poll
   path pays for one inversion, not two (bench/bench_gateway.py favours this over computing
   it here: about 58 us more per 64-channel poll of about 113 us). A channel whose calibration
   gives a line or a lookup (``ChannelConfig.conversion``, ``gateway.model.conversion``) is
   read with it instead, statelessly (no creep state; its static estimate is its force).
   A channel read through a curve (``gateway.model.curves``) is tracked with its drift state.
3. Status per channel: ok, no_contact, saturated, open, short, stale, error, extrapolated.
   A force outside the calibrated range is still read (along the curve, line or lookup, or
   by the physical model over its own, wider range) and flagged ``extrapolated``: the range
   of a curve, line or lookup is its own, and a channel whose calibration file gives
   ``calibrated_min_n``/``calibrated_max_n`` flags any force outside those too.
4. Array quantities from the channel positions (mm): total force (N), centre of pressure
   (force-weighted mean position over channels in contact), contact area (channels in
   contact x pitch^2, mm^2), peak channel.

Everything ends in an immutable ``DeviceSnapshot`` (frozen dataclass, read-only numpy
arrays). Values that are not valid numbers are NaN inside the snapshot, flagged by the
status, and ``DeviceSnapshot.channels()`` / the exporter leave them out: no NaN or inf ever
reaches the metrics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import NDArray

from ..config import ChannelConfig, DeviceConfig, Encoding
from ..errors import DecodeError
from ..modbus.image import RawSample
from ..modbus.special_codes import SPECIAL_ERROR, SPECIAL_SATURATED
from ..model import ModelState, RatioFrontEnd, SensorModel
from ..model.curves import CurveChannel, CurveSet, CurveState, Drift, LineCurve
from .baseline import BaselineCorrection
from .clock import NO_CLOCK_HISTORY, ClockHealth, time_step
from .converters import Converter, CurveConverter, PhysicsConverter, Step
from .dead_taxels import NO_COUNTS, DeadState, tracker_for
from .rois import roi_quantities, roi_slots
from .snapshot import (
    VALUED,
    DeviceSnapshot,
    StaticEstimate,
    array_quantities,
    frozen_copy,
    read_only,
)
from .status_tables import (
    _BASE_FROM_BITMAPS,
    _BASE_FROM_DIVIDER,
    _BIG_OHM,
    _CHANNEL_ERROR,
    _CHANNEL_NO_CONTACT,
    _CHANNEL_NO_ZERO,
    _CHANNEL_OK,
    _CHANNEL_OPEN,
    _CHANNEL_SATURATED,
    _CHANNEL_SHORT,
    _CHANNEL_STALE,
    _CHANNEL_UNCALIBRATED,
    _FINAL_STATUS,
    _FORCE_EXTRAPOLATED,
    _FORCE_INVALID,
    _FORCE_OK,
    _FORCE_SATURATED,
    _TINY_OHM,
    FINAL_BASE_STRIDE,
    _adc_tables,
)

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]


@dataclass(frozen=True)
class DeviceState:
    """What a device's conversion carries from one poll to the next (immutable)."""

    model_state: ModelState  # one entry per enabled channel
    last_time_s: float | None = None  # device clock (or host monotonic clock) of the last sample
    last_host_time_s: float | None = None
    time_from_device: bool = False
    last: DeviceSnapshot | None = None
    clock: ClockHealth = NO_CLOCK_HISTORY
    #: the drift state of the channels read through a curve (``gateway.model.curves``)
    curve_state: CurveState | None = None
    #: the dead-taxel tracker's state (``runtime.dead_taxels``; None: none yet)
    dead: DeadState | None = None


def state_arrays(state: ModelState) -> list[FloatArray]:
    """Copies of every per-channel array of a ``ModelState``, in field order."""
    return [np.array(getattr(state, f.name), dtype=np.float64, copy=True) for f in fields(ModelState)]


def state_from_arrays(arrays: Sequence[FloatArray]) -> ModelState:
    return ModelState(**{f.name: a for f, a in zip(fields(ModelState), arrays, strict=True)})


def channel_key(device: DeviceConfig, channel: ChannelConfig) -> tuple[object, ...]:
    """Identity of a channel's physics: its creep state may only be reused when all match."""
    return (device.name, device.encoding, channel.index, tuple(channel.effects), channel.params) + (
        () if channel.conversion is None else (channel.conversion,)
    )


@dataclass(frozen=True)
class _StaticWithConversions(StaticEstimate):
    """A static estimate whose converted channels (stateless) read their force."""

    converted: NDArray[np.intp]
    force_n: FloatArray

    def evaluate(self) -> FloatArray:
        out = np.array(super().evaluate())
        out[self.converted] = self.force_n[self.converted]
        return read_only(out)


@dataclass(frozen=True, eq=False)
class TrackedSample:
    """A poll between ``DeviceProcessor.track`` and ``DeviceProcessor.finish``: per
    channel the resistance to report and the one the model got (ohm), the base status,
    the model's force (N) and ``ForceStatus``; the device state after the sample (its
    ``last`` snapshot is set by ``finish``)."""

    raw: RawSample
    resistance_ohm: FloatArray
    model_resistance_ohm: FloatArray
    base_status: StatusArray
    force_n: FloatArray
    model_status: StatusArray
    temperature_c: FloatArray | None
    state: DeviceState
    wall_time_s: float
    #: the static (not drift-corrected) force of every converted channel (N), NaN elsewhere
    converted_static_n: FloatArray | None = None
    #: channels without a zero read at the converter's idle floor (None: none)
    unzeroed: NDArray[np.bool_] | None = None


class DeviceProcessor:
    """Converts polls of one device. Holds only immutable configuration-derived objects."""

    def __init__(self, device: DeviceConfig, bus: str, poll_interval_s: float) -> None:
        self.device = device
        self.bus = bus
        self.poll_interval_s = float(poll_interval_s)
        chans = [c for c in device.channels if c.enabled]
        self.channels: tuple[ChannelConfig, ...] = tuple(chans)
        self.index = np.array([c.index for c in chans], dtype=np.int64)
        self.names = tuple(c.name for c in chans)
        self.x_mm = np.array([c.x_mm for c in chans], dtype=np.float64)
        self.y_mm = np.array([c.y_mm for c in chans], dtype=np.float64)
        for a in (self.index, self.x_mm, self.y_mm):
            a.setflags(write=False)
        # the calibrated force range of each channel that has one (else 0 N to inf: none)
        ranged = [c.calibrated_range_n for c in chans]
        self._calibrated: tuple[FloatArray, FloatArray] | None = None
        if any(r is not None for r in ranged):
            self._calibrated = (
                frozen_copy(np.array([0.0 if r is None else r[0] for r in ranged], dtype=np.float64)),
                frozen_copy(np.array([np.inf if r is None else r[1] for r in ranged], dtype=np.float64)),
            )
        # every channel is read by one converter (``converters``): a device that reports its own
        # calibrated force or pressure through the identity curve (our drift correction on top
        # when the configuration gives one), a channel with a calibration table through its
        # curve, the others by the physical model, one group per effect set
        self.output = device.encoding is Encoding.OUTPUT
        if self.output:
            identity = CurveChannel(LineCurve(1.0, 0.0), device.output_drift or Drift())
            curves = [(k, identity) for k in range(len(chans))]
        else:
            curves = [(k, c.conversion) for k, c in enumerate(chans) if c.conversion is not None]
        self.curves = CurveSet([c for _, c in curves], [k for k, _ in curves]) if curves else None
        self._curve_keys = tuple(
            channel_key(device, chans[k]) for k in (() if self.curves is None else self.curves.positions)
        )
        by_effects: dict[tuple[str, ...], list[int]] = {}
        for k, c in enumerate(chans):
            # an uncalibrated channel's force would be thrown away: no model runs for it
            if c.conversion is None and not self.output and not device.needs_calibration(c):
                by_effects.setdefault(tuple(c.effects), []).append(k)
        self.groups: tuple[tuple[NDArray[np.intp], SensorModel], ...] = tuple(
            (np.array(ks, dtype=np.intp), SensorModel(effects, [chans[k].params for k in ks]))
            for effects, ks in by_effects.items()
        )
        everyone = np.arange(len(chans))
        self.converters: tuple[Converter, ...] = tuple(
            PhysicsConverter(ks, model, bool(np.array_equal(ks, everyone))) for ks, model in self.groups
        ) + (() if self.curves is None else (CurveConverter(self.curves, from_output=self.output),))
        self.keys = tuple(channel_key(device, c) for c in chans)
        # the force each channel reads at the short rail (saturated), from its converter
        top = np.full(len(chans), np.nan)
        for conv in self.converters:
            top[conv.positions] = conv.top_n()
        self._top_n = frozen_copy(top)
        # the enabled channels as a slice when they are all of them, in order (no copy)
        every = np.array_equal(self.index, np.arange(device.n_channels))
        self._pick: slice | NDArray[np.int64] = slice(None) if every else self.index
        self._no_values = frozen_copy(np.full(len(chans), np.nan))
        r0 = np.full(len(chans), np.inf)
        for ks, model in self.groups:
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                r0[ks] = model.resistance(np.zeros(len(ks)))
        if self.curves is not None:  # where a calibrated channel reads 0 N
            r0[self.curves.positions] = [c.unloaded_resistance_ohm for c in self.curves.channels]
        self._baseline = BaselineCorrection.of([c.baseline_ohm for c in chans], r0)
        # ADC channels without a zero (no baseline, nothing but default parameters): a force
        # read at the converter's idle floor may be the board's offset, and reads NO_ZERO
        self._unzeroed: NDArray[np.bool_] | None = None
        if device.encoding is Encoding.ADC:
            unzeroed = np.array(
                [c.baseline_ohm is None and c.conversion is None and c.params_source == ("defaults",)
                 for c in chans], dtype=np.bool_,
            )  # fmt: skip
            self._unzeroed = frozen_copy(unzeroed) if unzeroed.any() else None
        # channels with nothing to read force with (a ratio front end's, uncalibrated): a
        # reading, no force
        uncalibrated = np.array([device.needs_calibration(c) for c in chans], dtype=np.bool_)
        self._uncalibrated = frozen_copy(uncalibrated) if uncalibrated.any() else None
        self._relative = device.encoding is Encoding.ADC and isinstance(device.front_end, RatioFrontEnd)
        self._dead = tracker_for(device, self.index)
        areas = device.cell_areas_mm2
        self._cell_areas_mm2: float | FloatArray = (
            areas
            if isinstance(areas, float)
            else frozen_copy(np.asarray(areas, dtype=np.float64)[self.index])
        )
        self._rois = roi_slots(device.rois, self.index)
        # the rails are readings (``rails = "readings"``): read as with the device's bitmaps
        self._rails_read = device.rails == "readings"

    @property
    def cell_areas_mm2(self) -> float | FloatArray:
        """The cell area (mm^2): one for every cell, or one per enabled channel (regions)."""
        return self._cell_areas_mm2

    def _tare(self, r_model: FloatArray) -> FloatArray:
        """``r_model`` with each baseline channel's excess conductance taken off."""
        return r_model if self._baseline is None else self._baseline.apply(r_model)

    @property
    def name(self) -> str:
        return self.device.name

    def initial_state(self) -> DeviceState:
        """The state of a device whose load history is not known: every channel, read by the
        physical model or a calibration table, starts from the equilibrium at its first valid
        sample's load (``SensorModel.unknown_state``, ``CurveSet.initial_state``), never from rest."""
        n = len(self.channels)
        return DeviceState(ModelState.zeros(n).updated({"last_force_n": np.full(n, np.nan)}))

    def rested_state(self) -> DeviceState:
        """The state of a device known to have been unloaded long enough to settle."""
        curves = None if self.curves is None else self.curves.rested_state()
        return DeviceState(ModelState.zeros(len(self.channels)), curve_state=curves)

    def carry_state(self, old: DeviceProcessor, state: DeviceState) -> DeviceState:
        """State for this (new) configuration from an old one: channels whose device,
        index, effects and parameters are unchanged keep their creep state; others start from
        the equilibrium at their first load (``initial_state``). The clock and the last
        snapshot carry over when the device is the same."""
        fresh = self.initial_state().model_state
        arrays = state_arrays(fresh)
        old_pos = {k: i for i, k in enumerate(old.keys)}
        kept = 0
        for i, key in enumerate(self.keys):
            j = old_pos.get(key)
            if j is None:
                continue
            kept += 1
            src = state.model_state
            for dst, s in zip(arrays, state_arrays(src), strict=True):
                dst[i] = s[j]
        model_state = state_from_arrays(arrays)
        if kept == 0:
            return DeviceState(model_state)
        last = state.last if state.last is not None and state.last.channel_names == self.names else None
        # curve channels keep their drift state only when every one of them is unchanged
        curve_state = state.curve_state if self._curve_keys == old._curve_keys else None
        return DeviceState(
            model_state,
            state.last_time_s,
            state.last_host_time_s,
            state.time_from_device,
            last,
            state.clock,
            curve_state,
        )

    def kept_channels(self, old: DeviceProcessor) -> int:
        return len(set(self.keys) & set(old.keys))

    # ------------------------------------------------------------------ one poll
    def _resistance(self, raw: RawSample) -> tuple[FloatArray, FloatArray, StatusArray]:
        """Resistance to report (ohm; NaN where there is none: invalid or open), the
        resistance given to the model, and the base status (OK / OPEN / SHORT / ERROR).

        The rails mean open (0 counts, +inf ohm) and short (full scale, 0 ohm) only when the
        device reports no fault bitmaps. With bitmaps the device says which channels are
        faulty, and a rail is a reading: no current at rest (a sensor whose contact is open
        reads no contact, 0 N) or less resistance than the converter resolves (saturated).
        """
        idx = self._pick
        if raw.counts is not None:
            counts = raw.counts[idx]
            if counts.dtype == np.uint16:  # register values: every quantity is a lookup
                table = _adc_tables(self.device.front_end)
                r_out, dstat = table.report_ohm[counts], table.status[counts]
            else:
                r, dstat = self.device.front_end.resistance(counts)
                table = None
                r_out = np.where(r == np.inf, np.nan, r)  # the open rail has no resistance value
            if raw.open_bits is None and raw.short_bits is None and not self._rails_read:
                r_model = table.model_ohm[counts] if table is not None else r
                return r_out, r_model, _BASE_FROM_DIVIDER[dstat]
            code = dstat * np.int8(4)
            if raw.open_bits is not None:
                code += raw.open_bits[idx].view(np.int8) * np.int8(2)
            if raw.short_bits is not None:
                code += raw.short_bits[idx].view(np.int8)
            # with bitmaps a rail is a reading: inf -> no current at rest, 0 -> saturated
            if table is not None:
                r_model = table.model_with_bitmaps_ohm[counts]
            else:
                r_model = np.minimum(np.maximum(r, _TINY_OHM), _BIG_OHM)
            return r_out, r_model, _BASE_FROM_BITMAPS[code]
        if raw.resistance_ohm is None:
            raise DecodeError("a sample needs ADC counts or resistances")
        status = np.full(len(self.index), _CHANNEL_OK, dtype=np.int8)
        r = np.asarray(raw.resistance_ohm[idx], dtype=np.float64)
        with np.errstate(invalid="ignore"):
            rail_open = np.isposinf(r)
            rail_short = r == 0.0
            status[np.isnan(r) | np.isneginf(r) | (r < 0.0)] = _CHANNEL_ERROR
            r_out = np.where(np.isfinite(r) & (r >= 0.0), r, np.nan)
        if raw.open_bits is None and raw.short_bits is None and not self._rails_read:
            status[rail_open] = _CHANNEL_OPEN
            status[rail_short] = _CHANNEL_SHORT
            return r_out, r, status
        r_model = np.where(rail_open, _BIG_OHM, np.where(rail_short, _TINY_OHM, r))
        if raw.open_bits is not None:
            status[raw.open_bits[idx]] = _CHANNEL_OPEN
        if raw.short_bits is not None:
            status[raw.short_bits[idx] & (status != _CHANNEL_OPEN)] = _CHANNEL_SHORT
        return r_out, r_model, status

    def _dt(
        self, state: DeviceState, raw: RawSample, host_time_s: float
    ) -> tuple[float, float, bool, ClockHealth]:
        """Seconds since the previous sample (see ``clock.time_step``)."""
        return time_step(
            self.device.registers.clock,
            state.clock,
            raw.device_time_s,
            raw.device_ticks,
            state.last_time_s,
            state.last_host_time_s,
            state.time_from_device,
            host_time_s,
        )

    def process(
        self,
        state: DeviceState,
        raw: RawSample,
        wall_time_s: float,
        host_time_s: float,
        step_s: FloatArray | None = None,
    ) -> tuple[DeviceSnapshot, DeviceState]:
        """Convert one good poll. ``host_time_s`` is a monotonic clock, ``wall_time_s`` Unix time.

        The same as ``finish(track(...))``; the two steps exist so that a caller can run
        them at different moments (the poller runs each while a device answers).
        """
        return self.finish(self.track(state, raw, wall_time_s, host_time_s, step_s))

    def track(
        self,
        state: DeviceState,
        raw: RawSample,
        wall_time_s: float,
        host_time_s: float,
        step_s: FloatArray | None = None,
    ) -> TrackedSample:
        """First step of ``process``: resistances and drift-corrected forces.

        The rails are read once, here, before any converter: without fault bitmaps a rail is
        the channel's base status (open, short); with them the open rail is no current at rest
        (+inf ohm: no contact) and the short rail less resistance than the converter resolves,
        which reads saturated at the channel's top, without a sample for its state.

        ``step_s`` (s, one per enabled channel) replaces the clock's step for each channel: a
        replay of channels sampled at their own times (``runtime.replay``); the poller gives none."""
        n = len(self.channels)
        dt: float | FloatArray
        dt, now, use_device, clock_health = self._dt(state, raw, host_time_s)
        if step_s is not None:
            dt = step_s
        temperature = None if raw.temperature_c is None else raw.temperature_c[self._pick]
        apparent = None
        if self.output:
            apparent = self._output_force(raw)
            bad = ~np.isfinite(apparent)
            base = np.where(bad, np.int8(_CHANNEL_ERROR), np.int8(_CHANNEL_OK)).astype(np.int8)
            apparent = np.where(bad, np.nan, apparent)
            r_out = r_model = np.full(n, np.nan)
            short = None
        else:
            r_out, r_model, base = self._resistance(raw)
            r_model = self._tare(r_model)
            usable = base == _CHANNEL_OK
            if not usable.all():
                r_model = np.where(usable, r_model, np.nan)
            with np.errstate(invalid="ignore"):
                short = (r_model > 0.0) & (r_model <= _TINY_OHM)
                r_model = np.where(r_model >= _BIG_OHM, np.inf, r_model)
            if short.any():
                r_model = np.where(short, np.nan, r_model)
            else:
                short = None
        step = Step(
            r_model, temperature, dt, state.model_state, state.curve_state,
            np.full(n, np.nan), np.full(n, _FORCE_INVALID, dtype=np.int8), np.full(n, np.nan), apparent,
        )  # fmt: skip
        for conv in self.converters:
            conv.track(step)
        force, model_status = step.force_n, step.status
        if short is not None:
            force = np.where(short, self._top_n, force)
            model_status = np.where(short, np.int8(_FORCE_SATURATED), model_status)
        if self._calibrated is not None:
            # a force read inside the model's (or curve's, line's, lookup's) own range but
            # outside the range the channel was calibrated on is extrapolated
            low, high = self._calibrated
            with np.errstate(invalid="ignore"):
                outside = (model_status == _FORCE_OK) & ((force < low) | (force > high))
            if outside.any():
                model_status = np.where(outside, np.int8(_FORCE_EXTRAPOLATED), model_status)
        model_state = state.model_state if step.new_model is None else state_from_arrays(step.new_model)
        curve_state = step.new_curve_state if step.new_curve_state is not None else state.curve_state
        static = None if self.curves is None else step.static_n
        return TrackedSample(
            raw, r_out, r_model, base, force, model_status, temperature,
            DeviceState(
                model_state, now, host_time_s, use_device, None, clock_health, curve_state, state.dead
            ),
            wall_time_s, static, None if self.output else self._idle_unzeroed(raw),
        )  # fmt: skip

    def _idle_unzeroed(self, raw: RawSample) -> NDArray[np.bool_] | None:
        """The channels without a zero whose counts lie at the converter's idle floor."""
        if self._unzeroed is None or raw.counts is None:
            return None
        counts = raw.counts[self._pick]
        front_end = self.device.front_end
        if counts.dtype == np.uint16:
            floor = _adc_tables(front_end).idle_floor[counts]
        else:
            low, high = front_end.idle_floor_codes()
            floor = (counts >= low) & (counts <= high)
        unzeroed = self._unzeroed & floor
        return unzeroed if unzeroed.any() else None

    def _output_force(self, raw: RawSample) -> FloatArray:
        """The device's own output as force (N): a pressure (kPa) acts on the cell's area."""
        if raw.output_force_n is not None:
            return np.asarray(raw.output_force_n[self._pick], dtype=np.float64)
        if raw.output_pressure_kpa is not None:
            area_mm2 = self._cell_areas_mm2
            return np.asarray(raw.output_pressure_kpa[self._pick], dtype=np.float64) * (area_mm2 * 1e-3)
        raise DecodeError("a device with a calibrated output needs its force or pressure values")

    def finish(self, tracked: TrackedSample) -> tuple[DeviceSnapshot, DeviceState]:
        """Second step of ``process``: statuses, array quantities and the snapshot."""
        raw, base, temperature = tracked.raw, tracked.base_status, tracked.temperature_c
        clock = tracked.state.clock
        # at most 16 * 6 + 2 * 4 + 1 = 105: an int8 (status_tables.FINAL_BASE_STRIDE)
        code = base * np.int8(FINAL_BASE_STRIDE) + tracked.model_status * np.int8(2)
        if raw.saturated_bits is not None:
            code += raw.saturated_bits[self._pick].view(np.int8)
        status = _FINAL_STATUS[code]
        if tracked.unzeroed is not None:
            status = np.where(tracked.unzeroed & (status == _CHANNEL_OK), np.int8(_CHANNEL_NO_ZERO), status)
        if self._uncalibrated is not None:
            # a reading (the read-out's verdict is OK), no model: uncalibrated; but no current
            # at all (the open rail read as rest, or at or below the zero) is no contact under
            # any calibration
            readable = self._uncalibrated & (base == _CHANNEL_OK)
            resting = readable & np.isposinf(tracked.model_resistance_ohm)
            beyond = readable & np.isnan(tracked.model_resistance_ohm)  # the short rail as a reading
            status = np.where(readable, np.int8(_CHANNEL_UNCALIBRATED), status)
            status = np.where(resting, np.int8(_CHANNEL_NO_CONTACT), status)
            status = np.where(beyond, np.int8(_CHANNEL_SATURATED), status)
            force_n = np.where(resting, 0.0, np.where(beyond, np.nan, tracked.force_n))
        else:
            force_n = tracked.force_n
        special = None if raw.special is None or not raw.special.any() else raw.special[self._pick]
        if special is not None:  # declared codes: statuses, never forces
            status = np.where(special == SPECIAL_SATURATED, np.int8(_CHANNEL_SATURATED), status)
            status = np.where(special == SPECIAL_ERROR, np.int8(_CHANNEL_ERROR), status)
        dead_state, dead, dead_by_region = tracked.state.dead, None, NO_COUNTS
        if self._dead is not None:
            now_s = tracked.state.last_host_time_s
            dead_state, dead, dead_by_region = self._dead.step(tracked.state.dead, raw, self._pick, now_s)
            status = np.where(dead, np.int8(_CHANNEL_ERROR), status)
        valued = VALUED[status]
        force = np.where(valued, force_n, np.nan)
        if special is not None:
            force = np.where(special != 0, np.nan, force)
        reference = self._no_values
        if raw.reference_force_n is not None:
            reference = read_only(np.array(raw.reference_force_n[self._pick], dtype=np.float64))
        q = array_quantities(force, status, self.x_mm, self.y_mm, self._cell_areas_mm2)
        wall_time_s = tracked.wall_time_s
        inputs = (
            self.groups,
            read_only(tracked.model_resistance_ohm),
            temperature,
            read_only(valued),
            read_only(force),
        )
        static: StaticEstimate
        if self.curves is None:
            static = StaticEstimate(*inputs)
        else:
            by_channel = tracked.converted_static_n if tracked.converted_static_n is not None else force
            static = _StaticWithConversions(
                *inputs, self.curves.positions, read_only(np.where(valued, by_channel, np.nan))
            )
        snap = DeviceSnapshot(
            device=self.device.name,
            bus=self.bus,
            channel_index=self.index,
            channel_names=self.names,
            x_mm=self.x_mm,
            y_mm=self.y_mm,
            resistance_ohm=read_only(tracked.resistance_ohm),
            force_n=read_only(force),
            static_estimate=static,
            reference_force_n=reference,
            status=read_only(status),
            up=True,
            timestamp_s=wall_time_s,
            last_success_timestamp_s=wall_time_s,
            device_time_s=raw.device_time_s,
            poll_interval_s=self.poll_interval_s,
            time_source="device" if tracked.state.time_from_device else "host",
            clock_faults=(("stuck", clock.stuck), ("backwards", clock.backwards)),
            clock_fallback=self._clock_fallback(raw, clock),
            total_force_n=q.total_force_n,
            center_of_pressure_mm=q.center_of_pressure_mm,
            channels_in_contact=q.channels_in_contact,
            contact_area_mm2=q.contact_area_mm2,
            peak_channel=None if q.peak_index is None else self.names[q.peak_index],
            peak_force_n=q.peak_force_n,
            temperature_c=None
            if temperature is None
            else read_only(np.asarray(temperature, dtype=np.float64)),
            resistance_relative=self._relative,
            dead=None if dead is None else read_only(dead),
            dead_by_region=dead_by_region,
            rois=roi_quantities(self._rois, force, status, self.x_mm, self.y_mm, self._cell_areas_mm2),
        )
        s = tracked.state
        return snap, replace(s, last=snap, dead=dead_state)

    def _clock_fallback(self, raw: RawSample, clock: ClockHealth) -> str | None:
        """Why a device whose map names a clock is timed by the host clock (None if it is not)."""
        if self.device.registers.clock is None:
            return None
        if clock.fallback is not None:
            return clock.fallback
        return "unreadable" if raw.device_time_s is None else None

    def stale(self, state: DeviceState, wall_time_s: float, error: str) -> tuple[DeviceSnapshot, DeviceState]:
        """The device did not answer: keep the last values, mark every channel stale.

        The creep state is not advanced; the next good sample relaxes it over the whole gap.
        """
        n = len(self.channels)
        stale_status = frozen_copy(np.full(n, _CHANNEL_STALE, dtype=np.int8))
        last = state.last
        if last is None:
            nan = frozen_copy(np.full(n, np.nan))
            snap = DeviceSnapshot(
                device=self.device.name,
                bus=self.bus,
                channel_index=frozen_copy(self.index),
                channel_names=self.names,
                x_mm=frozen_copy(self.x_mm),
                y_mm=frozen_copy(self.y_mm),
                resistance_ohm=nan,
                force_n=nan,
                static_estimate=None,
                reference_force_n=nan,
                status=stale_status,
                up=False,
                timestamp_s=wall_time_s,
                last_success_timestamp_s=None,
                device_time_s=None,
                poll_interval_s=self.poll_interval_s,
                error=error,
                resistance_relative=self._relative,
            )
        else:
            snap = replace(last, status=stale_status, up=False, timestamp_s=wall_time_s, error=error)
        return snap, state
