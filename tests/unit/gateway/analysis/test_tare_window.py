"""The moving-load tare (``gateway.analysis.tare_window``): each channel's baseline from its own
unloaded moments within a window, on hand-built series of the acme-at6x6 array (12-bit low-side
divider, 10 kohm pull-up: r = 10k * c / (4095 - c), so more counts is more resistance, less
load) and of a float (ohm) device.

The moving load: a bar three columns wide sweeps the 6 x 6 grid once in 36 s (polls every
0.1 s). Column g (channel i has g = i % 6 here) is loaded while ``(t - 6 g) mod 36 < 18`` s: half
the window loaded, half unloaded, and at every moment 18 channels are loaded, so a tare of the
whole array refuses at any moment. Each channel has its own hand-set baseline."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.analysis.tare import MIN_POLLS, ChannelSeries, TareError, compute_tare, samples_to_series
from gateway.analysis.tare_window import compute_window_tare, rest_stretch
from gateway.config import DeviceConfig, parse_config
from gateway.modbus.image import RawSample

CONFIG = """\
[[bus]]
name = "jaw"
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "jaw"
device_id = 1
profile = "acme-at6x6"
"""
#: a zero-sum noise cycle of 5 polls (counts)
CYCLE = np.array([-2, -1, 0, 1, 2])

N = 36
DT_S = 0.1
POLLS = 360  # 36 s
TIME_S: np.ndarray[Any, np.dtype[np.float64]] = DT_S * np.arange(POLLS, dtype=np.float64)
#: hand-set baselines (counts): 3880, 3883, ... 3898, repeating every 7 channels
BASE = np.array([3880 + 3 * (i % 7) for i in range(N)])
LOAD = 3300  # 10k * 3300 / 795 = 41509 ohm: several N by the default model


def acme(text: str = CONFIG) -> DeviceConfig:
    return parse_config(text, source=Path("/cfg/gateway.toml")).buses[0].devices[0]


def loaded_mask(i: int) -> np.ndarray:
    """True where channel ``i`` carries the bar (18 of the 36 s)."""
    return ((TIME_S - 6.0 * (i % 6)) % 36.0) < 18.0 - 1e-9


def unloaded_span_s(i: int) -> tuple[float, float]:
    """The latest unloaded interval of channel ``i`` in the window (s, inclusive of its polls)."""
    free = ~loaded_mask(i)
    last = int(np.flatnonzero(free)[-1])
    first = last
    while first > 0 and free[first - 1]:
        first -= 1
    return float(TIME_S[first]), float(TIME_S[last])


def moving_load_counts() -> np.ndarray:
    """(polls, channels): each channel at its baseline with a zero-mean +-2 count noise where
    unloaded, at ``LOAD`` with the same noise where loaded."""
    k = np.arange(POLLS)
    out = np.empty((POLLS, N))
    for i in range(N):
        noise = CYCLE[(k + i) % 5]
        out[:, i] = np.where(loaded_mask(i), LOAD, BASE[i]) + noise
    return out


def samples(counts: np.ndarray) -> list[RawSample]:
    return [RawSample(counts=np.asarray(row, dtype=np.uint16)) for row in counts]


# ------------------------------------------------------------------------ the moving load
def test_the_whole_array_tare_refuses_a_moving_load_at_every_moment() -> None:
    counts = moving_load_counts()
    for start in (0, 120, 300):  # three 3 s snapshots
        with pytest.raises(TareError, match=r"^the array is loaded over"):
            compute_tare(
                acme(), samples(counts[start : start + 30]), times_s=list(TIME_S[start : start + 30])
            )
    with pytest.raises(TareError):  # and the whole window too
        compute_tare(acme(), samples(counts), times_s=list(TIME_S))


def test_each_channel_is_zeroed_from_its_own_unloaded_moments() -> None:
    device = acme()
    series = samples_to_series(device, samples(moving_load_counts()), times_s=list(TIME_S))
    result = compute_window_tare(device, series, counts=True, window="the 36 s sampled")
    assert result.skipped == ()
    assert result.tare.key == "baseline_counts"
    assert result.tare.channels == tuple(range(N))
    # the noise cycle sums to zero over 5 polls, so a stretch of any length averages within
    # 2 / MIN_POLLS = 0.2 counts of the baseline: the rounded value is the baseline itself
    assert result.tare.values == tuple(float(b) for b in BASE)
    for i in range(N):
        r_ohm = 10_000.0 * BASE[i] / (4095 - BASE[i])
        assert result.tare.resistance_ohm[i] == pytest.approx(r_ohm, rel=2e-3)
        # the stretch lies in the channel's latest unloaded interval, and is most of it
        lo, hi = unloaded_span_s(i)
        start_s, end_s = result.spans_s[i]
        assert lo - 1e-9 <= start_s < end_s <= hi + 1e-9, (i, result.spans_s[i], (lo, hi))
        assert end_s - start_s >= 0.8 * (hi - lo), (i, result.spans_s[i], (lo, hi))
    assert result.timed


def test_a_channel_loaded_throughout_is_named_and_not_zeroed() -> None:
    device = acme()
    counts = moving_load_counts()
    # ch14 carries a second, resting part: never below 3500 counts (10k * 3500 / 595 = 58824
    # ohm); its least loaded moments read 3500 +- 2
    counts[:, 14] = np.minimum(counts[:, 14], 3500 + CYCLE[np.arange(POLLS) % 5])
    series = samples_to_series(device, samples(counts), times_s=list(TIME_S))
    result = compute_window_tare(device, series, counts=True, window="the 36 s sampled")
    assert result.tare.channels == tuple(i for i in range(N) if i != 14)
    assert [i for i, _ in result.skipped] == [14]
    why = result.skipped[0][1]
    assert why.startswith("loaded throughout the 36 s sampled: at its least loaded (")
    assert "5.882e+04 ohm" in why  # the numbers: its resistance there ...
    conductance = (4095 - BASE) / (10_000.0 * BASE)
    conductance[14] = 1 / 58824.0
    ratio = conductance[14] / np.median(conductance)
    assert f"{ratio:.2g}x the median" in why  # ... and its conductance against the others'
    assert "N by the model" in why
    assert why.endswith("3x the median; sample longer, or lift the load off it for a moment")


def test_a_channel_recovering_by_creep_is_zeroed_from_its_later_still_stretch() -> None:
    """A float (ohm) channel: at 194750 ohm for 0-5 s, loaded (93670.9 ohm) 5-15 s, lifted at 15 s,
    then creeping back, ``R = B (1 - 0.08 exp(-(t - 15) / 3 s))``, to the end at 36 s; a
    +-0.1 % noise throughout. The creep is within the 0.5 % plateau band, less the noise, after
    15 + 3 ln(0.08 / 0.006) = 22.8 s; the mean over 15-36 s (a naive "after the lift") is
    1.1 % low, the mean over the still stretch within 0.2 %."""
    device = acme(
        CONFIG.replace(
            'profile = "acme-at6x6"', 'profile = "tactile-sim"\nchannels = 8\nencoding = "float32"'
        )
    )
    base = 194_750.0
    t = TIME_S
    k = np.arange(POLLS)
    creep = np.where(t >= 15.0, base * (1 - 0.08 * np.exp(-(t - 15.0) / 3.0)), base)
    r = np.where((t >= 5.0) & (t < 15.0), 93_670.9, creep) * (1 + 0.001 * CYCLE[k % 5] / 2)
    naive = float(np.mean(r[t >= 15.0]))
    assert naive / base - 1 < -0.01  # the recovery pulls a naive mean down by over 1 %
    assert 15.0 + 3.0 * math.log(0.08 / 0.006) == pytest.approx(22.77, abs=0.01)
    series = [ChannelSeries(i, r.copy(), t) for i in range(8)]
    # the other 7 channels: still at 200 kohm throughout
    series[1:] = [ChannelSeries(i, np.full(POLLS, 200_000.0), t) for i in range(1, 8)]
    result = compute_window_tare(device, series, counts=False, window="0-36 s of rec.csv")
    assert result.tare.key == "baseline_ohm" and result.skipped == ()
    assert result.tare.values[0] == pytest.approx(base, rel=2e-3)
    start_s, end_s = result.spans_s[0]
    assert start_s >= 22.7 and end_s == pytest.approx(35.9)
    assert result.tare.values[1:] == (200_000.0,) * 7


def test_a_creep_inside_the_plateau_band_is_cut_from_the_stretch_start() -> None:
    """A noisier channel (+-6 counts: sigma from its steps 1.4826 x 3 / sqrt 2 = 3.1 counts, a
    plateau band of 4 sigma = 12.6 counts) lifted at 10 s and creeping back as
    ``B - 12 exp(-(t - 10) / 4 s)``: all of 10-36 s is in the band, but its first third
    (10-18.7 s) averages about 12 x 4 / 8.7 x (1 - exp(-2.2)) = 5 counts below its last: moving.
    The first third is dropped; 18.7-36 s is still (about 0.7 counts between its thirds) and
    averages about 0.3 counts low: the baseline rounds to B. Over 10-36 s it would be about
    1.9 counts low and round to B - 2."""
    device = acme()
    counts = moving_load_counts()
    b = BASE[9]
    t = TIME_S
    recovery = np.where(t >= 10.0, b - 12.0 * np.exp(-(t - 10.0) / 4.0), LOAD)
    counts[:, 9] = np.rint(recovery) + 3 * CYCLE[np.arange(POLLS) % 5]
    assert b - float(np.mean(recovery[t >= 10.0])) > 1.5  # the naive mean is low
    series = samples_to_series(device, samples(counts), times_s=list(TIME_S))
    result = compute_window_tare(device, series, counts=True, window="the 36 s sampled")
    k = result.tare.channels.index(9)
    assert result.tare.values[k] == float(b)
    start_s, end_s = result.spans_s[k]
    assert start_s >= 15.0 and end_s == pytest.approx(35.9)


def test_a_channel_that_never_rests_is_named_with_its_drift() -> None:
    device = acme()
    counts = moving_load_counts()
    # ch03 ramps 3700 -> 3890 over the window: at no moment still, never at a plateau
    counts[:, 3] = np.rint(3700 + 190 * np.arange(POLLS) / (POLLS - 1))
    series = samples_to_series(device, samples(counts), times_s=list(TIME_S))
    result = compute_window_tare(device, series, counts=True, window="the 36 s sampled")
    assert [i for i, _ in result.skipped] == [3]
    why = result.skipped[0][1]
    assert why.startswith("never still at its own extreme for 10 polls in the 36 s sampled")
    assert "counts/s" in why and 3 not in result.tare.channels


def test_nothing_to_zero_is_refused_naming_every_channel() -> None:
    device = acme()
    counts = np.full((POLLS, N), 3500.0) + CYCLE[np.arange(POLLS) % 5][:, None]
    series = samples_to_series(device, samples(counts), times_s=list(TIME_S))
    with pytest.raises(TareError) as err:
        compute_window_tare(device, series, counts=True, window="the 36 s sampled")
    message = str(err.value)
    assert message.startswith("no channel rested in the 36 s sampled: ch00 (loaded throughout")
    assert message.endswith("nothing was written")


def test_without_times_the_span_is_given_in_polls() -> None:
    device = acme()
    series = samples_to_series(device, samples(moving_load_counts()))
    result = compute_window_tare(device, series, counts=True, window="the polls")
    assert not result.timed
    start, end = result.spans_s[0]  # ch00 unloaded from poll 180 to 359
    assert 180 <= start < end == 359


# ------------------------------------------------------------------------ rest_stretch alone
def test_rest_stretch_of_a_constant_series_is_the_whole_series() -> None:
    found = rest_stretch(np.full(25, 7.0), floor_abs=2.0)
    assert found.stretch is not None
    assert (found.stretch.start, found.stretch.stop, found.stretch.mean) == (0, 25, 7.0)
    assert found.level == 7.0


def test_rest_stretch_with_too_few_polls_finds_none() -> None:
    found = rest_stretch(np.full(MIN_POLLS - 1, 7.0), floor_abs=2.0)
    assert found.stretch is None and found.why == f"only {MIN_POLLS - 1} polls"


def test_rest_stretch_of_rests_too_short_names_the_longest() -> None:
    # a cell tapped every 0.5 s: 6 polls at rest (100), 4 pressed (40), 8 times over
    values = np.tile(np.concatenate([np.full(6, 100.0), np.full(4, 40.0)]), 8)
    found = rest_stretch(values, floor_abs=2.0)
    assert found.stretch is None and found.moving is None
    assert found.why == "never still at its own extreme for 10 polls (its longest rest there: 6 polls)"


def test_a_rest_just_begun_at_the_end_gives_way_to_a_longer_one() -> None:
    # 60 polls at rest, 40 loaded, 12 at rest at the end: 12 < 60 / 2, the earlier rest
    values = np.concatenate([np.full(60, 100.0), np.full(40, 40.0), np.full(12, 100.0)])
    found = rest_stretch(values, floor_abs=2.0)
    assert found.stretch is not None and (found.stretch.start, found.stretch.stop) == (0, 60)
    # 20 at rest, 40 loaded, 12 at rest: 12 >= max(10, 20 / 2), the latest
    values = np.concatenate([np.full(20, 100.0), np.full(40, 40.0), np.full(12, 100.0)])
    found = rest_stretch(values, floor_abs=2.0)
    assert found.stretch is not None and (found.stretch.start, found.stretch.stop) == (60, 72)


def test_rest_stretch_looks_down_when_low_is_unloaded() -> None:
    # a high-side reading: less is less load; 10 polls at 50, then 20 at 900 (loaded)
    values = np.concatenate([np.full(10, 50.0), np.full(20, 900.0)])
    found = rest_stretch(values, unloaded_high=False, floor_abs=2.0)
    assert found.stretch is not None and found.stretch.mean == 50.0
    assert (found.stretch.start, found.stretch.stop) == (0, 10)


@pytest.mark.parametrize("seed", range(200))
def test_a_noisy_rest_is_taken_whole_not_its_upper_half(seed: int) -> None:
    """Quantized normal noise of 2 counts (the simulator's rawgrid board): 100 polls loaded at
    3300, then 60 at rest around 3895. The extreme (the best median of 10 polls) sits about 1 sigma
    above the rest; the level is taken again from the rest's later half and the noise from its
    steps, and a band of 4 sigma below it keeps the rest whole: a stretch of at least 50 of
    the 60 polls whose mean is within 0.5 counts of the rest's (the standard error of 60 polls
    is 0.26 counts). A band that cut into the noise would keep its upper half, short and high."""
    rng = np.random.default_rng(seed)
    rest = 3895 + np.rint(rng.normal(0.0, 2.0, 60))
    values = np.concatenate([3300 + np.rint(rng.normal(0.0, 2.0, 100)), rest])
    found = rest_stretch(values, floor_abs=2.0)
    assert found.stretch is not None
    # to the end, but for a last poll or two outside the band (no rest after them to bridge to)
    assert found.stretch.stop >= 158 and found.stretch.n_polls >= 50, found.stretch
    taken = rest[found.stretch.start - 100 : found.stretch.stop - 100]
    assert found.stretch.mean == pytest.approx(taken.mean(), abs=1e-9)
    assert abs(found.stretch.mean - rest.mean()) < 0.5


@pytest.mark.parametrize("seed", range(50))
def test_a_rest_a_device_repeats_is_taken_whole(seed: int) -> None:
    """The same, read by polls three times faster than the device updates its frame: each
    sample repeats three times. The repeats are no measurements of the noise (their steps are
    0): the rest is still taken whole, at least 150 of its 180 polls."""
    rng = np.random.default_rng(seed)
    rest = np.repeat(3895 + np.rint(rng.normal(0.0, 2.0, 60)), 3)
    values = np.concatenate([np.repeat(3300 + np.rint(rng.normal(0.0, 2.0, 100)), 3), rest])
    found = rest_stretch(values, floor_abs=2.0)
    assert found.stretch is not None
    assert found.stretch.stop >= values.size - 6 and found.stretch.n_polls >= 150, found.stretch
    assert abs(found.stretch.mean - rest.mean()) < 0.5


@settings(max_examples=60, deadline=None)
@given(
    level=st.floats(1e3, 1e6),
    tail=st.integers(MIN_POLLS, 60),
    head=st.lists(st.floats(0.1, 0.9), min_size=0, max_size=80),
)
def test_rest_stretch_ends_with_a_still_tail_at_the_top(level: float, tail: int, head: list[float]) -> None:
    """Any series whose last ``tail`` polls sit still at a level every earlier poll is at least
    1 % below: the stretch is exactly that tail, at that level."""
    values = np.concatenate([level * np.asarray(head, dtype=np.float64).reshape(-1), np.full(tail, level)])
    values[: len(head)] = np.minimum(values[: len(head)], 0.99 * level)
    found = rest_stretch(values, floor_rel=0.005)
    assert found.stretch is not None
    assert found.stretch.stop == values.size
    assert found.stretch.start == len(head)
    assert found.stretch.mean == pytest.approx(level, rel=1e-12)
