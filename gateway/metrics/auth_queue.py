"""The bcrypt checks of unverified logins: one at a time, taken from the client addresses in turn.

A bcrypt check costs up to about 0.3 s (``web_config.MAX_BCRYPT_COST``), so the server runs
them on one thread of their own, and a flood of wrong passwords must not hold a right one
out (issue 33 §4). Checks are queued per client address (``request.remote``) and taken
round-robin: a scraper's check waits behind at most one check of each other address with
checks waiting, however many connections flood from one address. Admission:

* up to ``limit`` checks wait or run at once, from any addresses;
* beyond that, only an address with no check waiting is admitted, up to ``hard_limit`` in
  all, so a flood from a few addresses never refuses a new address; only a flood from more
  than ``hard_limit - limit`` distinct addresses can fill it;
* anything else is refused at once (the caller answers 503 with ``Retry-After``).

Everything here runs on the server's event loop (not thread-safe); ``run`` runs on
``executor``.
"""

from __future__ import annotations

import asyncio
import functools
from collections import deque
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass

__all__ = ["FairChecks"]


@dataclass(frozen=True, eq=False)
class _Check:
    run: Callable[[], bool]
    result: asyncio.Future[bool]


class FairChecks:
    """Checks waiting per address, run one at a time on ``executor``, addresses in turn."""

    def __init__(self, executor: Executor, limit: int, hard_limit: int) -> None:
        if not 1 <= limit <= hard_limit:
            raise ValueError(f"need 1 <= limit <= hard_limit, got {limit} and {hard_limit}")
        self.executor = executor
        self.limit = limit
        self.hard_limit = hard_limit
        self._waiting: dict[str, deque[_Check]] = {}
        self._per_address: dict[str, int] = {}
        #: when each address with checks pending was last served (a count of checks started)
        self._served_at: dict[str, int] = {}
        self._started = 0
        self._running: asyncio.Future[bool] | None = None
        #: checks waiting or running
        self.pending = 0

    def admits(self, address: str) -> bool:
        """Whether a check from ``address`` may queue now (see the module docstring)."""
        if self.pending < self.limit:
            return True
        return self._per_address.get(address, 0) == 0 and self.pending < self.hard_limit

    async def check(self, address: str, run: Callable[[], bool]) -> bool:
        """``run()``'s answer once its turn came and it ran (call ``admits`` first)."""
        loop = asyncio.get_running_loop()
        item = _Check(run, loop.create_future())
        self._waiting.setdefault(address, deque()).append(item)
        self._per_address[address] = self._per_address.get(address, 0) + 1
        self.pending += 1
        try:
            self._next(loop)
            return await item.result
        finally:
            self.pending -= 1
            left = self._per_address[address] - 1
            if left:
                self._per_address[address] = left
            else:
                del self._per_address[address]
                self._served_at.pop(address, None)

    def cancel_all(self) -> None:
        """Cancel every check, the running one included (the server stops)."""
        if self._running is not None:
            self._running.cancel()
        for queue in self._waiting.values():
            for item in queue:
                item.result.cancel()
        self._waiting.clear()

    def _next(self, loop: asyncio.AbstractEventLoop) -> None:
        """If none runs, start the next check: from the waiting address served longest ago
        (never first; ties in order of arrival)."""
        while self._running is None and self._waiting:
            address = min(self._waiting, key=lambda a: self._served_at.get(a, -1))
            queue = self._waiting[address]
            item = queue.popleft()
            if not queue:
                del self._waiting[address]
            self._started += 1
            self._served_at[address] = self._started
            if item.result.done():  # its request has gone (cancelled)
                continue
            running = loop.run_in_executor(self.executor, item.run)
            self._running = running
            running.add_done_callback(functools.partial(self._finished, loop, item))

    def _finished(self, loop: asyncio.AbstractEventLoop, item: _Check, done: asyncio.Future[bool]) -> None:
        self._running = None
        if not item.result.done():
            if done.cancelled():
                item.result.cancel()
            elif (exc := done.exception()) is not None:
                item.result.set_exception(exc)
            else:
                item.result.set_result(done.result())
        if not loop.is_closed():
            self._next(loop)
