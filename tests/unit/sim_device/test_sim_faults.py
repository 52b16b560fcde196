"""FaultInjector: validated fields, schedules over device time, probability."""

from __future__ import annotations

import pytest

from sim_device import FaultError, FaultEvent, FaultInjector


def test_fields_validate_and_clear() -> None:
    f = FaultInjector()
    assert not f.active
    f.delay_s = 0.5
    f.exception_code = 6
    f.garble = True
    assert f.active and f.decide(0.0).exception_code == 6
    for name, value in (("delay_s", -1.0), ("exception_code", 9), ("garble", 1), ("probability", 2.0)):
        with pytest.raises(FaultError):
            setattr(f, name, value)
    with pytest.raises(FaultError, match="unknown"):
        f.latency = 1.0
    f.clear()
    assert not f.active and f.decide(0.0).delay_s == 0.0


def test_schedule_switches_on_and_back_off() -> None:
    f = FaultInjector()
    f.schedule(10.0, until_s=20.0, no_response=True, delay_s=0.2)
    assert not f.decide(9.9).no_response
    d = f.decide(10.0)
    assert d.no_response and d.delay_s == 0.2
    assert not f.decide(20.0).no_response and f.delay_s == 0.0
    f.schedule_event(FaultEvent(at_s=30.0, changes={"exception_code": 4}))
    assert f.decide(31.0).exception_code == 4


def test_channel_events_are_popped_in_time_order() -> None:
    f = FaultInjector()
    f.schedule(5.0, until_s=6.0, channel=1, channel_mode="open")
    f.schedule(2.0, channel=0, channel_mode="short")
    assert f.pop_channel_events(1.0) == []
    assert f.pop_channel_events(5.5) == [(2.0, 0, 2), (5.0, 1, 1)]
    assert f.pop_channel_events(10.0) == [(6.0, 1, 0)]
    with pytest.raises(FaultError):
        f.schedule(1.0, channel_mode="open")
    with pytest.raises(FaultError):
        f.schedule(1.0, until_s=0.5, garble=True)
    with pytest.raises(FaultError):
        f.schedule(1.0)


def test_probability_hits_a_fraction_of_requests() -> None:
    f = FaultInjector(seed=3)
    f.exception_code = 6
    f.probability = 0.25
    hits = sum(f.decide(0.0).exception_code == 6 for _ in range(4000))
    assert 850 < hits < 1150
