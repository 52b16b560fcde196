"""One channel's whole calibration as a task of its own: what a worker process or a Dask worker
runs when ``calibrate`` spreads the channels of its records over cores or machines.

A task gets everything it needs as values (the channel's rows, the record's metadata and the
fit's settings), so it computes on a worker the same numbers to the bit as here: the same
arithmetic on the same arrays, with numpy's BLAS on one thread in every process
(``gateway.cli._threads``; a Dask nanny starts its workers with ``OPENBLAS_NUM_THREADS=1``, its
``distributed.nanny.pre-spawn-environ`` default)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from ..model import SensorParams
from .calibration import Calibration, calibrate
from .records import ChannelRecord

__all__ = ["FitSettings", "fit_one"]


@dataclass(frozen=True)
class FitSettings:
    """The fit every channel of a run gets: effects, prior parameters (SI units), the physical
    model's objective (``log_r``, ``force``, ``auto``) and the zero-offset mode."""

    effects: tuple[str, ...]
    prior: SensorParams
    objective: str
    force_offset: str


def fit_one(
    settings: FitSettings, channel: ChannelRecord, record_name: str, metadata: Mapping[str, str]
) -> Calibration:
    """Calibrate one channel in this process (``jobs=1``: the channel is the unit of parallel work)."""
    return calibrate(
        channel,
        settings.effects,
        settings.prior,
        record_name=record_name,
        metadata=dict(metadata),
        objective=settings.objective,
        force_offset=settings.force_offset,
        jobs=1,
    )
