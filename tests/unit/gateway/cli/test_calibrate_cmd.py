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
