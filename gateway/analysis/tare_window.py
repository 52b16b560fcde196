"""Zero under a moving load: each channel's baseline from its own unloaded moments in a window.

An array that is never wholly unloaded (a hand, a part sliding across it) still leaves each
channel unloaded for part of the time. Over a window of polls every channel is searched on its
own (``rest_stretch``) for a stretch of at least ``MIN_POLLS`` polls that is

* at the channel's own extreme, its least loaded level (the highest resistance, the lowest
  conductance): first the best median of ``MIN_POLLS`` consecutive polls (a median, so that
  taps among a short rest do not pull it down), with sigma the standard deviation of those
  polls less any far below their median; the latest rest of at least ``MIN_POLLS`` polls
  within two bands of it then gives the level again (the median of its later half, after any
  creep back; the best of many windows sits above the rest it was picked from) and sigma
  from its poll-to-poll steps (about 1.48 times their median absolute step over sqrt 2,
  which a creep hardly moves). A poll belongs to the plateau when it is within
  ``max(floor, 4 sigma)`` of the level (the band; the floor is the tare's drift floor, 2
  counts, or 0.5 % of the reading in ohm); a gap of at most ``BRIDGE_POLLS`` polls within two
  bands (noise) does not end it. Sigma is the channel's noise at rest, blind to the load's
  jitter elsewhere in the window;
* still: the tare's MOVING check (first third against last third) passes within the stretch.
  An FSR lifted after a load creeps back to its baseline over seconds to tens of seconds, so a
  stretch that still moves is cut from its start (its first third dropped) until it is still
  or too short: the recovery is left out, the settled end kept;
* the latest such stretch: the channel's state nearest the end of the window (temperature,
  drift), and after any recovery; unless it is shorter than half the longest (a rest that has
  only begun at the window's end), then the latest one at least that long.

Its mean is the baseline. The checks of the whole-array tare then run per channel, each a
reason the channel is not zeroed (and its baseline left as the file has it, ``"none"`` if it
has none), with numbers, in this order:

* FAULTY: a short or an invalid reading at the channel's extreme;
* LOADED (loaded throughout): at its least loaded the model reads more than ``max_force_n``
  (N), or it conducts more than ``LOADED_FACTOR`` times the median channel's (at least 4
  channels, each at its own least loaded);
* MOVING (never still): no still stretch of ``MIN_POLLS`` polls at its extreme;
* NOISY: the stretch's standard deviation exceeds the tare's noise limit.

The search works on one series of numbers and a direction (``rest_stretch``), so it serves any
baseline taken per channel or per region at its own minimum of load.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..config import DeviceConfig
from ..model import DividerStatus, RatioFrontEnd
from .tare import (
    DRIFT_FLOOR_COUNTS,
    DRIFT_FLOOR_REL,
    LOADED_FACTOR,
    MIN_POLLS,
    ChannelSeries,
    FloatArray,
    TareError,
    TareResult,
    conductance_floor,
    conductance_ratio,
    load_detail,
    rest_conductance,
    rest_forces,
    rest_readings,
    thirds_drift,
)

__all__ = ["RestSearch", "RestStretch", "WindowTare", "compute_window_tare", "rest_stretch"]

#: the plateau band around a channel's extreme, in standard deviations of its noise
PLATEAU_SIGMAS = 4.0
#: a median absolute deviation times this is a standard deviation (normal noise)
_MAD_TO_STD = 1.4826
#: a region of fewer chosen taxels is not judged as a whole (``loaded_regions``)
REGION_MIN_TAXELS = 9
#: a gap of at most this many polls within two bands of the extreme does not end a plateau
BRIDGE_POLLS = 5


@dataclass(frozen=True)
class RestStretch:
    """Polls ``start`` to ``stop`` (exclusive) of a series: their ``mean`` and standard
    deviation ``std`` (the series' units), and ``drift`` (mean of the last third minus that of
    the first) with its standard error ``drift_err``."""

    start: int
    stop: int
    mean: float
    std: float
    drift: float
    drift_err: float

    @property
    def n_polls(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class RestSearch:
    """What ``rest_stretch`` found: ``stretch`` the latest still stretch at the extreme (None
    if there is none), ``top`` the ``min_polls`` polls of the extreme itself (None with fewer
    polls), ``moving`` the last stretch at the extreme found to move (for the reason), ``why``
    the reason there is no stretch ("" when there is one), ``level`` the extreme (the values'
    units)."""

    stretch: RestStretch | None
    top: RestStretch | None
    moving: RestStretch | None
    why: str
    #: the extreme (least loaded) level: the best median of ``min_polls`` polls (NaN if none)
    level: float = float("nan")


def _stretch(v: FloatArray, start: int, stop: int) -> RestStretch:
    part = v[start:stop]
    drift, err = thirds_drift(part)
    return RestStretch(start, stop, float(part.mean()), float(part.std(ddof=1)), drift, err)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of every run of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _bridged(runs: list[tuple[int, int]], near: np.ndarray) -> list[tuple[int, int]]:
    """``runs`` joined across gaps of at most ``BRIDGE_POLLS`` polls that are all ``near``: a
    reading a little outside the band in the middle of a rest is noise, not a load."""
    out: list[tuple[int, int]] = []
    for start, stop in runs:
        if out and start - out[-1][1] <= BRIDGE_POLLS and near[out[-1][1] : start].all():
            out[-1] = (out[-1][0], stop)
        else:
            out.append((start, stop))
    return out


def rest_stretch(
    values: FloatArray,
    *,
    unloaded_high: bool = True,
    floor_abs: float = 0.0,
    floor_rel: float = 0.0,
    min_polls: int = MIN_POLLS,
) -> RestSearch:
    """The latest still stretch of ``values`` (one channel's polls, in order) at its own least
    loaded level: the highest values when ``unloaded_high`` (resistance, or counts that rise
    with it), else the lowest. The drift floor is ``max(floor_abs, floor_rel * |level|)`` (the
    values' units); see the module docstring."""
    v = np.asarray(values, dtype=np.float64)
    x = v if unloaded_high else -v
    finite = np.isfinite(x)
    if v.size < min_polls:
        return RestSearch(None, None, None, f"only {v.size} polls")
    windows = np.lib.stride_tricks.sliding_window_view(x, min_polls)
    whole = np.all(np.isfinite(windows), axis=1)
    if not whole.any():
        return RestSearch(None, None, None, f"no {min_polls} consecutive valid polls")
    # the extreme: the highest median of min_polls polls (the latest of equals), so that a
    # rest shorter than that among taps is not averaged with them into a level
    medians = np.where(whole, np.median(np.where(whole[:, None], windows, 0.0), axis=1), -np.inf)
    best = int(medians.size - 1 - np.argmax(medians[::-1]))
    level = float(medians[best])
    top = _stretch(v, best, best + min_polls)
    # the noise at the extreme itself: a moving load elsewhere in the window scatters the
    # readings far more, which says nothing of the channel at rest; the standard deviation of
    # those polls less any far below their median (a tap among them), which a median absolute
    # deviation finds
    floor = max(floor_abs, floor_rel * abs(level))
    polls = windows[best]
    rough = _MAD_TO_STD * float(np.median(np.abs(polls - level)))
    kept = polls[polls >= level - max(floor, PLATEAU_SIGMAS * rough)]
    sigma = float(kept.std(ddof=1)) if kept.size >= 2 else 0.0
    band = max(floor, PLATEAU_SIGMAS * sigma)
    wide = _bridged(_runs(finite & (x >= level - 2.0 * band)), finite & (x >= level - 3.0 * band))
    rests = [(a, b) for a, b in wide if b - a >= min_polls]
    if rests:
        # the best of min_polls polls sits above the rest it came from (it was picked for it),
        # and min_polls polls say little of the noise: both again from the latest rest found
        # with a wider band, the level from its later half (after any creep back), the noise
        # from its poll-to-poll steps (which a creep hardly moves)
        a, b = rests[-1]
        level = float(np.median(x[max(a, b - max(min_polls, (b - a) // 2)) : b]))  # its settled half
        floor = max(floor_abs, floor_rel * abs(level))
        rest = x[a:b]
        # a sample the device repeats between its frame updates is one measurement: its
        # steps of 0 say nothing of the noise
        steps = np.abs(np.diff(rest[np.concatenate([[True], rest[1:] != rest[:-1]])]))
        noise = _MAD_TO_STD * float(np.median(steps)) / np.sqrt(2.0) if steps.size else 0.0
        band = max(floor, PLATEAU_SIGMAS * noise)
    runs = _bridged(_runs(finite & (x >= level - band)), finite & (x >= level - 2.0 * band))
    moving: RestStretch | None = None
    still: list[RestStretch] = []  # the still stretch of each run, latest first
    for start, stop in reversed(runs):
        while stop - start >= min_polls:
            found = _stretch(v, start, stop)
            if abs(found.drift) <= max(floor, 4.0 * found.drift_err):
                still.append(found)
                break
            moving = moving or found
            start += (stop - start) // 3
    if still:
        # the latest, unless it is short beside an earlier one: a rest that has just begun at
        # the window's end is the creep's start, and its mean the least sure
        enough = max(min_polls, max(p.n_polls for p in still) // 2)
        chosen = next(p for p in still if p.n_polls >= enough)
        return RestSearch(chosen, top, moving, "", level if unloaded_high else -level)
    longest = max((b - a for a, b in runs), default=0)
    why = f"never still at its own extreme for {min_polls} polls"
    if moving is None:
        why += f" (its longest rest there: {longest} polls)"
    return RestSearch(None, top, moving, why, level if unloaded_high else -level)


@dataclass(frozen=True)
class WindowTare:
    """The result of a moving-load tare: ``tare`` the zeroed channels (their baselines, as a
    whole-array tare gives them; ``tare.n_polls`` the fewest polls of a stretch); per zeroed
    channel ``spans_s`` (first, last) the times of its stretch's polls (s, the series' clock)
    when ``timed``, else poll indices, and ``n_polls`` its number of polls; ``skipped``
    (channel index, reason with numbers) for every channel not zeroed."""

    tare: TareResult
    spans_s: tuple[tuple[float, float], ...]
    timed: bool
    skipped: tuple[tuple[int, str], ...]
    n_polls: tuple[int, ...] = ()


def _unloaded_high(device: DeviceConfig, counts: bool) -> bool:
    """True when a larger value is a larger resistance: always in ohm; for counts, as the
    device's front end turns them into ohm."""
    if not counts:
        return True
    codes = np.linspace(0.0, float(device.front_end.full_scale), 65)
    r, status = device.front_end.resistance(codes)
    good = np.flatnonzero(np.isfinite(r) & (status == int(DividerStatus.OK)))
    return bool(good.size < 2 or r[good[-1]] > r[good[0]])


def _span(s: ChannelSeries, stretch: RestStretch) -> tuple[float, float]:
    if s.time_s is None:
        return float(stretch.start), float(stretch.stop - 1)
    return float(s.time_s[stretch.start]), float(s.time_s[stretch.stop - 1])


def _span_text(span: tuple[float, float], timed: bool) -> str:
    a, b = span
    return f"{a:.4g}-{b:.4g} s" if timed else f"polls {a:.0f}-{b:.0f}"


def compute_window_tare(
    device: DeviceConfig,
    series: Sequence[ChannelSeries],
    *,
    counts: bool,
    window: str = "the sampling window",
    max_force_n: float = 0.5,
    max_noise_counts: float = 8.0,
    max_noise_rel: float = 0.02,
) -> WindowTare:
    """The baselines of the channels of ``series`` (ADC counts when ``counts``, else ohm), each
    from its own latest still stretch at its least loaded level within ``window`` (words for
    messages); the channels that have none are skipped with the reason. ``TareError`` when no
    channel could be zeroed (see the module docstring)."""
    if not series:
        raise TareError("no channel to tare; nothing was written")
    high = _unloaded_high(device, counts)
    floor_abs, floor_rel = (DRIFT_FLOOR_COUNTS, 0.0) if counts else (0.0, DRIFT_FLOOR_REL)
    found = [
        rest_stretch(s.values, unloaded_high=high, floor_abs=floor_abs, floor_rel=floor_rel) for s in series
    ]
    # each channel at its least loaded: its still stretch, else the extreme itself (its level,
    # a median, over the polls of ``top``)
    rep = [f.stretch or f.top for f in found]
    mean = np.array([f.level if f.stretch is None else f.stretch.mean for f in found])
    labels = {int(st): st.name.lower() for st in DividerStatus}
    r, status, value = rest_readings(device, mean, counts)
    ok = status == int(DividerStatus.OK)
    force = rest_forces(device, [s.index for s in series], r, ok)
    ratio = conductance_ratio(device, r, ok, counts, max_noise_counts)
    relative = isinstance(device.front_end, RatioFrontEnd)
    by_region = loaded_regions(
        device,
        [s.index for s in series],
        rest_conductance(r, ok),
        conductance_floor(device, counts, max_noise_counts),
    )
    timed = all(s.time_s is not None for s in series)
    skipped: list[tuple[int, str]] = []
    zeroed: list[int] = []
    for k, (s, f, p) in enumerate(zip(series, found, rep, strict=True)):
        where = "" if p is None else f"({_span_text(_span(s, p), timed)}, {p.n_polls} polls)"
        if p is None:
            skipped.append((s.index, f"{f.why} in {window}"))
        elif status[k] in (int(DividerStatus.SHORT), int(DividerStatus.INVALID)):
            skipped.append((s.index, f"faulty at its least loaded {where}: {labels[int(status[k])]}"))
        elif k in by_region.loaded:
            skipped.append((s.index, f"loaded throughout {window} with its region: {by_region.loaded[k]}"))
        elif k in by_region.ratio and ok[k] and by_region.ratio[k] > LOADED_FACTOR:
            detail = load_detail(float(force[k]), float(r[k]), by_region.ratio[k], relative)
            skipped.append(
                (
                    s.index,
                    f"loaded throughout {window}: at its least loaded {where} {detail} of its region "
                    f"(or the array's, whichever is more); allowed at rest: {LOADED_FACTOR:g}x; sample "
                    "longer, or lift the load off it for a moment",
                )
            )
        elif k not in by_region.ratio and ok[k] and (force[k] > max_force_n or ratio[k] > LOADED_FACTOR):
            detail = load_detail(float(force[k]), float(r[k]), float(ratio[k]), relative)
            skipped.append(
                (
                    s.index,
                    f"loaded throughout {window}: at its least loaded {where} {detail}; allowed at rest: "
                    f"at most {max_force_n:g} N (--max-force) and {LOADED_FACTOR:g}x the median; "
                    "sample longer, or lift the load off it for a moment",
                )
            )
        elif f.stretch is None:
            skipped.append((s.index, f"{f.why} in {window}{_moving_text(s, f.moving, counts, timed)}"))
        elif (noise := _noisy(f.stretch, counts, max_noise_counts, max_noise_rel)) is not None:
            skipped.append((s.index, f"too noisy {where}: {noise}"))
        else:
            zeroed.append(k)
    if not zeroed:
        shown = ", ".join(f"{device.channels[i].name} ({why})" for i, why in skipped[:6])
        more = f" and {len(skipped) - 6} more" if len(skipped) > 6 else ""
        raise TareError(f"no channel rested in {window}: {shown}{more}; nothing was written")
    notes = [
        f"{device.channels[series[k].index].name} read at a rail at rest ({labels[int(status[k])]}): the "
        "baseline records it, and readings there stay flagged"
        for k in zeroed
        if not ok[k]
    ]
    stretches = [found[k].stretch for k in zeroed]
    result = TareResult(
        key="baseline_counts" if counts else "baseline_ohm",
        values=tuple(float(value[k]) for k in zeroed),
        resistance_ohm=tuple(float(r[k]) for k in zeroed),
        force_before_n=tuple(float(force[k]) for k in zeroed),
        noise=tuple(0.0 if p is None else p.std for p in stretches),
        n_polls=min(0 if p is None else p.n_polls for p in stretches),
        notes=tuple(notes),
        channels=tuple(series[k].index for k in zeroed),
    )
    spans = tuple(_span(series[k], p) for k, p in zip(zeroed, stretches, strict=True) if p is not None)
    polls = tuple(p.n_polls for p in stretches if p is not None)
    return WindowTare(result, spans, timed, tuple(skipped), polls)


@dataclass(frozen=True)
class RegionJudgement:
    """Channels judged by their region (positions in the chosen channels): ``loaded`` those of a
    region loaded as a whole, with why; ``ratio`` every other one's conductance at rest over
    its region's median (at least noise's)."""

    loaded: dict[int, str]
    ratio: dict[int, float]


def loaded_regions(
    device: DeviceConfig, chosen: Sequence[int], conductance: FloatArray, floor_s: float
) -> RegionJudgement:
    """Each region of ``device`` judged as a whole at its channels' least loaded levels.

    A taxel loaded throughout the window cannot be told from one whose own reading at rest is
    high (a preloaded skin, a leak) by its own readings alone, nor by the model's force there;
    a region can. Each taxel's offset is its own, so a region at rest has taxels of small
    offset too: the least loaded tenth of its taxels (the 10th percentile of their
    conductance at their least loaded) is near the array's. A region under a load throughout
    (a palm held on an object) has none: its least loaded tenth conducts more than
    ``LOADED_FACTOR`` times the array's (all chosen channels; at least the conductance of
    noise, ``floor_s``), and none of its taxels is zeroed from this window. In a region at
    rest a taxel is loaded when it conducts more than ``LOADED_FACTOR`` times the region's
    median or the array's, whichever is more (a point load; a small region's median is
    noisy), not by the model's force there (an offset is no force). Regions of
    fewer than ``REGION_MIN_TAXELS`` chosen taxels are not judged."""
    judged = RegionJudgement({}, {})
    finite = np.isfinite(conductance)
    if not device.regions or np.count_nonzero(finite) < REGION_MIN_TAXELS:
        return judged
    hand = max(float(np.percentile(conductance[finite], 10.0)), floor_s)
    if not hand > 0.0:
        return judged
    typical = max(float(np.median(conductance[finite])), floor_s)
    positions = np.asarray(chosen, dtype=np.intp)
    for region in device.regions:
        first, stop = region.first_channel, region.first_channel + region.n_channels
        inside = np.flatnonzero((positions >= first) & (positions < stop) & finite)
        if inside.size < REGION_MIN_TAXELS:
            continue
        low = float(np.percentile(conductance[inside], 10.0))
        if low > LOADED_FACTOR * hand:
            why = (
                f"region {region.name}'s least loaded tenth conducts {low / hand:.2g}x the array's "
                f"(allowed: {LOADED_FACTOR:g}x); a region at rest has taxels near the array's least; "
                f"zero it when it is free (--channels {region.name})"
            )
            judged.loaded.update((int(k), why) for k in inside)
            continue
        median = max(float(np.median(conductance[inside])), typical)
        judged.ratio.update((int(k), float(conductance[k]) / median) for k in inside)
    return judged


def _moving_text(s: ChannelSeries, moving: RestStretch | None, counts: bool, timed: bool) -> str:
    if moving is None:
        return ""
    span = _span(s, moving)
    rate = ""
    seconds = span[1] - span[0]
    if counts:
        drift = f"{moving.drift:+.3g} counts"
        if timed and seconds > 0:
            rate = f", {moving.drift / seconds:+.3g} counts/s"
        limit = f"{DRIFT_FLOOR_COUNTS:g} counts"
    else:
        drift = f"{100 * moving.drift / moving.mean:+.3g} %"
        if timed and seconds > 0:
            rate = f", {100 * moving.drift / moving.mean / seconds:+.3g} %/s"
        limit = f"{100 * DRIFT_FLOOR_REL:g} % of the reading"
    return (
        f": its latest stretch there ({_span_text(span, timed)}) drifts {drift}{rate} "
        f"(first third to last third; allowed: {limit} or 4 standard errors)"
    )


def _noisy(stretch: RestStretch, counts: bool, max_noise_counts: float, max_noise_rel: float) -> str | None:
    if counts:
        if stretch.std > max_noise_counts:
            return f"std {stretch.std:.3g} counts; allowed: at most {max_noise_counts:g} counts (--max-noise)"
        return None
    if stretch.std > max_noise_rel * abs(stretch.mean):
        return (
            f"std {100 * stretch.std / stretch.mean:.3g} % of {stretch.mean:.4g} ohm; "
            f"allowed: at most {100 * max_noise_rel:g} % of the reading"
        )
    return None
