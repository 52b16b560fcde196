"""Zero: the unloaded baseline of every channel, from samples of an array at rest.

A channel that reads ``R_b`` unloaded where the model expects ``R(0 N)`` carries a parallel
conductance ``1/R_b - 1/R(0)`` (board leakage, a preloaded cell); the gateway takes it off every
reading (``runtime.processor``), so a channel at its baseline reads 0 N, no contact. ``tare``
measures ``R_b`` (as ADC counts for ADC devices, the raw reading; in ohm for float devices and
from a record) for all channels or the chosen ones, and refuses a set that is not a still,
unloaded array, naming the real cause first, with numbers:

* too few polls (fewer than ``MIN_POLLS``) of a channel;
* FAULTY: a channel shorted or invalid at rest (a fault, not a baseline); a channel open at
  rest is recorded as such, and the result says so;
* LOADED: the model reads more than ``max_force_n`` (N) at a channel's baseline, or its baseline
  conductance is more than ``LOADED_FACTOR`` times the median chosen channel's (at least 4
  channels); the message says the array is loaded and names the ways out (``--channels`` for
  the unloaded ones, ``--from-record`` with an unloaded moment, ``--moving-load`` for a load
  that moves (``tare_window``), ``--device-zero``);
* MOVING: the mean of the last third of a channel's polls differs from the first third's by
  more than ``max(DRIFT_FLOOR, 4 standard errors)`` (counts, or ``DRIFT_FLOOR_REL`` of the
  reading in ohm; the standard error from the scatter within the two thirds, so a step reads
  as a drift, not as noise; a sample a device repeats between its frame updates counts
  once): creep after a load was lifted, a hand still on the array; the message gives the
  drift over the window and per second;
* NOISY: a channel's standard deviation exceeds ``max_noise_counts`` (counts), or
  ``max_noise_rel`` of the reading (ohm); only this message suggests wiring or shielding.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final, Protocol

import numpy as np
from numpy.typing import NDArray

from ..config import DeviceConfig, Encoding
from ..errors import GatewayError
from ..model import DividerStatus, RatioFrontEnd, SensorModel

__all__ = [
    "MIN_POLLS",
    "ChannelSeries",
    "TareError",
    "TareResult",
    "compute_tare",
    "compute_tare_series",
    "index_ranges",
    "samples_to_series",
    "thirds_drift",
]

MIN_POLLS: Final = 10
DRIFT_FLOOR_COUNTS: Final = 2.0
DRIFT_FLOOR_REL: Final = 0.005
LOADED_FACTOR: Final = 3.0

FloatArray = NDArray[np.float64]


class RawSample(Protocol):
    """One poll's values of every channel (``gateway.modbus.image.RawSample`` is one)."""

    @property
    def counts(self) -> NDArray[np.integer[Any]] | FloatArray | None: ...

    @property
    def resistance_ohm(self) -> FloatArray | None: ...


class TareError(GatewayError):
    """The samples are not those of a still, unloaded array (the message says why)."""


@dataclass(frozen=True)
class ChannelSeries:
    """The readings of one channel over the window: ``values`` (ADC counts, or ohm when
    ``counts`` is False) at ``time_s`` (s, any origin; None: evenly spaced, no rate given)."""

    index: int
    values: FloatArray
    time_s: FloatArray | None = None


@dataclass(frozen=True)
class TareResult:
    """The baselines of the tared channels: ``channels`` their indices (ascending), ``key``
    ``baseline_counts`` or ``baseline_ohm``, ``values`` one per tared channel (counts or ohm),
    ``resistance_ohm`` the same as resistances (ohm, of the mean), ``force_before_n`` what the
    model read at each baseline without the tare (N), ``noise`` the standard deviations (counts
    or ohm), ``n_polls`` the fewest polls of a channel."""

    key: str
    values: tuple[float, ...]
    resistance_ohm: tuple[float, ...]
    force_before_n: tuple[float, ...]
    noise: tuple[float, ...]
    n_polls: int
    notes: tuple[str, ...]
    channels: tuple[int, ...] = ()


