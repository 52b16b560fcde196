"""``discrepancy --jobs N``: a step's candidate effects are fitted side by side on N processes,
and the report is the same, value for value, as one process's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from array_records import array_record
from click.testing import CliRunner

from gateway.cli import main

pytestmark = pytest.mark.slow  # two discrepancy runs, each a dozen fits


def test_discrepancy_on_two_jobs_reports_what_one_job_reports(tmp_path: Path) -> None:
    record = array_record(tmp_path / "one.csv", channels=1, seed=4)
    reports = []
    for jobs in ("1", "2"):
        result = CliRunner().invoke(main, ["discrepancy", str(record), "--jobs", jobs, "--json"])
        assert result.exit_code == 0, result.output
        reports.append(json.loads(result.stdout))
    assert reports[0] == reports[1]
    # candidates were tried (the parallel part ran): at least one step scored two or more
    assert any(len(step["candidates"]) >= 2 for step in reports[0]["steps"]), reports[0]["steps"]
