"""Issue 24, item 12, the CLI's small ones: the demo's terminal redraw, ``poll-once``'s
placeholders, what ``check-config`` shows of MQTT and calibration, the example's front end,
and one rule for ``record --out`` and ``calibrate --out`` on an existing file."""

from __future__ import annotations

import asyncio
import io
import re
import socket
import stat
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.cli import main, run_cmd
from gateway.cli.run_cmd import snapshot_table
from gateway.config import ChannelConfig, DeviceConfig, RegisterMap, load_config
from gateway.config.layout import GridLayout
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot

REPO = Path(__file__).resolve().parents[4]
EXAMPLE = REPO / "examples" / "gateway.toml"


# ----------------------------------------------------------------------------- the terminal view
def _screen(text: str, rows: int = 30, cols: int = 120) -> list[str]:
    """What a terminal shows after ``text``: the few controls the demo writes (cursor home,
    erase in line and in display, colours, cursor visibility); a newline starts the next
    line at its first column (the tty's output processing)."""
    grid = [[" "] * cols for _ in range(rows)]
    row = col = 0
    for token in re.findall(r"\x1b\[[?0-9;]*[A-Za-z]|\n|.", text, flags=re.DOTALL):
        if token == "\n":
            row, col = min(row + 1, rows - 1), 0
        elif token.startswith("\x1b["):
            code, final = token[2:-1], token[-1]
            if final == "H":
                row = col = 0
            elif final == "K":
                grid[row][col:] = [" "] * (cols - col)
            elif final == "J":
                if code == "2":
                    grid = [[" "] * cols for _ in range(rows)]
                else:
                    grid[row][col:] = [" "] * (cols - col)
                    for r in range(row + 1, rows):
                        grid[r] = [" "] * cols
        elif col < cols:
            grid[row][col] = token
            col += 1
    return ["".join(line).rstrip() for line in grid]


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_shorter_line_of_the_demo_view_overwrites_a_longer_one(monkeypatch: pytest.MonkeyPatch) -> None:
    frames = iter(
        ["title\n\nin contact    9 channels, 156.25 mm^2\ndevice        up"]
        + ["title\n\nin contact    1 channels, 6.25 mm^2\ndevice        up"] * 1000
    )
    monkeypatch.setattr(run_cmd, "render_view", lambda *args, **kwargs: next(frames))
    out = _Tty()
    assert asyncio.run(run_cmd.run_demo(0, "127.0.0.1", 1.0, out)) == 0
    shown = _screen(out.getvalue())
    assert "in contact    1 channels, 6.25 mm^2" in shown, shown[:6]
    assert not any("mm^22" in line or "mm^2 " in line for line in shown), shown[:6]


# ----------------------------------------------------------------------------- poll-once
def test_poll_once_placeholders_line_up_with_their_columns() -> None:
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", 2.5 * k, 0.0, True, PAPER_EFFECTS, SensorParams(), None)
        for k in range(2)
    )
    dev = DeviceConfig(
        "arr", 1, "float32", 2, RegisterMap(), Divider(), channels, False, GridLayout(2, 2, 2.5, 2.5), None
    )
    proc = DeviceProcessor(dev, "bench", 0.1)
    snap, _ = proc.stale(proc.initial_state(), 0.0, "timeout")
    lines = snapshot_table(GatewaySnapshot.build({"arr": snap}, {}, 1)).splitlines()
    header, rows = lines[1], lines[2:4]
    for column in ("resistance_ohm", "force_n", "static_n"):
        end = header.index(column) + len(column)
        for row in rows:
            assert row[end - 1] == "-" and row[end : end + 1] in ("", " "), (column, row, header)
    assert all(len(row) == len(header) for row in rows), (header, rows)


# ----------------------------------------------------------------------------- check-config
def _private(path: Path, text: str) -> Path:
    path.write_text(text)
    path.chmod(stat.S_IRUSR | stat.S_IWUSR)
    return path


