"""``runtime.replay`` of records whose channels are sampled at their own times (issue 33 §8).

A channel's results must not depend on when the other channels were sampled: replaying all
channels together equals replaying each channel alone through the same processor (the others'
series empty), to rounding, for physics channels of two effect sets and a curve channel with
drift. The processor runs once per sample rank (a channel's k-th sample), not once per
distinct time, so a record whose rows each have their own time costs what the same rows with
shared times cost (the speed itself is measured in bench/bench_view.py)."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.config import ChannelConfig, DeviceConfig, Encoding, RegisterMap
from gateway.config.layout import GridLayout
from gateway.model import PAPER_EFFECTS, Divider, SensorModel, SensorParams
from gateway.model.curves import CurveChannel, Drift, PowerLawCurve
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.replay import ChannelSeries, ReplayedChannel, replay
from gateway.runtime.snapshot import ChannelStatus

#: ch3 is read through a curve with drift (a1 = 0.2, tau = 5 s); ch2 by the physical model
#: without creep (a second effect set: a converter over part of the channels)
CREEP_CURVE = CurveChannel(PowerLawCurve(1e-4, 0.8), Drift(creep_fraction=0.2, creep_tau_s=5.0))
FORCES_N = (0.0, 0.3, 1.0, 2.5, 4.0)
STEPS_S = (0.0, 0.013, 0.1, 0.37, 1.0, 5.0, 40.0)


def _device(n: int = 4) -> DeviceConfig:
    effects = [PAPER_EFFECTS, PAPER_EFFECTS, ("tunneling", "contact"), PAPER_EFFECTS]
    channels = tuple(
        ChannelConfig(k, f"ch{k}", 2.5 * (k % 2), 2.5 * (k // 2), True, effects[k % 4], SensorParams(),
                      None, CREEP_CURVE if k % 4 == 3 else None)
        for k in range(n)
    )  # fmt: skip
    return DeviceConfig("rec", 1, Encoding.FLOAT32, n, RegisterMap(), Divider(), channels, False,
                        GridLayout(n, 2, 2.5, 2.5), None)  # fmt: skip


def _resistance(force_n: np.ndarray) -> np.ndarray:
    """The default sensor's static resistance at ``force_n`` (inf at 0 N: contact open)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return np.asarray(SensorModel(PAPER_EFFECTS, [SensorParams()]).resistance(force_n[:, None])[:, 0])


def _series(steps: list[float], forces: list[float], start_s: float) -> ChannelSeries:
    t = start_s + np.cumsum(np.asarray(steps, dtype=np.float64))
    f = np.asarray(forces, dtype=np.float64)
    return ChannelSeries(t, _resistance(f), f)


EMPTY = ChannelSeries(np.zeros(0), np.zeros(0), np.zeros(0))


def _alone(proc: DeviceProcessor, series: list[ChannelSeries], j: int) -> ReplayedChannel:
    only = [s if k == j else EMPTY for k, s in enumerate(series)]
    return replay(proc, only)[0][j]


channel_rows = st.integers(0, 14).flatmap(
    lambda n: st.tuples(
        st.lists(st.sampled_from(STEPS_S), min_size=n, max_size=n),
        st.lists(st.sampled_from(FORCES_N), min_size=n, max_size=n),
        st.sampled_from((0.0, 0.05, 0.2, 3.0)),
    )
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(channel_rows, min_size=4, max_size=4))
def test_each_channel_reads_as_it_does_alone(rows: list[tuple[list[float], list[float], float]]) -> None:
    proc = DeviceProcessor(_device(), bus="record", poll_interval_s=0.1)
    series = [_series(steps, forces, start) for steps, forces, start in rows]
    together, n_device = replay(proc, series)
    # a device sample per distinct time and occurrence of it within a channel (by hand)
    occurrences = {(t, sum(1 for u in s.time_s.tolist()[:i] if u == t)) for s in series
                   for i, t in enumerate(s.time_s.tolist())}  # fmt: skip
    assert n_device == len(occurrences)
    for j, s in enumerate(series):
        got, alone = together[j], _alone(proc, series, j)
        assert got.force_n.shape == s.time_s.shape
        np.testing.assert_array_equal(got.status, alone.status)
        np.testing.assert_allclose(got.force_n, alone.force_n, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got.force_static_n, alone.force_static_n, rtol=1e-9, atol=1e-9)


def test_distinct_times_read_as_the_same_rows_with_shared_times() -> None:
    """Sixteen channels on one load, channel k sampled k/16 of a step after channel 0: each
    channel's forces equal those of the record where all share channel 0's times, to the
    creep the offset makes (the load is held for most steps, so the difference is small)."""
    n, steps = 16, 60
    proc = DeviceProcessor(_device(n), bus="record", poll_interval_s=0.1)
    f = np.repeat(np.asarray([0.0, 1.0, 2.5, 1.0, 0.0, 4.0]), steps // 6)
    t = np.arange(steps, dtype=np.float64) * 1.0
    shared = [ChannelSeries(t, _resistance(f), f) for _ in range(n)]
    distinct = [ChannelSeries(t + k / n, _resistance(f), f) for k in range(n)]
    a, n_shared = replay(proc, shared)
    b, n_distinct = replay(proc, distinct)
    assert (n_shared, n_distinct) == (steps, steps * n)
    for ch_a, ch_b in zip(a, b, strict=True):
        np.testing.assert_array_equal(ch_a.status, ch_b.status)
        # the same steps, shifted: the first step of each is from its own first sample
        np.testing.assert_allclose(ch_a.force_n, ch_b.force_n, rtol=1e-9, atol=1e-9)


def test_the_processor_runs_once_per_sample_rank_not_per_distinct_time() -> None:
    """16 channels x 50 samples, every row its own time: 800 device samples, but the
    processor converts each channel's k-th sample together (50 conversions of the device)."""
    n, per = 16, 50
    proc = DeviceProcessor(_device(n), bus="record", poll_interval_s=0.1)
    calls = []
    track = proc.track

    def counted(*args: object, **kwargs: object) -> object:
        calls.append(1)
        return track(*args, **kwargs)  # type: ignore[arg-type]

    proc.track = counted  # type: ignore[method-assign,assignment]
    f = np.full(per, 1.0)
    t = np.arange(per, dtype=np.float64) * 0.5
    series = [ChannelSeries(t + k * 0.01, _resistance(f), f) for k in range(n)]
    results, n_device = replay(proc, series)
    assert n_device == n * per
    assert len(calls) == per
    assert all(int(s) == int(ChannelStatus.OK) for r in results for s in r.status.tolist())
