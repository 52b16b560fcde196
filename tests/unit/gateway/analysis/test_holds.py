"""Holds of a reference force on hand-made series: levels, noise, ramps, too-short holds."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.analysis.holds import Hold, find_holds, hold_tolerance_n


def _steps(levels: list[tuple[float, float]], dt: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A staircase: (duration s, level N) pieces sampled every ``dt`` s."""
    t: list[float] = []
    f: list[float] = []
    now = 0.0
    for duration, level in levels:
        n = round(duration / dt)
        t += [now + k * dt for k in range(n)]
        f += [level] * n
        now += n * dt
    return np.array(t), np.array(f)


def _spans(holds: tuple[Hold, ...]) -> list[tuple[int, int, float, float, float]]:
    return [(h.start, h.stop, h.start_s, h.end_s, round(h.level_n, 9)) for h in holds]


def test_levels_of_a_staircase_are_holds_and_zero_is_not() -> None:
    # 0 N 5 s, 1 N 10 s, 3 N 6 s, 0 N 5 s at 2 samples/s: rows 10-29, 30-41
    t, f = _steps([(5.0, 0.0), (10.0, 1.0), (6.0, 3.0), (5.0, 0.0)])
    holds = find_holds(t, f)
    assert _spans(holds) == [(10, 30, 5.0, 14.5, 1.0), (30, 42, 15.0, 20.5, 3.0)]
    assert holds[0].duration_s == pytest.approx(9.5) and holds[0].n_rows == 20


def test_a_hold_shorter_than_three_seconds_is_not_one() -> None:
    # 2 N for 3.0 s of rows at 0.5 s spacing: first to last row 2.5 s; 2 N for 3.5 s: 3.0 s, kept
    t, f = _steps([(2.0, 0.0), (3.0, 2.0), (2.0, 0.0), (3.5, 2.0), (2.0, 0.0)])
    holds = find_holds(t, f)
    assert _spans(holds) == [(14, 21, 7.0, 10.0, 2.0)]
    assert find_holds(t, f, min_duration_s=2.5)[0].start == 4


def test_noise_within_the_tolerance_keeps_one_hold_and_beyond_it_splits_it() -> None:
    t, f = _steps([(2.0, 0.0), (20.0, 4.0), (2.0, 0.0)])
    loaded = f > 0
    rng = np.random.default_rng(3)
    noisy = f.copy()
    noisy[loaded] += rng.uniform(-0.05, 0.05, loaded.sum())  # default tolerance: 2 % of 4.05 N
    (hold,) = find_holds(t, noisy)
    assert (hold.start, hold.stop) == (4, 44)
    assert hold.level_n == pytest.approx(float(noisy[4:44].mean()))
    # a spike of 0.5 N in the middle (row 24) belongs to neither: it ends one hold, the next
    # starts after it
    spiked = noisy.copy()
    spiked[24] += 0.5
    assert [(h.start, h.stop) for h in find_holds(t, spiked, tolerance_n=0.081)] == [(4, 24), (25, 44)]


def test_a_ramp_is_not_a_hold_but_its_plateau_is() -> None:
    # ramp 0 -> 5 N at 0.5 N/s (10 s), then 5 N for 8 s; tolerance 0.1 N (2 % of 5 N)
    t = np.arange(0.0, 18.0, 0.25)
    f = np.minimum(0.5 * t, 5.0)
    (hold,) = find_holds(t, f)
    assert hold_tolerance_n(f) == pytest.approx(0.1)
    # the plateau starts at t = 10 s (row 40); the ramp's last row within 0.2 N of 5 N is 9.75 s
    # (4.875 N): the run's mid-range 4.9375 N is within 0.1 N of every row from there
    assert (hold.start, hold.stop, hold.start_s, hold.end_s) == (39, 72, 9.75, 17.75)
    # a ramp slower than 2 x tolerance per 3 s is a hold to within the tolerance
    slow = 0.05 * t + 1.0
    assert [(h.start, h.start_s) for h in find_holds(t, slow, tolerance_n=0.1)][:1] == [(0, 0.0)]


def test_a_level_within_the_tolerance_of_zero_is_not_a_hold() -> None:
    t, f = _steps([(10.0, 0.05), (10.0, 2.0)])
    assert [h.level_n for h in find_holds(t, f, tolerance_n=0.06)] == [2.0]
    assert [h.level_n for h in find_holds(t, f, tolerance_n=0.04)] == pytest.approx([0.05, 2.0])


def test_nan_rows_and_a_step_back_in_time_end_a_run() -> None:
    t, f = _steps([(10.0, 1.0)])
    f[10] = np.nan
    assert [(h.start, h.stop) for h in find_holds(t, f)] == [(0, 10), (11, 20)]
    t2 = np.concatenate([t, t])
    f2 = np.full(t2.size, 1.0)
    assert [(h.start, h.stop) for h in find_holds(t2, f2)] == [(0, 20), (20, 40)]


def test_edges_are_the_first_and_last_tenth_of_the_rows_at_least_one() -> None:
    assert Hold(10, 35, 0.0, 12.0, 1.0).edges() == (slice(10, 12), slice(33, 35))  # 25 rows: 2
    assert Hold(0, 9, 0.0, 4.0, 1.0).edges() == (slice(0, 1), slice(8, 9))  # 9 rows: 1
    assert Hold(0, 100, 0.0, 50.0, 1.0).edge_rows() == 10
    assert Hold(0, 30, 0.0, 50.0, 1.0).edge_rows() == 3


def test_refuses_what_it_cannot_read() -> None:
    with pytest.raises(ValueError, match="one length"):
        find_holds([0.0, 1.0], [1.0])
    with pytest.raises(ValueError, match="tolerance_n"):
        find_holds([0.0, 1.0], [1.0, 1.0], tolerance_n=-1.0)
    assert find_holds([], []) == ()
