"""The paced clock of a simulated array: wall time, at most ``max_step_s`` per call."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.cli.simulated import PacedClock
from sim_device import ArrayConfig, SimArray


class FakeWall:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_follows_the_wall_while_calls_come_often() -> None:
    wall = FakeWall()
    clock = PacedClock(0.5, wall)
    readings = []
    for _ in range(4):
        wall.now += 0.2
        readings.append(clock())
    assert readings == pytest.approx([100.2, 100.4, 100.6, 100.8])


def test_a_late_call_gets_at_most_one_step_and_the_rest_is_not_made_up() -> None:
    wall = FakeWall()
    clock = PacedClock(0.5, wall)
    wall.now += 3.0  # a poll 3 s late
    assert clock() == pytest.approx(100.5)
    wall.now += 0.1
    assert clock() == pytest.approx(100.6)  # runs behind the wall from now on
    wall.now -= 1.0  # a wall clock that steps back gives no negative step
    assert clock() == pytest.approx(100.6)


@given(st.lists(st.floats(min_value=0.0, max_value=10.0), min_size=1, max_size=50))
def test_never_steps_back_nor_more_than_max_step(gaps: list[float]) -> None:
    wall = FakeWall()
    clock = PacedClock(0.25, wall)
    last = clock()
    for gap in gaps:
        wall.now += gap
        now = clock()
        assert 0.0 <= now - last <= min(gap, 0.25) + 1e-9
        last = now


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_refuses_a_step_that_is_not_a_positive_number(bad: float) -> None:
    with pytest.raises(ValueError, match="max_step_s must be a finite number > 0"):
        PacedClock(bad)


def test_a_simulated_array_on_a_paced_clock_advances_at_most_speed_x_step_per_read() -> None:
    wall = FakeWall()
    array = SimArray(
        ArrayConfig(channels=1, columns=1, speed=100.0), device_id=1, clock=PacedClock(0.04, wall)
    )
    wall.now += 60.0  # a minute without a read: at 100x, 6000 device seconds unpaced
    assert array.device_time_s == pytest.approx(4.0)
    wall.now += 0.01
    assert array.device_time_s == pytest.approx(5.0)
