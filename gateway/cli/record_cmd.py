"""``tactile-gateway record`` and ``tactile-gateway paper``: live records, and the paper replayed."""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import logging
import os
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from ..analysis.record_common import RECORD_FORMATS, record_format_for
from ..analysis.recorder import LiveRecorder, RecorderStats, record_path_ok
from ..atomic import AtomicFile
from ..config import GatewayConfig, RegisterMap, load_config
from ..errors import ConfigError
from ..runtime.poller import Poller, SnapshotHolder
from .common import config_option
from .simulated import PacedClock, gateway_params


def _progress(elapsed_s: float, duration_s: float, stats: RecorderStats, final: bool = False) -> None:
    width = 30
    done = min(1.0, elapsed_s / duration_s) if duration_s > 0 else 1.0
    bar = "#" * int(done * width) + "." * (width - int(done * width))
    line = (
        f"[{bar}] {elapsed_s:7.1f}/{duration_s:g} s  samples {stats.rows}  "
        f"read errors {stats.read_errors}  skipped {stats.skipped_rows}"
    )
    if sys.stderr.isatty():
        click.echo("\r" + line + ("\n" if final else ""), err=True, nl=False)
    elif final:
        click.echo(line, err=True)


async def record_live(
    config: GatewayConfig,
    out_path: Path,
    duration_s: float,
    channels: list[str] | None = None,
    device: str | None = None,
    metadata: dict[str, str] | None = None,
    show_progress: bool = True,
    until: Callable[[], bool] | None = None,
    keep_existing_if_empty: bool = False,
    cancel: asyncio.Event | None = None,
    record_format: str = "csv",
) -> RecorderStats:
    """Poll with ``config`` for ``duration_s`` seconds, or until ``until()`` holds (checked
    every 50 ms), and write a record to ``out_path``: into a temporary file beside it, renamed
    over it at the end (also after SIGINT/SIGTERM), so that a killed recording never leaves a
    file that looks like a complete record. With ``keep_existing_if_empty`` (``out_path``
    exists) a recording without a sample leaves ``out_path`` as it was. With ``cancel`` the
    caller handles SIGINT/SIGTERM: once ``cancel`` is set the recording ends and writes nothing
    (``out_path`` is left as it was). ``record_format``: ``csv`` or ``mcap``
    (``docs/record-format.md``)."""
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # its errors reach us as read errors
    stop = asyncio.Event() if cancel is None else cancel
    loop = asyncio.get_running_loop()
    handled = []
    for sig in (signal.SIGINT, signal.SIGTERM) if cancel is None else ():
        with contextlib.suppress(RuntimeError, ValueError, NotImplementedError):
            loop.add_signal_handler(sig, stop.set)
            handled.append(sig)
    try:
        with AtomicFile(out_path) as out:
            meta = {
                "source": "tactile-gateway record",
                "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                **(metadata or {}),
            }
            sink = out if record_format == "mcap" else out.text
            recorder = LiveRecorder(sink, config, channels, meta, device=device, record_format=record_format)
            holder = SnapshotHolder()
            holder.subscribe(recorder)
            t0 = time.monotonic()
            async with Poller(config, holder):
                check_s = 0.5 if until is None else 0.05
                while not stop.is_set() and (elapsed := time.monotonic() - t0) < duration_s:
                    if until is not None and until():
                        break
                    if show_progress:
                        _progress(elapsed, duration_s, recorder.stats)
                    with contextlib.suppress(TimeoutError):
                        wait_s = min(check_s, max(0.01, duration_s - elapsed))
                        await asyncio.wait_for(stop.wait(), timeout=wait_s)
            if show_progress:
                _progress(min(time.monotonic() - t0, duration_s), duration_s, recorder.stats, final=True)
            empty = keep_existing_if_empty and recorder.stats.rows == 0
            if not empty and not (cancel is not None and cancel.is_set()):
                recorder.close()  # the last rows (an MCAP record's summary and index)
                out.commit()  # otherwise leaving the block removes the temporary file
        return recorder.stats
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)


