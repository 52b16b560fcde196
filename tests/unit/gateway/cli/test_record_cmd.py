"""``tactile-gateway record``: what it refuses, and an honest exit status."""

from __future__ import annotations

import socket
from pathlib import Path

from click.testing import CliRunner

from gateway.cli import main


def _config(tmp_path: Path) -> Path:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    path = tmp_path / "gw.toml"
    path.write_text(
        f'[[bus]]\nname = "b"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {port}\ntimeout_s = 0.2\n'
        "backoff_initial_s = 0.05\nbackoff_max_s = 0.1\n\n"
        '[[bus.device]]\nname = "d"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 2\n'
    )
    return path


def test_an_existing_file_that_is_not_a_record_is_not_overwritten_without_force(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    out.write_text("precious\n")
    result = CliRunner().invoke(
        main, ["record", "-c", str(_config(tmp_path)), "--duration", "0", "--out", str(out)]
    )
    assert result.exit_code == 2 and "is not a record" in result.output and "or --force" in result.output
    assert out.read_text() == "precious\n"


def test_a_record_with_every_device_down_exits_1(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    result = CliRunner().invoke(
        main, ["record", "-c", str(_config(tmp_path)), "--duration", "0.5", "--out", str(out), "--force"]
    )
    assert result.exit_code == 1, result.output
    assert "no sample recorded in 0.5 s: no device answered" in result.output


def test_record_says_which_channels_start_loaded(tmp_path: Path) -> None:
    """A channel whose reference is 10 N from the first row starts loaded; one at 0 N does not."""
    import numpy as np

    from gateway.analysis.records import format_record, write_record
    from gateway.cli.record_cmd import _loaded_starts

    t = np.arange(0.0, 20.0, 0.5)
    loaded = np.where(t < 10.0, 10.0, 0.0)
    rest = np.where(t < 10.0, 0.0, 5.0)
    r = np.column_stack([1e4 / np.maximum(loaded, 0.01), 1e4 / np.maximum(rest, 0.01)])
    path = tmp_path / "rec.csv"
    text = format_record({"time": "real"}, ["tip", "pad"], t, r, force_n=np.column_stack([loaded, rest]))
    write_record(path, text)
    lines = _loaded_starts(path)
    assert len(lines) == 1 and "channel tip" in lines[0] and "starts loaded at 10 N" in lines[0], lines
    assert _loaded_starts(tmp_path / "missing.csv") == []


def test_a_csv_record_named_mcap_is_refused(tmp_path: Path) -> None:
    """A .mcap name is read as MCAP by its magic: a CSV written there would not read back."""
    out = tmp_path / "run.mcap"
    result = CliRunner().invoke(
        main,
        ["record", "-c", str(_config(tmp_path)), "--duration", "0", "--out", str(out), "--format", "csv"],
    )
    assert result.exit_code == 2 and "--format csv" in result.output and ".mcap" in result.output
    assert not out.exists()