def _names(device: DeviceConfig, idx: Sequence[int] | NDArray[np.intp], detail: Sequence[str]) -> str:
    shown = [f"{device.channels[int(i)].name} ({d})" for i, d in zip(idx, detail, strict=True)]
    more = f" and {len(shown) - 6} more" if len(shown) > 6 else ""
    return ", ".join(shown[:6]) + more


def index_ranges(indices: Sequence[int]) -> str:
    """``[0, 1, 2, 5, 7, 8]`` -> ``"0-2,5,7-8"`` (the ``--channels`` spelling)."""
    parts: list[str] = []
    ordered = sorted(set(indices))
    k = 0
    while k < len(ordered):
        j = k
        while j + 1 < len(ordered) and ordered[j + 1] == ordered[j] + 1:
            j += 1
        parts.append(str(ordered[k]) if j == k else f"{ordered[k]}-{ordered[j]}")
        k = j + 1
    return ",".join(parts)


def compute_tare(
    device: DeviceConfig,
    samples: Sequence[RawSample],
    *,
    channels: Sequence[int] | None = None,
    times_s: Sequence[float] | None = None,
    window: str = "the sampling window",
    max_force_n: float = 0.5,
    max_noise_counts: float = 8.0,
    max_noise_rel: float = 0.02,
) -> TareResult:
    """The baselines of ``device`` (of ``channels``, indices; default all) from ``samples`` of
    it at rest, polled at ``times_s`` (s; optional, for drift rates); ``TareError`` if they are
    not those of a still, unloaded array (see the module docstring)."""
    chosen = list(range(device.n_channels)) if channels is None else sorted(set(channels))
    adc = device.encoding is Encoding.ADC
    series = samples_to_series(device, samples, channels=chosen, times_s=times_s)
    return compute_tare_series(
        device,
        series,
        counts=adc,
        window=window,
        max_force_n=max_force_n,
        max_noise_counts=max_noise_counts,
        max_noise_rel=max_noise_rel,
    )


def samples_to_series(
    device: DeviceConfig,
    samples: Sequence[RawSample],
    *,
    channels: Sequence[int] | None = None,
    times_s: Sequence[float] | None = None,
) -> list[ChannelSeries]:
    """One ``ChannelSeries`` per channel of ``channels`` (indices; default all) from polls of
    ``device``: ADC counts for an ADC device, else ohm, at ``times_s`` (s; optional); a poll
    without values of the device's encoding is left out. ``TareError`` when there are fewer
    than ``MIN_POLLS`` polls, or fewer than that carry values."""
    chosen = list(range(device.n_channels)) if channels is None else sorted(set(channels))
    if len(samples) < MIN_POLLS:
        raise TareError(
            f"only {len(samples)} polls; a tare needs at least {MIN_POLLS} (sample longer); "
            "nothing was written"
        )
    adc = device.encoding is Encoding.ADC
    keep = [k for k, s in enumerate(samples) if (s.counts if adc else s.resistance_ohm) is not None]
    if len(keep) < MIN_POLLS:
        raise TareError("the samples carry no values of this device's encoding; nothing was written")
    data = np.array(
        [np.asarray(samples[k].counts if adc else samples[k].resistance_ohm, dtype=np.float64) for k in keep]
    )
    t = None if times_s is None else np.asarray([times_s[k] for k in keep], dtype=np.float64)
    return [ChannelSeries(i, data[:, i], t) for i in chosen]