@click.command("record")
@config_option
@click.option("--duration", "duration_s", required=True, type=click.FloatRange(min=0.0), help="seconds")
@click.option(
    "--out", "out_path", required=True, type=click.Path(path_type=Path), help="record to write (CSV or .mcap)"
)
@click.option(
    "--format",
    "record_format",
    type=click.Choice(RECORD_FORMATS),
    default=None,
    help="csv or mcap (default: mcap when --out ends in .mcap, else csv)",
)
@click.option("--channels", default=None, help="comma-separated channel names (default: all)")
@click.option(
    "--force", "overwrite", is_flag=True, help="replace --out even if it is not a record (e.g. another CSV)"
)
def record(
    config_path: Path,
    duration_s: float,
    out_path: Path,
    record_format: str | None,
    channels: str | None,
    overwrite: bool,
) -> None:
    """Write a measurement record from live polls (reference force and temperature where available).

    ``--format mcap`` writes MCAP (one ROS 2 message per poll of a device) that Foxglove and
    ROS 2 tooling open, and that ``apply``, ``view``, ``calibrate`` and ``discrepancy`` read as
    they read CSV (``docs/record-format.md``).

    ``--out`` replaces an earlier record (as ``calibrate --out`` replaces an earlier
    calibration file), but never another kind of file unless ``--force``; a recording that
    got no sample leaves an earlier record as it was.

    Exit status 1 when no sample was recorded (every device down), 2 for bad arguments."""
    try:
        config = load_config(config_path)
        if record_format == "csv" and record_format_for(out_path) == "mcap":
            raise ValueError(
                f"--format csv into {out_path}: a record named .mcap is read as MCAP; name it .csv, "
                "or write MCAP (--format mcap)"
            )
        record_path_ok(out_path, force=overwrite, replace_record=True)
    except (ConfigError, ValueError) as exc:
        raise click.UsageError(str(exc)) from None
    names = [c.strip() for c in channels.split(",") if c.strip()] if channels else None
    known = {c.name for bus in config.buses for d in bus.devices for c in d.channels}
    known |= {f"{d.name}/{c.name}" for bus in config.buses for d in bus.devices for c in d.channels}
    for name in names or []:
        if name not in known:
            raise click.UsageError(f"no channel {name!r} in {config_path}")
    existed = out_path.exists()
    stats = asyncio.run(
        record_live(
            config,
            out_path,
            duration_s,
            names,
            metadata={"config": str(config_path)},
            keep_existing_if_empty=existed,
            record_format=record_format_for(out_path, record_format),
        )
    )
    kept = stats.rows == 0 and existed
    if not kept:
        click.echo(
            f"wrote {stats.rows} samples from {stats.polls} polls to {out_path} "
            f"({stats.read_errors} read errors)"
        )
        for line in _loaded_starts(out_path):
            click.echo(line)
    if stats.rows == 0:
        click.echo(
            f"record: no sample recorded in {duration_s:g} s: no device answered ({stats.read_errors} read "
            f"errors){f'; {out_path} is left as it was' if kept else ''}; check the devices and the "
            "configuration",
            err=True,
        )
        raise SystemExit(1)


def _loaded_starts(path: Path) -> list[str]:
    """A line for each channel of the record at ``path`` that starts loaded
    (``analysis.load_history.start_load``): a calibration or discrepancy of it starts from an
    unknown load history there."""
    from ..analysis.load_history import start_load
    from ..analysis.records import RecordError, read_record

    try:
        record = read_record(path)
    except (RecordError, OSError):
        return []
    out = []
    for name, ch in record.channels.items():
        if ch.n_samples == 0:
            continue
        start = start_load(ch.time_s, ch.resistance_ohm, ch.force_n)
        if start.loaded:
            out.append(f"note: channel {name}: {start.sentence()}")
    return out


def _played(array: Any, end_s: float) -> Callable[[], bool]:
    """True once the simulated ``array`` has sampled up to ``end_s`` of device time (reads its
    last sample: does not call, and so advance, its clock)."""
    return lambda: bool(array.last_sample_time_s >= end_s)


#: Device seconds a paper replay's simulated device may run between two reads.
MAX_UNSEEN_DEVICE_S = 4.0


async def _paper_records(out_dir: Path, speed: float, cancel: asyncio.Event) -> tuple[Path, Path, object]:
    from sim_device import ArrayConfig, SimArray, serve_tcp

    from ..config import bus_config_for, device_config_for, gateway_config_for
    from ..model import Divider

    creep_cfg = ArrayConfig(channels=1, columns=1, seed=7, scenario="creep-test", speed=speed)
    stair_cfg = creep_cfg.with_changes(scenario="staircase", speed=speed / 10.0)
    # paced clocks: a poll at least every MAX_UNSEEN_DEVICE_S of device time, however busy the
    # machine (the records' sampling, and so the fits' standard errors, do not depend on load)
    creep = SimArray(creep_cfg, device_id=1, clock=PacedClock(MAX_UNSEEN_DEVICE_S / creep_cfg.speed))
    stair = SimArray(stair_cfg, device_id=2, clock=PacedClock(MAX_UNSEEN_DEVICE_S / stair_cfg.speed))
    creep_params, stair_params = gateway_params(creep.channel_params), gateway_params(stair.channel_params)
    bench = RegisterMap(force_reference_address=1000, temperature_address=1600)
    divider = Divider(creep_cfg.supply_v, creep_cfg.reference_ohm, creep_cfg.adc_bits)
    creep_path, stair_path = out_dir / "creep_tests.csv", out_dir / "staircase.csv"
    async with serve_tcp([creep, stair], host="127.0.0.1", port=0) as sim:
        # One poller per record, each reading its own device only (a device that another
        # poller also read would advance between the recorder's polls). Each record ends when
        # its device has played its scenario; the wall-time limit is a backstop (a paced device
        # runs slower than its speed only when polls come late).
        records = []
        for name, device_id, params, array, path in (
            ("creep", 1, creep_params, creep, creep_path),
            ("staircase", 2, stair_params, stair, stair_path),
        ):
            device = device_config_for(name, device_id, params, 1, 2.5, front_end=divider, registers=bench)
            bus = bus_config_for(
                "sim", "tcp", [device], host="127.0.0.1", port=sim.port, poll_interval_s=0.02
            )
            end_s = array.scenario.duration_s or 600.0
            records.append(
                record_live(
                    gateway_config_for([bus]),
                    path,
                    20.0 * end_s / array.config.speed,
                    device=name,
                    show_progress=False,
                    until=_played(array, end_s),
                    cancel=cancel,
                )
            )
        await asyncio.gather(*records)
    return creep_path, stair_path, creep_params[0]


