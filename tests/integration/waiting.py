"""Waiting on events instead of for fixed times (docs/reliability.md, issue 25).

A test that sleeps for the time an event usually takes is slow on an idle machine and wrong on
a busy one. These helpers poll the event's own condition (a process's line, a counter, a
device clock, a port) until it holds or a deadline passes, and fail naming what was awaited.
The deadline is a backstop, far beyond the usual wait: it only bounds how long a broken test
takes to fail.
"""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Callable
from typing import Any


class ManualClock:
    """A clock (s) that moves only when the test moves it: ``SimArray(..., clock=clock)`` makes
    the simulated device's time ``speed x clock()``, so the device is at a chosen instant
    however long the test's requests take."""

    def __init__(self, start_s: float = 0.0) -> None:
        self.now_s = start_s

    def __call__(self) -> float:
        return self.now_s

    def advance(self, dt_s: float) -> None:
        self.now_s += dt_s


async def until(
    cond: Callable[[], Any],
    timeout_s: float,
    what: str,
    *,
    step_s: float = 0.02,
    ignore: tuple[type[BaseException], ...] = (),
) -> Any:
    """Poll ``cond()`` (a function or a coroutine function) until its value is truthy and
    return that value; an exception in ``ignore`` counts as not yet. Fails naming ``what``
    (and the last value or exception) after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    last: Any = None
    while True:
        try:
            last = cond()
            if inspect.isawaitable(last):
                last = await last
            if last:
                return last
        except ignore as exc:
            last = exc
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what} (last: {last!r})")
        await asyncio.sleep(step_s)


def wait_for(
    cond: Callable[[], Any],
    timeout_s: float,
    what: str,
    *,
    step_s: float = 0.05,
    ignore: tuple[type[BaseException], ...] = (),
) -> Any:
    """``until`` for code outside an event loop (blocks the thread between checks)."""
    deadline = time.monotonic() + timeout_s
    last: Any = None
    while True:
        try:
            last = cond()
            if last:
                return last
        except ignore as exc:
            last = exc
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what} (last: {last!r})")
        time.sleep(step_s)
