"""Snapshots: the immutable result of the polls, as the exporter and recorders see it.

A ``DeviceSnapshot`` is the converted last poll of one device: per enabled channel its
resistance (ohm), drift-corrected force (N), status (``ChannelStatus``) and position (mm),
plus the array quantities (total force N, centre of pressure mm, contact area mm^2, peak
channel). A ``GatewaySnapshot`` holds every device's snapshot and counters. Arrays are
read-only; a value that is not a valid number is NaN, flagged by the status, and never
reaches the metrics or a frame: ``finite_or_none`` is the one NaN policy (None where a value is
absent or not finite, optionally rounded) that ``DeviceSnapshot.channels``, the ``Frame``
(``runtime.frame``) and through it the page's and MQTT's JSON use.
"""

from __future__ import annotations

import enum
import math
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Generic, TypeVar, overload

import numpy as np
from numpy.typing import NDArray

from ..modbus.status_word import StatusWordReading
from ..model import SensorModel
from .counters import DeviceCounters

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
StatusArray = NDArray[np.int8]


class ChannelStatus(enum.IntEnum):
    """What one channel's value means in this snapshot."""

    OK = 0  # a force inside the calibrated range (the model's, where none is calibrated)
    NO_CONTACT = 1  # resistance at or above R(force_min), a force <= 0 N, or open at rest: reads 0 N
    SATURATED = 2  # at or beyond force_max (model) or ADC at a rail (device bitmap)
    OPEN = 3  # open circuit (ADC 0 counts, +inf ohm, or the device's open bitmap)
    SHORT = 4  # short circuit (ADC full scale, 0 ohm, or the device's short bitmap)
    STALE = 5  # the device did not answer this poll: values are the last ones
    ERROR = 6  # an invalid value (NaN, negative, out of range): no value
    #: a force (> 0 N, in contact) outside the calibrated range, read along the calibration
    #: beyond it (a curve, line or lookup extended past its ends; the physical model beyond
    #: the forces it was calibrated on): a value, but not a calibrated one
    EXTRAPOLATED = 7
    #: a force read at the converter's idle floor (within 6 % of full scale of the open
    #: level) on a channel without a zero (no baseline, default parameters): it may be the
    #: board's leak or the converter's offset rather than a load. The value is kept, but it
    #: is not counted as contact (total force, area, centre of pressure); tare the channel
    NO_ZERO = 8
    #: a reading without a force: a ``ratio`` front end's channel (r / R_ref of an unknown
    #: reference resistor) with neither a calibration nor parameters of its own, where the
    #: default parameters (ohm) would read a made-up force. The reading is kept (and
    #: recorded, for ``calibrate``); no force, not counted in any array quantity
    UNCALIBRATED = 9

    @property
    def label(self) -> str:
        return self.name.lower()


STATUS_LABELS: tuple[str, ...] = tuple(s.label for s in ChannelStatus)


_G = TypeVar("_G", bound=np.generic)


def read_only(a: NDArray[_G]) -> NDArray[_G]:
    """Mark a freshly built array (no other reference to it) read-only, without a copy."""
    a.setflags(write=False)
    return a


def frozen_copy(a: NDArray[_G]) -> NDArray[_G]:
    """A read-only copy of ``a``."""
    out: NDArray[_G] = np.array(a, copy=True)
    out.setflags(write=False)
    return out


#: The statuses whose channel carries a force (N), and those that count as in contact.
VALUED_STATUSES: tuple[ChannelStatus, ...] = (
    ChannelStatus.OK,
    ChannelStatus.NO_CONTACT,
    ChannelStatus.SATURATED,
    ChannelStatus.EXTRAPOLATED,
    ChannelStatus.NO_ZERO,
)
#: The statuses whose channel carries a reading (a resistance, in ohm or R_ref), with or without a force.
READING_STATUSES: tuple[ChannelStatus, ...] = (*VALUED_STATUSES, ChannelStatus.UNCALIBRATED)
CONTACT_STATUSES: tuple[ChannelStatus, ...] = (
    ChannelStatus.OK,
    ChannelStatus.SATURATED,
    ChannelStatus.EXTRAPOLATED,
)
#: The same as lookup tables by status code.
_STATUS_CODES = np.arange(len(ChannelStatus))
VALUED = frozen_copy(np.isin(_STATUS_CODES, [int(s) for s in VALUED_STATUSES]))
IN_CONTACT = frozen_copy(np.isin(_STATUS_CODES, [int(s) for s in CONTACT_STATUSES]))


@dataclass(frozen=True)
class ChannelView:
    """One channel of a snapshot, with absent values as None (never NaN or inf)."""

    index: int
    name: str
    x_mm: float
    y_mm: float
    status: ChannelStatus
    resistance_ohm: float | None
    force_n: float | None
    force_static_n: float | None
    reference_force_n: float | None


