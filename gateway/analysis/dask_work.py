"""Calibration tasks on a Dask distributed cluster (``calibrate --scheduler ADDRESS``).

``DaskWorkers(address)`` connects a ``distributed.Client`` to a running scheduler and offers the
same ``submit(fn, *args)`` -> ``concurrent.futures.Future`` as ``parallel.Workers``, through the
client's own executor (``Client.get_executor``): Dask queues, places and retries the tasks; this
module keeps no queue of its own. Records are read once, here, and each channel's rows are
shipped with its task (nothing needs a shared filesystem); the workers need this package at the
same version (the task is ``channel_work.fit_one``, pickled by name). Leaving the block cancels
what is still queued and closes the client; the cluster itself is left running.

``distributed`` is imported only here, and only when a scheduler is named."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor, Future
from types import TracebackType
from typing import Any, ParamSpec, TypeVar

__all__ = ["CONNECT_TIMEOUT_S", "DaskWorkers", "SchedulerError"]

P = ParamSpec("P")
T = TypeVar("T")

#: How long to try to reach the scheduler before giving up (s).
CONNECT_TIMEOUT_S = 10.0


class SchedulerError(Exception):
    """No usable scheduler at the address given (the message says why, in one line)."""


class DaskWorkers:
    """Tasks handed to a Dask scheduler's workers (module docstring)."""

    def __init__(self, address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        self.address = address
        self.timeout_s = timeout_s
        self._client: Any = None
        self._executor: Executor | None = None
        self.jobs = 0

    def __enter__(self) -> DaskWorkers:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - a dependency of the package
            raise SchedulerError(f"--scheduler needs dask.distributed: {exc}") from None
        # a Client that fails to connect leaves its event-loop thread behind (and a traceback when
        # it is collected): reach the scheduler first on a loop of our own, then connect
        self._probe()
        try:
            self._client = Client(self.address, timeout=self.timeout_s, set_as_default=False)
        except (OSError, ValueError, TypeError) as exc:
            raise self._error(exc) from None
        self.jobs = max(1, sum(self._client.nthreads().values()))
        self._executor = self._client.get_executor(pure=False)
        return self

    def _probe(self) -> None:
        import asyncio

        from distributed.comm import connect

        async def reach() -> None:
            comm = await connect(self.address, timeout=self.timeout_s)
            await comm.close()

        try:
            asyncio.run(reach())
        except (OSError, ValueError, TypeError) as exc:
            raise self._error(exc) from None

    def _error(self, exc: BaseException) -> SchedulerError:
        why = " ".join(str(exc).split()) or type(exc).__name__
        return SchedulerError(f"--scheduler {self.address!r}: no Dask scheduler reached ({why})")

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=kind is None)
            self._executor = None
        if self._client is not None:
            self._client.close()
            self._client = None

    def submit(self, fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> Future[T]:
        """``fn(*args, **kwargs)`` on one of the cluster's workers."""
        assert self._executor is not None, "use DaskWorkers in a with block"
        return self._executor.submit(fn, *args, **kwargs)
