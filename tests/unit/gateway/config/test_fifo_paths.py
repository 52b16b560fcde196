"""A named pipe (FIFO) where a file is expected is refused unopened, never waited on (issue 33 §6).

A FIFO with no writer blocks ``open()`` until a writer comes: a configuration naming one as
its calibration file stopped the poll loop at SIGHUP (the reload opened it before checking
what it is), and ``apply`` hung on one. Each reader below is run in a thread; should it block,
the test opens the FIFO for writing itself (which lets the reader's ``open`` return), so a
regression fails here instead of hanging the suite.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from gateway.analysis.records import RecordError, read_record
from gateway.analysis.update import UpdateError, load_channels
from gateway.cli import main
from gateway.config import load_config
from gateway.config.calibration_file import check_calibration_file
from gateway.config.tables import read_text_file
from gateway.errors import ConfigError

#: How long a reader may take to refuse a FIFO before it counts as blocked (generous: a busy
#: machine; a refusal takes microseconds).
BLOCKED_AFTER_S = 10.0

CONFIG = """\
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "arr"
device_id = 1
channels = 4
calibration = "cal.toml"
[bus.device.registers]
adc_address = 100
[bus.device.front_end]
kind = "low_side"
supply_v = 3.3
reference_ohm = 10000.0
adc_bits = 12
"""


def refused_unblocked(fifo: Path, read: Callable[[], object]) -> BaseException:
    """Run ``read`` (which must refuse ``fifo``); the exception it raised. Fails the test if
    it blocked (after unblocking it) or returned."""
    outcome: list[BaseException | None] = []

    def target() -> None:
        try:
            read()
        except BaseException as exc:  # handed to the test
            outcome.append(exc)
        else:
            outcome.append(None)

    thread = threading.Thread(target=target, name="fifo-reader")
    thread.start()
    thread.join(BLOCKED_AFTER_S)
    blocked = thread.is_alive()
    if blocked:  # a writer end lets the reader's open() return (and read EOF)
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
        thread.join(BLOCKED_AFTER_S)
    assert not blocked, f"reading {fifo} blocked on the FIFO"
    assert outcome and outcome[0] is not None, "a FIFO was read as a file"
    return outcome[0]


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "cal.toml"
    os.mkfifo(path)
    return path


def test_a_fifo_as_a_text_file_is_refused_unopened(fifo: Path) -> None:
    exc = refused_unblocked(fifo, lambda: read_text_file(fifo, "calibration file"))
    assert isinstance(exc, ConfigError)
    assert str(exc) == f"{fifo}: not a regular file; a calibration file is a file"


def test_a_configuration_naming_a_fifo_as_its_calibration_is_refused(fifo: Path) -> None:
    config = fifo.parent / "gateway.toml"
    config.write_text(CONFIG, encoding="utf-8")
    exc = refused_unblocked(fifo, lambda: load_config(config))
    assert isinstance(exc, ConfigError)
    assert "not a regular file" in str(exc) and str(fifo) in str(exc) and len(str(exc)) < 300


def test_a_fifo_as_the_configuration_is_refused(tmp_path: Path) -> None:
    config = tmp_path / "gateway.toml"
    os.mkfifo(config)
    exc = refused_unblocked(config, lambda: load_config(config))
    assert isinstance(exc, ConfigError) and "not a regular file" in str(exc)


def test_calibration_readers_refuse_a_fifo(fifo: Path) -> None:
    exc = refused_unblocked(fifo, lambda: check_calibration_file(fifo))
    assert isinstance(exc, ConfigError) and "not a regular file" in str(exc)
    exc = refused_unblocked(fifo, lambda: load_channels(fifo))
    assert isinstance(exc, UpdateError) and "not a regular file" in str(exc)


def test_a_fifo_as_a_record_is_refused(tmp_path: Path) -> None:
    record = tmp_path / "run.csv"
    os.mkfifo(record)
    exc = refused_unblocked(record, lambda: read_record(record))
    assert isinstance(exc, RecordError) and "not a regular file" in str(exc)


@pytest.mark.parametrize("which", ["calibration", "record"])
def test_apply_refuses_a_fifo_and_exits(tmp_path: Path, which: str) -> None:
    cal, record = tmp_path / "cal.toml", tmp_path / "run.csv"
    cal.write_text('[channel.c1]\nkind = "lookup"\n', encoding="utf-8")
    record.write_text("time_s,channel,resistance_ohm\n0,c1,1e5\n1,c1,2e5\n", encoding="utf-8")
    fifo = cal if which == "calibration" else record
    fifo.unlink()
    os.mkfifo(fifo)
    out = tmp_path / "out.csv"
    args = ["apply", str(cal), str(record), "--out", str(out)]
    results: list[Result] = []

    def run() -> None:
        results.append(CliRunner().invoke(main, args))
        raise _Done

    exc = refused_unblocked(fifo, run)
    assert isinstance(exc, _Done) and results
    result = results[0]
    assert result.exit_code == 2, result.output
    assert "not a regular file" in result.output and str(fifo) in result.output
    assert not out.exists()


class _Done(Exception):
    """Raised after a command returned, so that ``refused_unblocked`` sees it ended."""
