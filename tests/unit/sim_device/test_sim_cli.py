"""tactile-sim command line: listing, clean errors for bad flags and bad files, a short run."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from sim_device import builtin_scenarios
from sim_device.cli import main


def test_scenarios_lists_every_builtin() -> None:
    result = CliRunner().invoke(main, ["scenarios"])
    assert result.exit_code == 0
    lines = result.output.splitlines()
    assert len(lines) == len(builtin_scenarios())
    for name, line in zip(builtin_scenarios(), lines, strict=True):
        assert line.split()[0] == name


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["run", "--tcp", "nohost"], 2, "HOST:PORT"),
        (["run", "--tcp", "127.0.0.1:99999"], 2, "65535"),
        (["run", "--channels", "0"], 2, "--channels"),
        (["run", "--tcp", "127.0.0.1:0", "--rtu", "/dev/x"], 2, "only one"),
        (["run", "--tls", "127.0.0.1:0"], 2, "--cert"),
        (["run", "--device-ids", "1,1"], 2, "distinct"),
        (["run", "--scenario", "nosuch"], 1, "unknown scenario 'nosuch'"),
        (["run", "--world-effects", "crep2"], 1, "did you mean 'creep2'"),
        (["run", "--speed", "-1"], 1, "speed"),
        (["run", "--rtu", "/dev/does-not-exist", "--stop-after", "0"], 1, "does not exist"),
        (["run", "--bogus"], 2, "No such option"),
    ],
)
def test_bad_flags_give_a_message_and_no_traceback(args: list[str], code: int, message: str) -> None:
    result = CliRunner().invoke(main, args)
    assert result.exit_code == code, result.output
    assert message in result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_bad_scenario_file_names_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / "p.toml"
    path.write_text("[[load]]\nsteps = [{ ramp_n = 3, rate_n_per_s = -1 }]\n")
    result = CliRunner().invoke(main, ["run", "--scenario", str(path)])
    assert result.exit_code == 1
    assert f"{path}: load[0].steps[0].rate_n_per_s: must be > 0" in result.output
    assert "Traceback" not in result.output


def test_short_run_with_recording(tmp_path: Path) -> None:
    record = tmp_path / "r.csv"
    args = ["run", "--tcp", "127.0.0.1:0", "--scenario", "holds", "--speed", "100", "--channels", "4",
            "--record", str(record), "--stop-after", "0.6"]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "serving 1 array(s) of 4 channels" in result.output and "stopped" in result.output
    lines = record.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    assert lines[header] == "time_s,channel,resistance_ohm,force_n,temperature_c"
    assert len(lines) - header - 1 >= 4 * 5


def test_version_is_the_distribution_version_like_the_gateway() -> None:
    from importlib.metadata import version

    from gateway.cli import main as gateway_main

    result = CliRunner().invoke(main, ["--version"])
    assert result.exit_code == 0, result.output
    assert result.output == f"tactile-sim, version {version('tactile-gateway')}\n"
    gw = CliRunner().invoke(gateway_main, ["--version"])
    assert gw.output.split(", ")[1] == result.output.split(", ")[1]
