"""``make stress-test``: the integration tests, round after round, while every core is busy.

A test that passes on a quiet machine and fails under load has a race or a timing assumption;
this makes such a test fail here rather than in a user's first ``make test``. Each round runs
``pytest tests/integration`` with one CPU hog per core (a busy loop in its own process, at
normal priority) and reports pass or fail; the exit status is 1 if any round failed.

Usage: ``python -m bench.stress [--rounds 5] [--hogs N] [pytest arguments...]``
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import subprocess
import sys
import time


def _hog() -> None:
    x = 0
    while True:
        x = (x * 1103515245 + 12345) & 0x7FFFFFFF


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--hogs", type=int, default=os.cpu_count() or 2)
    parser.add_argument(
        "--log-dir", default="stress-logs", help="where a failed round's full pytest output is kept"
    )
    args, pytest_args = parser.parse_known_args(argv)
    results: list[tuple[int, int, float, str]] = []
    for round_no in range(1, args.rounds + 1):
        hogs = [multiprocessing.Process(target=_hog, daemon=True) for _ in range(args.hogs)]
        for hog in hogs:
            hog.start()
        t0 = time.monotonic()
        try:
            run = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "pytest",
                    "-q",
                    "-p",
                    "no:cacheprovider",
                    "tests/integration",
                    *pytest_args,
                ],
                capture_output=True,
                text=True,
            )
        finally:
            for hog in hogs:
                hog.terminate()
            for hog in hogs:
                hog.join(timeout=5)
        elapsed = time.monotonic() - t0
        summary = run.stdout.strip().splitlines()[-1] if run.stdout.strip() else "(no output)"
        failed = [line for line in run.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
        results.append((round_no, run.returncode, elapsed, summary))
        print(
            f"round {round_no}/{args.rounds} with {args.hogs} CPU hogs: {summary} ({elapsed:.0f} s)",
            flush=True,
        )
        for line in failed:
            print(f"  {line}", flush=True)
        if run.returncode != 0:
            os.makedirs(args.log_dir, exist_ok=True)
            log_path = os.path.join(args.log_dir, f"round-{round_no}.log")
            with open(log_path, "w", encoding="utf-8") as log:
                log.write(run.stdout + run.stderr)
            print(f"  full output: {log_path}", flush=True)
    bad = [r for r in results if r[1] != 0]
    print(f"stress test: {len(results) - len(bad)} of {len(results)} rounds passed under load")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