def rest_readings(
    device: DeviceConfig, mean: FloatArray, counts: bool
) -> tuple[FloatArray, NDArray[Any], FloatArray]:
    """Each channel's resistance (ohm; r / R_ref for a ``ratio`` front end), ``DividerStatus``
    and baseline value (rounded counts when ``counts``, else ohm) at rest, from its mean
    reading there. With ``rails = "readings"`` the open rail is no current at rest (OK, +inf),
    as the gateway reads it."""
    if counts:
        r, status = device.front_end.resistance(mean)
        value = np.rint(mean)
        _, rounded_status = device.front_end.resistance(value)
        status = np.where(rounded_status == int(DividerStatus.OK), status, rounded_status)
        if device.rails == "readings":
            status = np.where(status == int(DividerStatus.OPEN), int(DividerStatus.OK), status)
        return r, status, value
    r = mean.copy()
    ok = np.isfinite(r) & (r > 0)
    if device.rails == "readings":
        ok |= np.isposinf(r)
    return r, np.where(ok, int(DividerStatus.OK), int(DividerStatus.INVALID)), r


def rest_forces(
    device: DeviceConfig, chosen: Sequence[int], r: FloatArray, ok: NDArray[np.bool_]
) -> FloatArray:
    """The force (N) each channel's model reads at ``r`` (NaN where not ``ok``, and for a
    channel with nothing to read a force with: ``DeviceConfig.needs_calibration``)."""
    force = np.full(len(chosen), np.nan)
    for k, i in enumerate(chosen):
        ch = device.channels[i]
        if ok[k] and not device.needs_calibration(ch):
            model = SensorModel(ch.effects, [ch.params])
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                force[k] = float(model.invert_static(np.array([r[k]])).force_n[0])
    return force


def conductance_floor(device: DeviceConfig, counts: bool, max_noise_counts: float) -> float:
    """Read in counts, the conductance of a code ``max_noise_counts`` beyond the open sensor's
    (0 in ohm): less than that at rest is noise, not load."""
    if not counts:
        return 0.0
    x_open, x_short = device.front_end._code_edges()
    step = max_noise_counts if x_short >= x_open else -max_noise_counts
    code = min(max(x_open + step, 0.0), float(device.front_end.full_scale))
    r_floor, _ = device.front_end.resistance(np.array([code]))
    return 1.0 / float(r_floor[0]) if np.isfinite(r_floor[0]) and r_floor[0] > 0 else 0.0


def rest_conductance(r: FloatArray, ok: NDArray[np.bool_]) -> FloatArray:
    """1 / r where ``ok`` (0 for +inf: no current), NaN elsewhere."""
    with np.errstate(divide="ignore"):
        return np.where(ok, 1.0 / np.where(ok, r, 1.0), np.nan)


def conductance_ratio(
    device: DeviceConfig, r: FloatArray, ok: NDArray[np.bool_], counts: bool, max_noise_counts: float
) -> FloatArray:
    """Each channel's conductance at rest over the median channel's (NaN for all with fewer than
    4 ``ok`` channels). Read in counts, the median is taken as at least ``conductance_floor``:
    on a read-out whose unloaded taxels read about 0 (a robot hand's raw values) the median is
    noise, and noise is no load."""
    ratio = np.full(r.size, np.nan)
    if np.count_nonzero(ok) < 4:
        return ratio
    conductance = rest_conductance(r, ok)
    median = max(float(np.nanmedian(conductance)), conductance_floor(device, counts, max_noise_counts))
    if median > 0:
        ratio = conductance / median
    return ratio


def load_detail(force_n: float, r: float, ratio: float, relative: bool) -> str:
    """``1.2 N by the model at 9e+04 ohm, 4x the median conductance``; without a force (an
    uncalibrated channel) the reading alone."""
    unit = "R_ref" if relative else "ohm"
    head = f"{r:.4g} {unit}" if math.isnan(force_n) else f"{force_n:.3g} N by the model at {r:.4g} {unit}"
    return f"{head}, {ratio:.2g}x the median conductance"


