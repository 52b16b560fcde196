"""The converters of a device's channels: one interface, state in, force and status out.

Every enabled channel is read by exactly one converter:

* ``PhysicsConverter``: a group of channels with one effect set, read by the physical model
  (``SensorModel.track``, drift-corrected inversion), its state the group's rows of the
  device's ``ModelState``;
* ``CurveConverter``: every channel with a calibration table (line, lookup or curve: one
  ``CurveChannel`` form, ``gateway.model.tracker.CurveSet``), or every channel of a device that
  reports its own calibrated output (the device's reading is the apparent force, only the
  drift is corrected), its state a ``CurveState``.

The processor applies the rail and status rules once, before any converter
(``DeviceProcessor.track``): a converter gets a resistance that is a reading (ohm, +inf for no
current at rest, NaN where there is none), never a rail code, and fills its channels' force
(N), ``ForceStatus`` and static estimate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from ..model import ModelState, SensorModel
from ..model.inversion import ForceStatus
from ..model.tracker import CurveSet, CurveState

__all__ = ["Converter", "CurveConverter", "PhysicsConverter", "Step"]

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]
_EXTRAPOLATED = np.int8(int(ForceStatus.EXTRAPOLATED))


@dataclass(eq=False)
class Step:
    """One sample of a device on its way through the converters: the inputs (per enabled
    channel: the model's resistance in ohm, the device's own reading x in N for an output
    device, temperatures) and what the converters fill in (force N, status, static estimate N,
    NaN where the physical model's is evaluated later) and the state they leave."""

    resistance_ohm: FloatArray
    temperature_c: FloatArray | None
    dt_s: float | FloatArray  # one step for the device, or one per enabled channel
    model_state: ModelState
    curve_state: CurveState | None
    force_n: FloatArray
    status: StatusArray
    static_n: FloatArray
    apparent_n: FloatArray | None = None
    new_model: list[FloatArray] | None = field(default=None)
    new_curve_state: CurveState | None = None


class Converter(Protocol):
    """Reads the channels at ``positions`` (indices into the device's enabled channels)."""

    positions: NDArray[np.intp]

    def top_n(self) -> FloatArray:
        """The force each channel reads at the short rail (saturated; N, NaN: none)."""
        ...

    def track(self, step: Step) -> None:
        """Fill ``step``'s force, status and static estimate at ``positions``, and its state."""
        ...


class PhysicsConverter:
    """Channels read by the physical model with one effect set."""

    def __init__(self, positions: NDArray[np.intp], model: SensorModel, every: bool) -> None:
        self.positions = positions
        self.model = model
        self.every = every  # the group is every enabled channel, in order

    def top_n(self) -> FloatArray:
        return np.asarray(self.model.params.force_max_n, dtype=np.float64) * np.ones(self.positions.size)

    def track(self, step: Step) -> None:
        idx = self.positions
        temp = step.temperature_c
        if temp is not None and not self.model.has("temperature"):
            temp = None
        ms = step.model_state
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            if self.every:
                inv, new = self.model.track(step.resistance_ohm, ms, step.dt_s, temp)
            else:
                dt = step.dt_s[idx] if isinstance(step.dt_s, np.ndarray) else step.dt_s
                inv, new = self.model.track(
                    step.resistance_ohm[idx], ms.select(idx), dt, None if temp is None else temp[idx]
                )
        step.force_n[idx] = inv.force_n
        step.status[idx] = inv.status
        if self.every:
            step.new_model = [np.asarray(getattr(new, f), dtype=np.float64) for f in _FIELDS]
            return
        if step.new_model is None:
            step.new_model = [np.array(getattr(ms, f), dtype=np.float64, copy=True) for f in _FIELDS]
        for dst, f in zip(step.new_model, _FIELDS, strict=True):
            dst[idx] = getattr(new, f)


_FIELDS = tuple(ModelState.__dataclass_fields__)


class CurveConverter:
    """Channels read through ``CurveChannel`` forms (``CurveSet``), from their resistance or,
    for a device's own calibrated output, from the device's reading itself."""

    def __init__(self, curves: CurveSet, *, from_output: bool = False) -> None:
        self.curves = curves
        self.positions = curves.positions
        self.from_output = from_output

    def top_n(self) -> FloatArray:
        return np.asarray(np.where(np.isfinite(self.curves.high), self.curves.high, np.nan))

    def track(self, step: Step) -> None:
        pos = self.positions
        state = step.curve_state or self.curves.initial_state()
        dt = step.dt_s[pos] if isinstance(step.dt_s, np.ndarray) else step.dt_s
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            if self.from_output:
                assert step.apparent_n is not None
                x_in = step.apparent_n[pos]
                f, st, x, extrapolated, new = self.curves.track_apparent(x_in, state, dt)
            else:
                f, st, x, extrapolated, new = self.curves.track(step.resistance_ohm[pos], state, dt)
        step.force_n[pos] = f
        step.status[pos] = np.where(extrapolated, _EXTRAPOLATED, st)
        # the static estimate reads no contact by the channel's own rule, as the force does
        step.static_n[pos] = np.where(np.isnan(f), np.nan, np.where(x <= self.curves.floor, 0.0, x))
        step.new_curve_state = new
