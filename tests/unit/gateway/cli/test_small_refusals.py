"""Issue 24 §8 (small ones): ``--duration nan`` is refused by ``demo`` and ``subscribe``;
``paper --out`` naming a file is a usage error, not a traceback; ``record`` writes into a
temporary file renamed over its target at the end, so a killed recording leaves no file
that looks complete."""

from __future__ import annotations

import asyncio
import stat
from pathlib import Path

import pytest
from click.testing import CliRunner
from test_record_cmd import _config

from gateway.cli import main
from gateway.cli.record_cmd import record_live
from gateway.config import load_config


@pytest.mark.parametrize("value", ["nan", "inf"])
@pytest.mark.parametrize(
    "command", [["demo"], ["subscribe", "--broker", "127.0.0.1"]], ids=["demo", "subscribe"]
)
def test_a_duration_that_is_not_a_finite_number_is_refused(command: list[str], value: str) -> None:
    result = CliRunner().invoke(main, [*command, "--duration", value])
    assert result.exit_code == 2, result.output
    assert "--duration" in result.output and "expected a finite number" in result.output


def test_paper_out_naming_a_device_is_a_usage_error() -> None:
    result = CliRunner().invoke(main, ["paper", "--out", "/dev/null"])  # click passes a non-regular file
    assert result.exit_code == 2, result.output
    assert "--out: /dev/null exists and is not a directory" in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_record_writes_a_temporary_file_and_renames_it_at_the_end(tmp_path: Path) -> None:
    config = load_config(_config(tmp_path))
    out = tmp_path / "run.csv"
    seen: list[list[str]] = []

    def during() -> bool:  # what a SIGKILL now would leave behind
        seen.append(sorted(p.name for p in tmp_path.iterdir()))
        return True

    asyncio.run(record_live(config, out, 5.0, show_progress=False, until=during))
    assert seen and "run.csv" not in seen[0]
    assert any(name.startswith(".run.csv.") and name.endswith(".tmp") for name in seen[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gw.toml", "run.csv"]
    assert "time_s" in out.read_text()


def test_record_replaces_an_earlier_record_through_its_link_keeping_its_mode(tmp_path: Path) -> None:
    # the one atomic writer (gateway.atomic): a link is followed and stays, the mode is kept
    config = load_config(_config(tmp_path))
    real = tmp_path / "real.csv"
    real.write_text("time_s,resistance_ohm\n0,1000\n")
    real.chmod(0o600)
    link = tmp_path / "run.csv"
    link.symlink_to(real)
    asyncio.run(record_live(config, link, 5.0, show_progress=False, until=lambda: True))
    assert link.is_symlink() and link.resolve() == real
    assert stat.S_IMODE(real.stat().st_mode) == 0o600
    assert "tactile-gateway record" in real.read_text() and "1000" not in real.read_text()
