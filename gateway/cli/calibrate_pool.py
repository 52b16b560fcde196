"""Where ``calibrate`` fits whole channels: forked processes on this machine (``--jobs N``,
``parallel.Workers``) or a Dask cluster (``--scheduler ADDRESS``, ``dask_work.DaskWorkers``).

Each channel of each record is one task (``channel_work.fit_one``) and the results come back
in the channels' order, so a calibration file is the same to the byte with any pool. A tracker
(``calibrate_progress``) is told as each channel is done."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future
from contextlib import AbstractContextManager
from typing import Any, Protocol

import click

from ..analysis.calibration import Calibration
from ..analysis.channel_work import FitSettings, fit_one
from ..analysis.dask_work import DaskWorkers, SchedulerError
from ..analysis.parallel import Workers
from ..analysis.records import ChannelRecord

__all__ = ["Pool", "Tracker", "open_pool", "submit_channels", "wants_channel_pool"]


class Pool(Protocol):
    """What runs the tasks: ``submit`` returns a future; ``jobs`` tasks run at once."""

    jobs: int

    def submit(self, fn: Any, /, *args: Any) -> Future[Any]: ...


class Tracker(Protocol):
    """Told what is done (``calibrate_progress``); its methods may be called from a pool's thread."""

    def add_record(self, record: str, channels: int) -> None: ...

    def channel_done(self, record: str, channel: str) -> None: ...

    def record_done(self, record: str, ok: bool) -> None: ...


class _Refused(click.ClickException):
    """A usage refusal found only when the pool starts (exit status 2, one line)."""

    exit_code = 2


class _Opened(AbstractContextManager["Workers | DaskWorkers"]):
    """The pool of a run, started on entry; a scheduler that cannot be reached is one line."""

    def __init__(self, pool: Workers | DaskWorkers) -> None:
        self.pool = pool

    def __enter__(self) -> Workers | DaskWorkers:
        try:
            return self.pool.__enter__()
        except SchedulerError as exc:
            raise _Refused(str(exc)) from None

    def __exit__(self, *exc: Any) -> None:
        self.pool.__exit__(*exc)


def open_pool(jobs: int | None, scheduler: str | None) -> _Opened:
    """``jobs`` forked processes (default: every core), or the Dask cluster at ``scheduler``."""
    if scheduler is not None:
        if jobs is not None:
            raise click.UsageError("--jobs and --scheduler do not go together: the cluster has its workers")
        return _Opened(DaskWorkers(scheduler))
    return _Opened(Workers(jobs, spare_caller=False))


def wants_channel_pool(n_channels: int, jobs: int | None, scheduler: str | None) -> bool:
    """Channels side by side: on a cluster, or with more than one channel and more than one job
    (a single channel keeps its own fits side by side instead, ``calibration.calibrate``)."""
    return scheduler is not None or (n_channels > 1 and Workers(jobs).jobs > 1)


def submit_channels(
    pool: Pool,
    settings: FitSettings,
    channels: Sequence[ChannelRecord],
    record_name: str,
    metadata: Mapping[str, str],
    tracker: Tracker,
) -> list[Future[Calibration]]:
    """One task per channel, in the channels' order; the tracker hears of each as it is done."""
    tracker.add_record(record_name, len(channels))
    futures: list[Future[Calibration]] = []
    for ch in channels:
        future: Future[Calibration] = pool.submit(fit_one, settings, ch, record_name, dict(metadata))
        future.add_done_callback(_told(tracker, record_name, ch.name))
        futures.append(future)
    return futures


def _told(tracker: Tracker, record_name: str, channel: str) -> Callable[[Future[Calibration]], None]:
    def done(_: Future[Calibration]) -> None:
        tracker.channel_done(record_name, channel)

    return done
