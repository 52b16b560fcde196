"""``tactile-gateway calibrate --out``: what it will not overwrite, checked before any fit."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from gateway.cli import main


def test_out_never_replaces_a_gateway_configuration(tmp_path: Path) -> None:
    config = tmp_path / "gateway.toml"
    text = '# my plant\n[[bus]]\nname = "b"\nkind = "tcp"\nhost = "h"\n'
    config.write_text(text)
    result = CliRunner().invoke(main, ["calibrate", str(tmp_path / "r.csv"), "--out", str(config)])
    assert result.exit_code == 2
    assert "exists and is not a calibration file" in result.output and "--force" in result.output
    assert config.read_text() == text


def test_out_into_a_missing_folder_is_one_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        main, ["calibrate", str(tmp_path / "r.csv"), "--out", str(tmp_path / "nodir" / "x.toml")]
    )
    assert result.exit_code == 2 and "directory" in result.output and "does not exist" in result.output
    assert "Traceback" not in result.output


THICK = Path(__file__).resolve().parents[3] / "data" / "real" / "tams_thick.csv"


def test_progress_names_each_stage_on_stderr_and_json_stays_clean(tmp_path: Path) -> None:
    out = tmp_path / "cal.toml"
    shown = CliRunner().invoke(
        main, ["calibrate", str(THICK), "--as", "pad", "--out", str(out), "--progress"]
    )
    assert shown.exit_code == 0, shown.output
    lines = [line for line in shown.stderr.splitlines() if line.startswith("[")]
    stages = [line.split(": ", 1)[1] for line in lines]
    assert stages[0].startswith("physical model, log-R objective (")
    assert stages[-1] == "done" and any(s.startswith("curves x drift forms") for s in stages)
    assert all("channel '0' (1/1)" in line for line in lines)
    seconds = [float(line[1 : line.index(" s]")]) for line in lines]
    assert seconds == sorted(seconds)
    # not a terminal (the runner's stderr), and --json: no progress, one JSON object on stdout
    quiet = CliRunner().invoke(main, ["calibrate", str(THICK), "--as", "pad", "--json"])
    assert quiet.exit_code == 0 and not any(line.startswith("[") for line in quiet.stderr.splitlines())
    assert quiet.stdout.lstrip().startswith("{")