@overload
def finite_or_none(values: float | None, digits: int | None = None) -> float | None: ...
@overload
def finite_or_none(
    values: Iterable[float] | NDArray[np.float64], digits: int | None = None
) -> list[float | None]: ...
def finite_or_none(
    values: float | Iterable[float] | NDArray[np.float64] | None, digits: int | None = None
) -> float | list[float | None] | None:
    """The one NaN policy for what leaves a snapshot (frames, JSON, metrics): a value as a
    float, rounded to ``digits`` decimals if given, or None where it is absent or not finite
    (JSON has no NaN; a metric has no sample). One value gives one value (a numpy scalar is
    a float); an array or iterable gives a list."""
    if values is None or isinstance(values, (float, int, np.number)):
        if values is None or not math.isfinite(values):
            return None
        return float(values) if digits is None else round(float(values), digits)
    if digits is not None and isinstance(values, np.ndarray) and values.dtype == np.float64:
        return _rounded_array(values, digits)
    raw = values.tolist() if isinstance(values, np.ndarray) else values
    finite = math.isfinite
    if digits is None:
        return [float(v) if finite(v) else None for v in raw]
    return [round(float(v), digits) if finite(v) else None for v in raw]


def _rounded_array(values: NDArray[np.float64], digits: int) -> list[float | None]:
    """``[round(v, digits) if finite else None for v in values]``, equal value for value, at a
    quarter of the cost: k = rint(v x 10^digits) is Python's rounded decimal wherever v x
    10^digits lies further than a few units in the last place from a half (the product's own
    rounding cannot move it across one) and k is an exact integer (below 2^52); then
    k / 10^digits, one correctly rounded division, is the double nearest that decimal, as
    ``round`` gives. The other values (near a half, huge, not finite) go through ``round``."""
    scale = 10.0**digits
    flat = np.ravel(values)
    with np.errstate(invalid="ignore", over="ignore"):
        scaled = flat * scale
        k = np.rint(scaled)
        magnitude = np.abs(scaled)
        exact = (np.abs(np.abs(scaled - k) - 0.5) > 4.0 * np.spacing(magnitude)) & (magnitude < 2.0**52)
    out: list[float | None] = (k / scale).tolist()
    if not exact.all():
        for i in np.flatnonzero(~exact).tolist():
            v = float(flat[i])
            out[i] = round(v, digits) if math.isfinite(v) else None
    return out


_T = TypeVar("_T")


class Once(Generic[_T]):
    """A value computed at most once, by the first thread that asks for it: the others
    wait on the lock for that one computation and then share its result. The fast path
    (already computed) takes no lock: the value is stored before the flag is set."""

    __slots__ = ("_done", "_lock", "_value")

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._done = False
        self._value: _T | None = None

    def get(self, compute: Callable[[], _T]) -> _T:
        if not self._done:
            with self._lock:
                if not self._done:
                    self._value = compute()
                    self._done = True
        return self._value  # type: ignore[return-value]


@dataclass(frozen=True, eq=False)
class StaticEstimate:
    """The inputs of a snapshot's static inversion (``SensorModel.invert_static``)."""

    groups: tuple[tuple[NDArray[np.intp], SensorModel], ...]
    resistance_ohm: FloatArray  # as given to the model: NaN where the channel had no value
    temperature_c: FloatArray | None  # per snapshot channel, or None
    valued: BoolArray  # channels whose status carries a force
    #: where Newton's method starts: the drift-corrected force, within about 10 % of the
    #: static one, so the static inversion takes two or three steps, not six (N; NaN: none)
    guess_n: FloatArray

    def evaluate(self) -> FloatArray:
        """The static force of every channel (N; NaN where the status carries none)."""
        n = len(self.resistance_ohm)
        # the inversion clips a guess into the force range, where a NaN, negative or -inf
        # guess starts at force_min as 0 N does; only +inf would start elsewhere (force_max)
        guess = np.where(self.guess_n == np.inf, 0.0, self.guess_n)
        out: FloatArray | None = None
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            if len(self.groups) == 1 and len(self.groups[0][0]) == n and _in_order(self.groups[0][0]):
                model = self.groups[0][1]
                temp = self.temperature_c if model.has("temperature") else None
                # one model for every channel in order (the common case): no gathering
                out = model.invert(self.resistance_ohm, None, temp, guess_n=guess).force_n
            else:
                out = np.full(n, np.nan)
                for idx, model in self.groups:
                    temp = None
                    if self.temperature_c is not None and model.has("temperature"):
                        temp = self.temperature_c[idx]
                    out[idx] = model.invert(self.resistance_ohm[idx], None, temp, guess_n=guess[idx]).force_n
        return read_only(np.where(self.valued & np.isfinite(out), out, np.nan))


