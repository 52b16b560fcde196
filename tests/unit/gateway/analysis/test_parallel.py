"""``parallel.Workers``: a calibration's fits and read-back on other cores give the same result
to the bit as one process, and nothing outlives the block (the shared fixture fails a test that
leaks a process or a thread)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from gateway.analysis.calibration import calibrate
from gateway.analysis.parallel import Workers
from gateway.analysis.records import read_record

REAL = Path(__file__).resolve().parents[3] / "data" / "real"


def _pid() -> int:
    return os.getpid()


def _fail(message: str) -> None:
    raise ValueError(message)


def test_a_calibration_on_two_processes_equals_one_on_one() -> None:
    record = read_record(REAL / "tams_10k-nosil-cylindertip.csv", require_force=True)
    one = calibrate(record.channel(), metadata=record.metadata, jobs=1)
    two = calibrate(record.channel(), metadata=record.metadata, jobs=2)
    assert json.dumps(one.as_dict(), sort_keys=True) == json.dumps(two.as_dict(), sort_keys=True)
    assert [(s.name, s.held_out_force_rms_n, s.drift) for s in one.scores] == [
        (s.name, s.held_out_force_rms_n, s.drift) for s in two.scores
    ]
    assert one.fit.params == two.fit.params


def test_workers_run_elsewhere_only_with_more_than_one_job() -> None:
    with Workers(1) as inline:
        assert inline.submit(_pid).result() == os.getpid()
    with Workers(2) as forked:
        assert forked.parallel
        assert forked.submit(_pid).result() != os.getpid()


@pytest.mark.parametrize("jobs", [1, 2])
def test_an_error_in_a_worker_reaches_the_caller(jobs: int) -> None:
    with Workers(jobs) as workers:
        future = workers.submit(_fail, "no fit")
        with pytest.raises(ValueError, match="no fit"):
            future.result()


def test_jobs_below_one_are_refused() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        Workers(0)