def _loaded_message(
    device: DeviceConfig,
    idx: NDArray[np.intp],
    force: FloatArray,
    r: FloatArray,
    ratio: FloatArray,
    max_force_n: float,
    chosen: Sequence[int],
    window: str,
) -> str:
    relative = isinstance(device.front_end, RatioFrontEnd)
    detail = [load_detail(float(force[i]), float(r[i]), float(ratio[i]), relative) for i in idx]
    loaded_channels = {chosen[int(i)] for i in idx}
    rest = [c for c in chosen if c not in loaded_channels]
    way = f"--channels {index_ranges(rest)}" if rest else "--channels with the unloaded ones"
    return (
        f"the array is loaded over {window}: {_names(device, [chosen[int(i)] for i in idx], detail)}; "
        f"allowed at rest: at most {max_force_n:g} N (--max-force) and {LOADED_FACTOR:g}x the median "
        f"channel's conductance. A baseline under a load would hide it: lift it off and tare again, or "
        f"tare only the unloaded channels ({way}), or take the baseline from a record of an unloaded "
        "moment (--from-record RECORD.csv --start-s S --end-s E), or, if the load moves, zero each "
        "channel from its own unloaded moments (--moving-load), or zero the device itself "
        "(--device-zero, if it has a zero action); nothing was written"
    )


def _distinct(values: FloatArray) -> FloatArray:
    """``values`` without the repeats of the sample before (a device that has not updated its
    frame since the last poll answers the same sample); at least two values (the first and
    the last, which may be equal) so that a scatter can be computed."""
    if values.size < 2:
        return np.concatenate([values, values])
    keep = np.concatenate([[True], values[1:] != values[:-1]])
    kept = values[keep]
    return kept if kept.size >= 2 else values[[0, -1]]


