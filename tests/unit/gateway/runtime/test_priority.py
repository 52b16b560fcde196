"""``yield_to_poll_loop``: the calling thread's niceness rises by ``BACKGROUND_NICE`` (10), capped
at 19, and no other thread's changes (Linux schedules threads one by one).

Every call runs in a thread started for it: a niceness once raised cannot be lowered again
without privilege, so the test process's own threads must never call it."""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable
from typing import TypeVar

import pytest
from prometheus_client import CollectorRegistry

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.metrics.server import MetricsServer
from gateway.model import SensorParams
from gateway.runtime import priority
from gateway.runtime.priority import BACKGROUND_NICE, FAST_POLL_INTERVAL_S, polls_fast, yield_to_poll_loop

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="threads have a niceness of their own on Linux only"
)

_T = TypeVar("_T")


def nice_of(tid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, tid)


def own_nice() -> int:
    return nice_of(threading.get_native_id())


def in_a_new_thread(fn: Callable[[], _T]) -> _T:
    """``fn()`` run in a thread of its own (joined); what it returned or raised."""
    out: list[_T] = []
    err: list[BaseException] = []

    def run() -> None:
        try:
            out.append(fn())
        except BaseException as exc:
            err.append(exc)

    thread = threading.Thread(target=run, name="test-priority")
    thread.start()
    thread.join(timeout=30.0)
    assert not thread.is_alive()
    if err:
        raise err[0]
    return out[0]


def test_the_background_step_is_ten() -> None:
    assert BACKGROUND_NICE == 10  # the numbers below are computed by hand with it


def test_the_calling_thread_rises_by_the_step_and_the_main_thread_does_not() -> None:
    main_tid = threading.get_native_id()
    main_before, process_before = nice_of(main_tid), os.getpriority(os.PRIO_PROCESS, 0)

    def call() -> tuple[int, int | None, int, int]:
        before = own_nice()
        returned = yield_to_poll_loop()
        return before, returned, own_nice(), nice_of(main_tid)

    before, returned, after, main_meanwhile = in_a_new_thread(call)
    assert before == main_before  # a new thread starts at its creator's niceness
    assert after == min(19, before + 10)
    assert returned == after
    assert main_meanwhile == main_before
    assert nice_of(main_tid) == main_before
    assert os.getpriority(os.PRIO_PROCESS, 0) == process_before


@pytest.mark.parametrize("above", [0, 5, 9, 10, 15, 19])
def test_the_niceness_is_capped_at_19(above: int) -> None:
    # starts from this process's own niceness (raising it needs no privilege), whatever that is
    start = min(19, nice_of(threading.get_native_id()) + above)
    expected = min(19, start + 10)

    def call() -> tuple[int | None, int]:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), start)  # raising: no privilege
        return yield_to_poll_loop(), own_nice()

    assert in_a_new_thread(call) == (expected, expected)


def test_threads_the_yielding_thread_starts_inherit_its_niceness() -> None:
    main_before = own_nice()

    def call() -> tuple[int | None, int]:
        yielded = yield_to_poll_loop()
        return yielded, in_a_new_thread(own_nice)

    yielded, child = in_a_new_thread(call)
    assert yielded == min(19, main_before + 10)
    assert child == yielded
    assert own_nice() == main_before


def test_elsewhere_it_does_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(priority.sys, "platform", "darwin")

    def call() -> tuple[int, int | None, int]:
        before = own_nice()
        return before, yield_to_poll_loop(), own_nice()

    before, returned, after = in_a_new_thread(call)
    assert returned is None and after == before


def test_a_refusal_is_none_and_leaves_the_niceness(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(which: int, who: int, prio: int) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(priority.os, "setpriority", refuse)

    def call() -> tuple[int, int | None, int]:
        before = own_nice()
        return before, yield_to_poll_loop(), own_nice()

    before, returned, after = in_a_new_thread(call)
    assert returned is None and after == before


@pytest.mark.parametrize(
    ("intervals", "fast"),
    [((0.0,), True), ((0.1, 0.0099), True), ((0.01,), False), ((0.1, 1.0), False), ((), False)],
)
def test_a_fast_bus_polls_more_often_than_every_10_ms(intervals: tuple[float, ...], fast: bool) -> None:
    assert FAST_POLL_INTERVAL_S == 0.01
    buses = [
        bus_config_for(
            f"b{k}",
            "tcp",
            [device_config_for(f"d{k}", 1, [SensorParams()] * 4, 2, 2.5)],
            host="127.0.0.1",
            port=502 + k,
            poll_interval_s=interval,
        )
        for k, interval in enumerate(intervals)
    ]
    assert polls_fast(gateway_config_for(buses)) is fast


@pytest.mark.parametrize("fast", [True, False])
def test_the_metrics_server_thread_yields_only_when_told(fast: bool) -> None:
    main = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    with MetricsServer(CollectorRegistry(), "127.0.0.1", 0, yield_to_polling=fast) as server:
        thread = server._thread
        assert thread is not None and thread.native_id is not None
        niceness = os.getpriority(os.PRIO_PROCESS, thread.native_id)
    assert niceness == (min(19, main + BACKGROUND_NICE) if fast else main)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == main