def _in_order(idx: NDArray[np.intp]) -> bool:
    """Whether ``idx`` is 0, 1, ..., len - 1 (remembered per index array: groups are fixed)."""
    key = id(idx)
    known = _IN_ORDER.get(key)
    if known is None or known[0] is not idx:
        known = (idx, bool(np.array_equal(idx, np.arange(len(idx)))))
        if len(_IN_ORDER) > 256:
            _IN_ORDER.clear()
        _IN_ORDER[key] = known
    return known[1]


_IN_ORDER: dict[int, tuple[NDArray[np.intp], bool]] = {}


@dataclass(frozen=True)
class RoiQuantities:
    """One region of interest at one poll (``runtime.rois``): its name, its enabled channels
    (device indices), and over those in contact the sum of force (N), the peak force (N; 0
    when none is in contact), the contact area (mm^2) and the centre of pressure (mm; None
    when none is in contact), as ``array_quantities`` computes them over the whole array."""

    name: str
    channels: tuple[int, ...]
    force_n: float
    peak_n: float
    area_mm2: float
    cop_mm: tuple[float, float] | None


@dataclass(frozen=True, eq=False)
class DeviceSnapshot:
    """The converted result of the last poll of one device (immutable).

    Arrays have one entry per enabled channel (``channel_index`` holds the device index);
    NaN marks an absent value (see ``status``). Forces in N, resistances in ohm, positions
    and centre of pressure in mm, contact area in mm^2, times in s.

    Derived values are computed on first use, explicitly lazy and thread-safe: the static
    force (``force_static_n``: the model's inversion without creep state, a diagnostic about
    half as costly as the poll's whole conversion, so the poll path does not pay for it:
    58 us on top of 113 us per 64-channel poll of bench/bench_gateway.py) and, through
    ``derived``, the ``Frame`` (``runtime.frame.frame_of``: the one typed frame the page, the
    stream and MQTT encode). Each is computed by exactly one thread, the first that asks (a
    scrape, the web server's loop or the MQTT thread), under a lock of its own (``Once``); a
    thread asking meanwhile waits for that one computation, and every reader gets the same
    read-only result. No field changes after construction (a copy made with
    ``dataclasses.replace`` computes its own).
    """

    device: str
    bus: str
    channel_index: IntArray
    channel_names: tuple[str, ...]
    x_mm: FloatArray
    y_mm: FloatArray
    resistance_ohm: FloatArray
    force_n: FloatArray
    static_estimate: StaticEstimate | None  # see ``force_static_n``
    reference_force_n: FloatArray
    status: StatusArray
    up: bool
    timestamp_s: float  # wall clock of this poll (Unix time)
    last_success_timestamp_s: float | None  # wall clock of the last good poll
    device_time_s: float | None  # device clock at the last good poll
    poll_interval_s: float
    total_force_n: float = 0.0
    center_of_pressure_mm: tuple[float, float] | None = None
    channels_in_contact: int = 0
    contact_area_mm2: float = 0.0
    peak_channel: str | None = None
    peak_force_n: float | None = None
    error: str | None = None  # why the last poll failed
    temperature_c: FloatArray | None = None  # sensor temperature where the device reports it, degC
    time_source: str = "host"  # what timed the creep step of this poll: "device" or "host"
    clock_faults: tuple[tuple[str, int], ...] = ()  # device clock faults by kind: stuck, backwards
    clock_fallback: str | None = None  # why the host clock times a device whose map has a clock
    #: False only for the placeholder a device is listed with before its first poll completes
    #: (no observation: the stream and MQTT publish nothing for it; a failed poll is True)
    polled: bool = True
    #: True when ``resistance_ohm`` holds r / R_ref (dimensionless), not ohm: a ``ratio`` front
    #: end's readings, in units of the board's unknown reference resistor
    resistance_relative: bool = False
    #: per channel, True where the taxel is dead: frozen while its region moves
    #: (``runtime.dead_taxels``; its status is ``error``); None when not tracked
    dead: NDArray[np.bool_] | None = None
    #: dead taxels per region, every region (0 included); () when not tracked
    dead_by_region: tuple[tuple[str, int], ...] = ()
    #: the device's named status words at this poll (``[[bus.device.status_word]]``), in order
    status_words: tuple[StatusWordReading, ...] = ()
    #: the device's regions of interest at this poll (``[[bus.device.roi]]``, ``runtime.rois``)
    rois: tuple[RoiQuantities, ...] = ()
    _static: Once[FloatArray] = field(default_factory=Once, init=False, repr=False, compare=False)
    _derived: dict[object, Once[object]] = field(default_factory=dict, init=False, repr=False, compare=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False, repr=False, compare=False)

    @property
    def n_channels(self) -> int:
        return len(self.channel_names)

    @property
    def force_static_n(self) -> FloatArray:
        """Force by static inversion (no creep state), N; NaN where absent (read-only). A
        diagnostic, so it is computed on first use (e.g. a scrape), not at every poll, once,
        by whichever thread asks first (see the class docstring)."""
        return self._static.get(self._evaluate_static)

    def _evaluate_static(self) -> FloatArray:
        if self.static_estimate is None:
            return read_only(np.full(self.n_channels, np.nan))
        return self.static_estimate.evaluate()

    def derived(self, compute: Callable[[DeviceSnapshot], _T]) -> _T:
        """``compute(self)``, computed once by whichever thread asks first and then shared
        (``runtime.frame.frame_of``: the one ``Frame`` of this poll). ``compute`` must be the
        same function object at every call (a module-level function), as it is the key."""
        cell = self._derived.get(compute)
        if cell is None:
            with self._lock:
                cell = self._derived.setdefault(compute, Once())
        return cell.get(lambda: compute(self))  # type: ignore[return-value]

    def channels(self) -> list[ChannelView]:
        return [
            ChannelView(
                index=int(self.channel_index[k]),
                name=self.channel_names[k],
                x_mm=float(self.x_mm[k]),
                y_mm=float(self.y_mm[k]),
                status=ChannelStatus(int(self.status[k])),
                resistance_ohm=finite_or_none(float(self.resistance_ohm[k])),
                force_n=finite_or_none(float(self.force_n[k])),
                force_static_n=finite_or_none(float(self.force_static_n[k])),
                reference_force_n=finite_or_none(float(self.reference_force_n[k])),
            )
            for k in range(self.n_channels)
        ]

    def status_counts(self) -> dict[str, int]:
        counts = np.bincount(self.status.astype(np.int64), minlength=len(ChannelStatus))
        return {s.label: int(counts[s]) for s in ChannelStatus}


