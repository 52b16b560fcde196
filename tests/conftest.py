"""The one fixture every test runs under: it fails a test that leaks a thread, a child
process or an asyncio task.

A thread or process a test started must be gone when the test ends (given a short grace for
those already told to stop); a task still pending when an async test returns was never
awaited or cancelled. Each leak is named in the failure.
"""

from __future__ import annotations

import asyncio
import os
import threading
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
import pytest_asyncio
from hypothesis import HealthCheck, settings

# Property tests check values, never time: no deadline per example (hypothesis' default of
# 200 ms fails an example that a busy 2-core machine merely ran slowly). Speed lives in bench/.
settings.register_profile("tactile", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("tactile")

# One BLAS thread, as the command line has (gateway/cli/_threads.py): the fits' matrices are
# small, and a thread pool per process spins on a busy 2-core machine (a calibration measured
# 25 s with the default pool under load, 5.3 s with one thread). Set before numpy loads (none
# of the imports above loads it); the environment may say otherwise.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

#: How long a thread or process that is shutting down may take to be gone (s).
GRACE_S = 5.0

TESTS = Path(__file__).resolve().parent

#: Tests outside tests/integration (whose conftest marks its own) that take over ~2 s, by
#: module or by ``module::function`` (every parameter of it), so that ``make test-fast``
#: (``pytest -m "not slow"``) leaves them out without edits to their files. Measured with
#: ``--durations`` on the 2-core machine, 2026-11-25.
SLOW: frozenset[str] = frozenset(
    {
        "docs/test_docs_run.py",  # runs the docs' commands as printed (4-42 s each)
        "fuzz/test_fuzz_modbus_wrong_answers.py",  # at least 3 s of wrong answers
        "fuzz/test_fuzz_register_decoding.py::test_fuzz_decode_sample_and_the_processor",
        "fuzz/test_fuzz_config_parser.py::test_fuzz_valid_document_with_random_edits",
        "unit/gateway/analysis/test_discrepancy.py",  # 13 of its 16 tests fit models for 2-15 s
        "unit/gateway/analysis/test_discrepancy_unexplained.py",
        "unit/gateway/analysis/test_fsr_emulator_acceptance.py",
        "unit/gateway/analysis/test_interval_coverage.py",
        "unit/gateway/analysis/test_calibration.py::test_calibrate_cli_json_and_file",
        "unit/gateway/analysis/test_calibration.py::test_round_trip_calibration_reads_another_record_within_a_tenth_of_a_newton",
        "unit/gateway/analysis/test_real_records.py::test_every_real_calibration_reports_model_and_line_on_the_same_held_out_rows",
        "unit/gateway/analysis/test_real_records.py::test_measured_numbers_on_the_real_files",
        "unit/gateway/config/test_calibration_conversions.py::test_calibrate_model_line_file_reads_through_the_processor",
    }
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the tests of SLOW slow (tests/integration/conftest.py marks that directory)."""
    slow = pytest.mark.slow
    for item in items:
        path = Path(str(item.path))
        if not path.is_relative_to(TESTS):
            continue
        module = path.relative_to(TESTS).as_posix()
        function = getattr(item, "originalname", item.name)
        if module in SLOW or f"{module}::{function}" in SLOW:
            item.add_marker(slow)


def _children() -> set[int]:
    """Live child processes of this process (zombies not yet reaped count as live)."""
    found: set[int] = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        try:
            found.update(int(pid) for pid in (task / "children").read_text().split())
        except OSError:
            continue
    return found


def _threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.is_alive()}


@pytest.fixture(autouse=True)
def no_leaked_threads_or_processes() -> Iterator[None]:
    threads_before, children_before = _threads(), _children()
    yield
    deadline = time.monotonic() + GRACE_S
    while True:
        threads = _threads() - threads_before
        children = _children() - children_before
        if not (threads or children) or time.monotonic() > deadline:
            break
        time.sleep(0.02)
    leaks = [f"thread {t.name!r} (daemon={t.daemon})" for t in threads]
    leaks += [f"child process {pid}: {_cmdline(pid)}" for pid in sorted(children)]
    if leaks:
        pytest.fail("the test leaked: " + "; ".join(leaks), pytrace=False)


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return "?"


@pytest_asyncio.fixture(autouse=True)
async def no_leaked_tasks(no_leaked_threads_or_processes: None) -> AsyncIterator[None]:
    """Runs inside the thread and process check, so that check comes last."""
    before = asyncio.all_tasks()
    yield
    current = asyncio.current_task()
    leaked = [t for t in asyncio.all_tasks() - before if t is not current and not t.done()]
    for task in leaked:
        task.cancel()
    # the loop's own executor threads (asyncio.to_thread) end with the loop, here rather than
    # at the runner's teardown, which comes after the thread check
    await asyncio.get_running_loop().shutdown_default_executor()
    if leaked:
        pytest.fail(
            "the test leaked asyncio tasks: " + ", ".join(repr(t.get_coro()) for t in leaked), pytrace=False
        )
