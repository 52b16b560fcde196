"""The shared leak guard (``tests/conftest.py``) fails a test that leaks, and only then."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

CONFTEST = (Path(__file__).resolve().parents[1] / "conftest.py").read_text(encoding="utf-8")

LEAKY = """
import asyncio, subprocess, sys, threading

def test_thread_left_running():
    stop = threading.Event()
    threading.Thread(target=stop.wait, args=(30,), name="forgotten", daemon=True).start()

def test_child_left_running():
    subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3)"])

async def test_task_left_pending():
    asyncio.get_running_loop().create_task(asyncio.sleep(30))

def test_clean_thread():
    t = threading.Thread(target=lambda: None)
    t.start()
    t.join()

async def test_clean_to_thread():
    await asyncio.to_thread(lambda: None)
"""


def test_leaks_fail_and_clean_tests_pass(pytester: pytest.Pytester) -> None:
    pytester.makeconftest(CONFTEST.replace("GRACE_S = 5.0", "GRACE_S = 0.2"))
    pytester.makepyfile(test_leaky=LEAKY)
    pytester.makeini("[pytest]\nasyncio_mode = auto\nasyncio_default_fixture_loop_scope = function\n")
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=5, errors=3)
    result.stdout.fnmatch_lines(
        [
            "*ERROR at teardown of test_thread_left_running*",
            "the test leaked: thread 'forgotten' (daemon=True)",
            "*ERROR at teardown of test_child_left_running*",
            "the test leaked: child process *: *python -c import time; time.sleep(3)",
            "*ERROR at teardown of test_task_left_pending*",
            "the test leaked asyncio tasks: <coroutine object sleep at *>",
        ]
    )