@dataclass(frozen=True)
class ArrayQuantities:
    """Whole-array quantities over the channels in contact (status ok, saturated or
    extrapolated, F > 0)."""

    total_force_n: float
    center_of_pressure_mm: tuple[float, float] | None
    channels_in_contact: int
    contact_area_mm2: float
    peak_index: int | None  # position in the snapshot arrays
    peak_force_n: float | None


def array_quantities(
    force_n: FloatArray,
    status: StatusArray,
    x_mm: FloatArray,
    y_mm: FloatArray,
    cell_area_mm2: float | FloatArray,
) -> ArrayQuantities:
    """Total force (N), centre of pressure (mm), contact area (mm^2) and peak channel.

    The centre of pressure is sum(F_i x_i) / sum(F_i) over channels in contact; it is None
    (not NaN) when nothing is in contact. Contact area = the sum of the cell areas of the
    channels in contact (``cell_area_mm2``: one for every cell, or one per channel).
    """
    f = np.asarray(force_n, dtype=np.float64)
    contact = IN_CONTACT[np.asarray(status)] & (f > 0.0)  # NaN is never > 0
    n = int(np.count_nonzero(contact))
    if n == 0:
        return ArrayQuantities(0.0, None, 0, 0.0, None, None)
    fc = np.where(contact, f, 0.0)
    total = float(fc.sum())
    cop = (float(np.dot(fc, x_mm)) / total, float(np.dot(fc, y_mm)) / total)
    peak = int(fc.argmax())  # forces in contact are > 0, the rest 0
    if isinstance(cell_area_mm2, float | int):
        area = float(n * cell_area_mm2)
    else:
        area = float(np.asarray(cell_area_mm2, dtype=np.float64)[contact].sum())
    return ArrayQuantities(total, cop, n, area, peak, float(f[peak]))


@dataclass(frozen=True)
class GatewaySnapshot:
    """Everything the exporter shows: the last snapshot and counters of every device."""

    devices: Mapping[str, DeviceSnapshot] = field(default_factory=lambda: MappingProxyType({}))
    counters: Mapping[str, DeviceCounters] = field(default_factory=lambda: MappingProxyType({}))
    sequence: int = 0

    @classmethod
    def build(
        cls, devices: Mapping[str, DeviceSnapshot], counters: Mapping[str, DeviceCounters], sequence: int
    ) -> GatewaySnapshot:
        return cls(MappingProxyType(dict(devices)), MappingProxyType(dict(counters)), sequence)
