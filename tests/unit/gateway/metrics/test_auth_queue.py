"""``FairChecks``: bcrypt checks one at a time, client addresses in turn (issue 33 §4)."""

from __future__ import annotations

import asyncio
import functools
import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

from gateway.metrics.auth_queue import FairChecks


class Held:
    """Checks that record their order and wait for a gate (the first one holds the thread)."""

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.ran: list[str] = []

    def run(self, label: str, answer: bool = True) -> bool:
        self.gate.wait(30)
        self.ran.append(label)
        return answer


async def settled(checks: FairChecks, pending: int) -> None:
    """Let the loop run until ``pending`` checks are queued (each request task has started)."""
    for _ in range(1000):
        if checks.pending == pending:
            return
        await asyncio.sleep(0)
    raise AssertionError(f"{checks.pending} checks pending, expected {pending}")


async def test_addresses_are_served_in_turn_not_in_arrival_order() -> None:
    held = Held()
    with ThreadPoolExecutor(1) as pool:
        checks = FairChecks(pool, limit=100, hard_limit=100)
        # address a floods five checks before b and c arrive with one each
        labels = ["a1", "a2", "a3", "a4", "a5", "b1", "c1"]
        tasks = []
        for label in labels:
            address = label[0]
            tasks.append(asyncio.create_task(checks.check(address, functools.partial(held.run, label))))
            await asyncio.sleep(0)
        await settled(checks, len(labels))
        held.gate.set()
        assert await asyncio.gather(*tasks) == [True] * len(labels)
    # a1 was running when b and c came; then each address in turn: b, c, then a's rest
    assert held.ran == ["a1", "b1", "c1", "a2", "a3", "a4", "a5"]
    assert checks.pending == 0


async def test_a_full_queue_still_admits_an_address_with_no_check_waiting_up_to_the_hard_limit() -> None:
    held = Held()
    with ThreadPoolExecutor(1) as pool:
        checks = FairChecks(pool, limit=3, hard_limit=5)
        tasks = [asyncio.create_task(checks.check("flood", lambda: held.run("f"))) for _ in range(3)]
        await settled(checks, 3)
        assert not checks.admits("flood")  # the flood's own fourth check is refused
        assert checks.admits("scraper")
        tasks.append(asyncio.create_task(checks.check("scraper", lambda: held.run("s"))))
        await settled(checks, 4)
        assert not checks.admits("scraper")  # one at a time past the limit
        assert checks.admits("other")
        tasks.append(asyncio.create_task(checks.check("other", lambda: held.run("o"))))
        await settled(checks, 5)
        assert not checks.admits("third")  # the hard limit
        held.gate.set()
        await asyncio.gather(*tasks)
    assert held.ran == ["f", "s", "o", "f", "f"]
    assert checks.admits("flood") and checks.pending == 0


async def test_a_check_whose_request_went_is_skipped_and_an_error_reaches_its_caller() -> None:
    held = Held()
    with ThreadPoolExecutor(1) as pool:
        checks = FairChecks(pool, limit=10, hard_limit=10)
        first = asyncio.create_task(checks.check("a", lambda: held.run("first")))
        gone = asyncio.create_task(checks.check("b", lambda: held.run("gone")))

        def fails() -> bool:
            raise RuntimeError("bcrypt refused")

        failing = asyncio.create_task(checks.check("c", fails))
        await settled(checks, 3)
        gone.cancel()
        held.gate.set()
        assert await first is True
        with pytest.raises(RuntimeError, match="bcrypt refused"):
            await failing
        with pytest.raises(asyncio.CancelledError):
            await gone
    assert held.ran == ["first"] and checks.pending == 0


def test_limits_are_checked() -> None:
    with ThreadPoolExecutor(1) as pool, pytest.raises(ValueError, match="1 <= limit <= hard_limit"):
        FairChecks(pool, limit=4, hard_limit=3)