def test_check_config_shows_the_mqtt_target_and_the_calibration_file(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text("[channel.ch00]\nr0_ohm = 180000.0\n")
    _private(tmp_path / "mqtt.pw", "s3cret-password\n")
    config = tmp_path / "gw.toml"
    config.write_text(
        '[mqtt]\nhost = "broker.lan"\nport = 1884\ntopic_prefix = "plant/line3/tactile"\n'
        'gateway = "gw1"\nusername = "alice"\npassword_file = "mqtt.pw"\n\n'
        '[[bus]]\nname = "b"\nkind = "tcp"\nhost = "127.0.0.1"\n\n'
        '[[bus.device]]\nname = "left"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 4\n'
        'calibration = "cal.toml"\n\n'
        '[[bus.device]]\nname = "right"\ndevice_id = 2\nprofile = "tactile-sim"\nchannels = 4\n'
    )
    result = CliRunner().invoke(main, ["check-config", "-c", str(config)])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "mqtt: broker.lan:1884" in out, out
    assert "plant/line3/tactile/gw1/" in out, out
    assert "s3cret" not in out and "mqtt.pw" not in out and "alice" not in out, out
    left, right = out.split("device left", 1)[1].split("device right", 1)
    assert f"calibration: {tmp_path / 'cal.toml'}" in left, out
    assert "calibration: none" in right, out


def test_check_config_says_when_mqtt_is_off(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["check-config", "-c", str(EXAMPLE)])
    assert result.exit_code == 0, result.output
    assert "mqtt: off" in result.output


# ----------------------------------------------------------------------------- the example
def test_the_example_uses_the_current_front_end_spelling() -> None:
    text = EXAMPLE.read_text()
    assert "[bus.device.divider]" not in text
    assert "[bus.device.front_end]" in text
    dev = load_config(EXAMPLE).buses[0].devices[0]
    assert dev.front_end == Divider(5.0, 10000.0, 16)


# ----------------------------------------------------------------------------- record --out
def _unreachable_config(tmp_path: Path) -> Path:
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


def _record(tmp_path: Path, out: Path, *extra: str) -> tuple[int, str]:
    args = ["record", "-c", str(_unreachable_config(tmp_path)), "--duration", "0.3", "--out", str(out)]
    result = CliRunner().invoke(main, [*args, *extra])
    return result.exit_code, result.output


OLD_RECORD = "# source: tactile-gateway record\ntime_s,channel,resistance_ohm\n0,d/ch00,1000\n"


def test_record_replaces_a_record_as_calibrate_replaces_a_calibration(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    # an earlier record: the next `record --out` to it is not refused (calibrate --out replaces
    # an earlier calibration file the same way); here no device answers, so nothing replaces it
    out.write_text(OLD_RECORD)
    code, output = _record(tmp_path, out)
    assert code == 1 and "no sample recorded" in output, output
    assert "refusing" not in output and "is left as it was" in output and "wrote" not in output
    assert out.read_text() == OLD_RECORD  # a record without a sample never replaces one


def test_record_refuses_another_kind_of_file_without_force(tmp_path: Path) -> None:
    for text in ("precious notes\n", '[[bus]]\nname = "b"\n', "a,b,c\n1,2,3\n"):
        out = tmp_path / "notes.csv"
        out.write_text(text)
        code, output = _record(tmp_path, out)
        assert code == 2 and "is not a record" in output and "--force" in output, output
        assert out.read_text() == text
    code, output = _record(tmp_path, out, "--force")
    assert code == 1, output  # accepted; no device answered, so nothing was recorded


def test_calibrate_out_follows_the_same_rule(tmp_path: Path) -> None:
    notes = tmp_path / "notes.toml"
    notes.write_text("precious = true\n")
    rec = tmp_path / "r.csv"
    rec.write_text(
        "time_s,channel,resistance_ohm,force_n\n"
        + "".join(f"{t},0,{1e5 / (1 + f)},{f}\n" for t, f in enumerate(np.linspace(0.1, 5, 40)))
    )
    result = CliRunner().invoke(main, ["calibrate", str(rec), "--model", "line", "--out", str(notes)])
    assert result.exit_code == 2, result.output
    assert "is not a calibration file" in result.output and "--force" in result.output
    assert notes.read_text() == "precious = true\n"