def thirds_drift(values: FloatArray) -> tuple[float, float]:
    """(drift, its standard error) of a series of at least two values: the mean of its last
    third minus that of its first third, and the standard error of that difference from the
    scatter within the two thirds (a step between them is a drift, not noise; a value a device
    repeats between its frame updates counts once)."""
    third = max(1, values.size // 3)
    first, last = _distinct(values[:third]), _distinct(values[-third:])
    with np.errstate(invalid="ignore"):
        drift = float(values[-third:].mean() - values[:third].mean())
        std_err = math.sqrt(first.var(ddof=1) / first.size + last.var(ddof=1) / last.size)
    return drift, std_err


def compute_tare_series(
    device: DeviceConfig,
    series: Sequence[ChannelSeries],
    *,
    counts: bool,
    window: str = "the sampling window",
    max_force_n: float = 0.5,
    max_noise_counts: float = 8.0,
    max_noise_rel: float = 0.02,
) -> TareResult:
    """The baselines of the channels of ``series`` (each its own readings, ADC counts when
    ``counts`` else ohm) over ``window`` (words for messages); ``TareError`` naming the cause
    in the order faulty, loaded, moving, noisy (see the module docstring)."""
    if not series:
        raise TareError("no channel to tare; nothing was written")
    chosen = [s.index for s in series]
    n = np.array([s.values.size for s in series])
    if int(n.min()) < MIN_POLLS:
        few = np.flatnonzero(n < MIN_POLLS)
        detail = [f"{int(n[i])} polls" for i in few]
        raise TareError(
            f"too few polls in {window}: {_names(device, [chosen[int(i)] for i in few], detail)}; "
            f"a tare needs at least {MIN_POLLS} per channel (sample longer); nothing was written"
        )
    m = len(series)
    mean = np.empty(m)
    std = np.empty(m)
    drift = np.empty(m)
    rate = np.full(m, np.nan)
    std_err = np.empty(m)
    with np.errstate(invalid="ignore"):
        for k, s in enumerate(series):
            v = s.values
            third = max(1, v.size // 3)
            mean[k] = v.mean()
            std[k] = v.std(ddof=1)
            drift[k], std_err[k] = thirds_drift(v)
            if s.time_s is not None:
                span = float(s.time_s[-third:].mean() - s.time_s[:third].mean())
                if span > 0:
                    rate[k] = drift[k] / span
    finite = np.isfinite(mean)

    # FAULTY: a short or an invalid reading at rest
    r, status, value = rest_readings(device, mean, counts)
    ok = status == int(DividerStatus.OK)
    labels = {int(s): s.name.lower() for s in DividerStatus}
    faulty = np.flatnonzero(np.isin(status, [int(DividerStatus.SHORT), int(DividerStatus.INVALID)]))
    if faulty.size:
        detail = [labels[int(status[i])] for i in faulty]
        raise TareError(
            f"faulty at rest: {_names(device, [chosen[int(i)] for i in faulty], detail)}; a short or an "
            "invalid reading is a fault, not a baseline (disable the channel or fix it); nothing was written"
        )
    notes: list[str] = []
    not_ok = np.flatnonzero(~ok)
    if not_ok.size:
        detail = [labels[int(status[i])] for i in not_ok]
        notes.append(
            f"{_names(device, [chosen[int(i)] for i in not_ok], detail)} read at a rail at rest: the "
            "baseline records it, and readings there stay flagged"
        )

    # LOADED: a force by the model, or far more conductance than the median channel
    force = rest_forces(device, chosen, r, ok)
    ratio = conductance_ratio(device, r, ok, counts, max_noise_counts)
    with np.errstate(invalid="ignore"):
        loaded = ok & ((force > max_force_n) | (ratio > LOADED_FACTOR))
    if loaded.any():
        raise TareError(
            _loaded_message(device, np.flatnonzero(loaded), force, r, ratio, max_force_n, chosen, window)
        )

    # MOVING: a trend across the window
    floor = np.full(m, DRIFT_FLOOR_COUNTS) if counts else DRIFT_FLOOR_REL * np.abs(mean)
    drifting = finite & (np.abs(drift) > np.maximum(floor, 4.0 * std_err))
    if drifting.any():
        idx = np.flatnonzero(drifting)
        if counts:
            detail = [
                f"{drift[i]:+.3g} counts over {window}"
                + (f", {rate[i]:+.3g} counts/s" if np.isfinite(rate[i]) else "")
                for i in idx
            ]
            limit = f"{DRIFT_FLOOR_COUNTS:g} counts"
        else:
            detail = [
                f"{100 * drift[i] / mean[i]:+.3g} % over {window}"
                + (f", {100 * rate[i] / mean[i]:+.3g} %/s" if np.isfinite(rate[i]) else "")
                for i in idx
            ]
            limit = f"{100 * DRIFT_FLOOR_REL:g} % of the reading"
        raise TareError(
            f"the array is moving: {_names(device, [chosen[int(i)] for i in idx], detail)} (first third "
            f"to last third; allowed: {limit} or 4 standard errors, whichever is larger); wait until it "
            "has settled (creep after a load is lifted takes tens of seconds) and tare again; "
            "nothing was written"
        )

    # NOISY: still and unloaded, but the readings scatter
    if counts:
        noisy = std > max_noise_counts
        noise_limit = f"{max_noise_counts:g} counts (--max-noise)"
        detail_noise = [f"std {std[i]:.3g} counts" for i in range(m)]
    else:
        noisy = std > max_noise_rel * np.abs(mean)
        noise_limit = f"{100 * max_noise_rel:g} % of the reading"
        detail_noise = [f"std {100 * std[i] / mean[i]:.3g} % of {mean[i]:.4g} ohm" for i in range(m)]
    noisy &= finite
    if noisy.any():
        idx = np.flatnonzero(noisy)
        raise TareError(
            f"too noisy over {window}: "
            f"{_names(device, [chosen[int(i)] for i in idx], [detail_noise[i] for i in idx])}"
            f"; allowed: at most {noise_limit}; the array is still and unloaded, so check the wiring "
            "or shielding, or raise the limit; nothing was written"
        )
    key = "baseline_counts" if counts else "baseline_ohm"
    return TareResult(
        key=key,
        values=tuple(float(v) for v in value),
        resistance_ohm=tuple(float(x) for x in r),
        force_before_n=tuple(float(x) for x in force),
        noise=tuple(float(x) for x in std),
        n_polls=int(n.min()),
        notes=tuple(notes),
        channels=tuple(chosen),
    )