class _Stopped(Exception):
    """SIGINT or SIGTERM arrived during ``paper``."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


class _PaperSignals:
    """SIGINT/SIGTERM for ``paper``: while its recordings run, a signal sets their ``cancel``
    event (they end and write nothing); at any other moment it raises :class:`_Stopped`."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._live: tuple[asyncio.AbstractEventLoop, asyncio.Event] | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> _PaperSignals:
        self._old = {sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum: int, frame: object) -> None:
        if self.signum is None:
            self.signum = signum
        if self._live is not None:
            loop, cancel = self._live
            loop.call_soon_threadsafe(cancel.set)
        else:
            raise _Stopped(self.signum)

    async def records(self, out_dir: Path, speed: float) -> tuple[Path, Path, object]:
        """:func:`_paper_records`, ended early by a signal (then :class:`_Stopped`)."""
        cancel = asyncio.Event()
        self._live = (asyncio.get_running_loop(), cancel)
        try:
            if self.signum is None:
                result = await _paper_records(out_dir, speed, cancel)
        finally:
            self._live = None
        if self.signum is not None:
            raise _Stopped(self.signum)
        return result


@click.command("paper")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--speed",
    type=click.FloatRange(min=10.0, max=2000.0),
    default=200.0,
    show_default=True,
    help="simulated clock speed of the creep tests (the staircase runs 10x slower)",
)
def paper(out_dir: Path, speed: float) -> None:
    """Replay the paper's experiments on the simulated array, end to end through Modbus."""
    from ..analysis.paper import analyze, write_outputs
    from ..analysis.records import read_record
    from ..model import SensorParams

    if out_dir.exists() and not out_dir.is_dir():
        raise click.UsageError(
            f"--out: {out_dir} exists and is not a directory (paper writes records and plots into one)"
        )
    created = not out_dir.exists()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(dir=out_dir, prefix=".paper-", suffix=".tmp"))
    except OSError as exc:
        raise click.UsageError(
            f"--out: cannot create the directory {out_dir}: {exc.strerror or exc}"
        ) from None
    click.echo(
        f"recording the creep tests and a staircase through Modbus (about {5400 / speed:.0f} s; longer on "
        "a busy machine: the simulated clock waits for late polls) ..."
    )
    # Everything is written into ``work`` and moved into ``out_dir`` only once complete, with
    # the signals blocked, so that a stopped replay leaves no file behind.
    written: list[Path] = []
    try:
        with _PaperSignals() as signals:
            creep_path, stair_path, true = asyncio.run(signals.records(work, speed))
            assert isinstance(true, SensorParams)
            creep = read_record(creep_path, require_force=True).channel()
            stair = read_record(stair_path, require_force=True).channel()
            result = analyze(creep, stair, true)
            outputs = write_outputs(
                result, work, f"{creep_path.name}, {stair_path.name} (recorded through Modbus)"
            )
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
            try:
                for path in (creep_path, stair_path, *outputs):
                    os.replace(path, out_dir / path.name)
                    written.append(out_dir / path.name)
            finally:
                shutil.rmtree(work, ignore_errors=True)
                signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
    except _Stopped as stopped:
        shutil.rmtree(work, ignore_errors=True)
        if created:
            with contextlib.suppress(OSError):
                out_dir.rmdir()
        name = signal.Signals(stopped.signum).name
        click.echo(f"paper: stopped by {name}; nothing written", err=True)
        sys.exit(128 + stopped.signum)
    for path in written[2:]:
        click.echo(str(path))
