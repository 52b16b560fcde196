"""Work a calibration can run on another core: a fit or a read-back handed to a worker process.

``Workers(jobs)`` is a context manager with ``submit(fn, *args)`` returning a
``concurrent.futures.Future``. With ``jobs`` > 1 the calls run in up to ``jobs - 1`` worker
processes forked from this one (the caller keeps the last core for its own share of the work),
or in ``jobs`` of them with ``spare_caller=False`` (the caller only waits: whole channels, each
a calibration of its own, ``gateway.cli.calibrate_pool``; a discrepancy step's candidate fits).
With ``jobs`` = 1, or where ``fork`` is not available, each call runs at once in this process
and its future is already done. A call does the same arithmetic in either place, so a result is
the same to the bit (``tests/unit/gateway/analysis/test_parallel.py``). Leaving the block waits
for every worker and ends it: nothing outlives a calibration.

numpy's own threads are pinned to one per process by the command line (``gateway.cli._threads``)
before numpy loads, so two workers on two cores do not fight over them.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from types import TracebackType
from typing import ParamSpec, TypeVar

__all__ = ["Workers", "default_jobs"]

P = ParamSpec("P")
T = TypeVar("T")


def default_jobs() -> int:
    """Every core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class Workers:
    """Calls handed to forked worker processes (module docstring)."""

    def __init__(self, jobs: int | None = None, spare_caller: bool = True) -> None:
        self.jobs = default_jobs() if jobs is None else int(jobs)
        if self.jobs < 1:
            raise ValueError(f"jobs = {jobs!r} must be at least 1")
        self.spare_caller = spare_caller
        self._executor: Executor | None = None

    @property
    def parallel(self) -> bool:
        return self.jobs > 1 and "fork" in multiprocessing.get_all_start_methods()

    def __enter__(self) -> Workers:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None

    def submit(self, fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> Future[T]:
        """``fn(*args, **kwargs)`` in a worker, or here and now without one."""
        if not self.parallel:
            done: Future[T] = Future()
            try:
                done.set_result(fn(*args, **kwargs))
            except Exception as exc:  # the caller sees it from .result(), as from a worker
                done.set_exception(exc)
            return done
        if self._executor is None:
            self._executor = ProcessPoolExecutor(
                max_workers=self.jobs - 1 if self.spare_caller else self.jobs,
                mp_context=multiprocessing.get_context("fork"),
            )
        return self._executor.submit(fn, *args, **kwargs)
