"""``tactile-gateway view RECORD``: a recorded file played back on the live page.

The record (``docs/record-format.md``, read by ``analysis.records.read_record``) is replayed
through the runtime's processor (``runtime.replay``, as ``apply`` does: each channel at its own
samples), one device sample per recorded time, each channel showing its last reading
(``runtime.replay.held_snapshots``); the snapshots of the device samples the page gets
(``playback.thin``) are handed to the web layer's ``PlaybackPage``, which serves the live page
in playback mode. Where the channels sit and how a resistance reads as a
force come from, in this order:

1. ``--config CONFIG``: the device of that configuration (``--device NAME``, or its only one);
2. the configuration the record names (``# config: PATH``, which ``record`` writes), if that
   file exists (as written, or beside the record);
3. otherwise a fallback, said on stderr: the record's channels in record order on a
   row-major grid of ``# columns: N`` columns (metadata; default the square root of the
   channel count, rounded up) at ``# pitch_mm: P`` (default 2.5 mm), read with the default
   sensor parameters (the paper's Linqstat, ``docs/parameters.md``).

A record channel is the device's channel of the same name, or ``DEVICE/NAME`` (a record of
several devices). A configured channel the record does not have reads no value (``error``,
drawn ``ERR``). Bad input (no such file, not a record, an empty record, channels that are not
the device's) is one line on stderr and exit status 2.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import math
import os
import signal
import sys
from dataclasses import replace
from pathlib import Path

import click
import numpy as np
from prometheus_client import CollectorRegistry

from ..analysis.records import ChannelRecord, Record, RecordWriter, names_text, read_record
from ..config import ChannelConfig, DeviceConfig, Encoding, RegisterMap, load_config
from ..config.layout import GridLayout
from ..errors import ConfigError, RecordError
from ..metrics.server import MetricsServer
from ..model import PAPER_EFFECTS, Divider, SensorParams
from ..runtime.processor import DeviceProcessor
from ..runtime.replay import ChannelSeries, ReplayError, held_snapshots
from ..runtime.snapshot import DeviceSnapshot
from ..web.playback import Playback, PlaybackPage, playback_frames, thin

EXIT_BAD_INPUT = 2
#: The fallback layout's pitch when the record does not give one (mm).
DEFAULT_PITCH_MM = 2.5
#: The page's default fixed colour scale (N), as the live gateway's.
SCALE_MAX_N = 5.0


class ViewError(Exception):
    """Input ``view`` cannot show (the message is the one line printed)."""


def _named_config(record: Record, record_path: Path) -> Path | None:
    """The configuration file a record names (``# config: PATH``), if it exists."""
    named = record.metadata.get("config")
    if not named:
        return None
    for candidate in (Path(named), record_path.parent / named):
        if candidate.is_file():
            return candidate
    return None


def _pick_device(config_path: Path, device: str | None) -> DeviceConfig:
    config = load_config(config_path)
    devices = [d for bus in config.buses for d in bus.devices]
    if device is not None:
        for d in devices:
            if d.name == device:
                return d
        raise ViewError(
            f"{config_path}: no device {device!r} (devices: {', '.join(d.name for d in devices)})"
        )
    if len(devices) != 1:
        raise ViewError(
            f"{config_path} has {len(devices)} devices ({', '.join(d.name for d in devices)}); "
            "choose one with --device NAME"
        )
    return devices[0]


def _metadata_number(record: Record, key: str) -> float | None:
    text = record.metadata.get(key)
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ViewError(f"{record.path}: metadata {key!r}: {text!r} is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise ViewError(f"{record.path}: metadata {key!r}: {text!r} must be a positive number")
    return value


def fallback_device(record: Record) -> DeviceConfig:
    """The record's channels on a row-major grid (``# columns``, ``# pitch_mm`` metadata or the
    defaults), read with the default sensor parameters; channels keep the record's names."""
    names = list(record.channels)
    columns_value = _metadata_number(record, "columns")
    columns = int(columns_value) if columns_value is not None else math.ceil(math.sqrt(len(names)))
    columns = max(1, min(columns, len(names)))
    pitch_mm = _metadata_number(record, "pitch_mm") or DEFAULT_PITCH_MM
    n = len(names)
    channels = tuple(
        ChannelConfig(k, name, (k % columns) * pitch_mm, (k // columns) * pitch_mm, True,
                      PAPER_EFFECTS, SensorParams(), None, None)
        for k, name in enumerate(names)
    )  # fmt: skip
    return DeviceConfig("record", 1, Encoding.FLOAT32, n, RegisterMap(), Divider(), channels, False,
                        GridLayout(n, columns, pitch_mm, pitch_mm), None)  # fmt: skip


def _match(record: Record, device: DeviceConfig) -> list[str | None]:
    """For each enabled channel of ``device``, the record channel it reads (None: none)."""
    enabled = [c for c in device.channels if c.enabled]
    chosen: list[str | None] = []
    for c in enabled:
        for label in (c.name, f"{device.name}/{c.name}"):
            if label in record.channels:
                chosen.append(label)
                break
        else:
            chosen.append(None)
    used = {name for name in chosen if name is not None}
    mine = [n for n in record.channels if "/" not in n or n.startswith(f"{device.name}/")]
    extra = [n for n in mine if n not in used]
    if not used or extra:
        shown = names_text(extra or list(record.channels))
        raise ViewError(
            f"{record.path}: record channel(s) {shown} are not enabled channels of device "
            f"{device.name!r} ({', '.join(c.name for c in enabled)}); give the right --config / --device"
        )
    return chosen


def record_snapshots(record: Record, device: DeviceConfig) -> tuple[list[DeviceSnapshot], bool, int]:
    """``record`` replayed through ``device``'s processor: the snapshots of the device samples
    the page gets (``playback.thin``: every one up to ``MAX_FRAMES``; in time order, each
    channel showing its last reading, ``runtime.replay.held_snapshots``), whether the record
    has a reference force for the channels it reads, and the number of device samples."""
    chosen = _match(record, device)
    empty = np.zeros(0, dtype=np.float64)
    read = [record.channels[n] for n in chosen if n is not None]
    has_reference = all(c.force_n is not None for c in read)
    has_temperature = all(c.temperature_c is not None for c in read)
    series = []
    for name in chosen:
        if name is None:
            series.append(ChannelSeries(empty, empty, empty if has_reference else None,
                                        empty if has_temperature else None))  # fmt: skip
            continue
        c = record.channels[name]
        series.append(ChannelSeries(c.time_s, c.resistance_ohm, c.force_n if has_reference else None,
                                    c.temperature_c if has_temperature else None))  # fmt: skip
    processor = DeviceProcessor(device, bus="record", poll_interval_s=_interval_s(read))
    try:
        snapshots, n_samples = held_snapshots(processor, series, thin)
    except ReplayError as exc:
        raise ViewError(f"{record.path}: {exc}") from None
    return snapshots, has_reference, n_samples


def _interval_s(channels: list[ChannelRecord]) -> float:
    """The record's median sample step (s), as the frames' poll interval (0.1 s if none)."""
    steps = [np.diff(c.time_s) for c in channels]
    joined = np.concatenate(steps) if steps else np.zeros(0)
    joined = joined[joined > 0]
    return float(np.median(joined)) if joined.size else 0.1


def load_playback(
    record_path: Path, config_path: Path | None, device: str | None, note: list[str] | None = None
) -> Playback:
    """Read ``record_path`` and replay it for the page (``ViewError``/``RecordError``/
    ``ConfigError`` for input it cannot show). ``note`` gets what the fallback says."""
    record = read_record(record_path)
    how = ""
    if config_path is None:
        named = _named_config(record, record_path)
        if named is not None:
            config_path = named
            how = f"the record's configuration {named}"
    if config_path is not None:
        dev = _pick_device(config_path, device)
        how = how or f"{config_path}"
    else:
        dev = fallback_device(record)
        how = "no configuration: a fallback grid with the default sensor parameters"
        if note is not None:
            note.append(
                f"view: {record_path} names no configuration and none was given (--config): channels "
                f"on a grid of {dev.layout.columns} columns at {dev.layout.pitch_x_mm:g} mm, forces from "
                "the default sensor parameters"
            )
    snapshots, has_reference, n_samples = record_snapshots(record, dev)
    if not snapshots:
        raise ViewError(f"{record_path}: no sample of device {dev.name!r} to show")
    try:
        playback = playback_frames(
            snapshots, has_reference=has_reference, scale_max_n=SCALE_MAX_N, config=dev,
            source=str(record_path), samples_total=n_samples,
        )  # fmt: skip
    except ValueError as exc:
        raise ViewError(f"{record_path}: {exc}") from None
    playback.info["layout_from"] = how
    return replace(playback, export_csv=lambda a, b: record_span_csv(record, a, b, config_path))


def record_span_csv(record: Record, from_s: float, to_s: float, config_path: Path | None = None) -> str:
    """The rows of ``record`` with times from ``from_s`` to ``to_s`` (s) as a record (CSV text,
    by the one writer, ``RecordWriter``), in time order, the record's columns kept: the page's
    export in playback. ``time_s`` stays the record's."""
    channels = list(record.channels.values())
    has_force = bool(channels) and all(c.force_n is not None for c in channels)
    has_temp = bool(channels) and all(c.temperature_c is not None for c in channels)
    meta = {k: v for k, v in record.metadata.items() if k != "config"}
    meta["source"] = f"tactile-gateway view export of {record.path}, {from_s:g} to {to_s:g} s"
    if config_path is not None:
        meta["config"] = os.path.abspath(config_path)
    out = io.StringIO()
    writer = RecordWriter(out, meta, has_force=has_force, has_temperature=has_temp)
    rows = []
    for k, c in enumerate(channels):
        for i in np.flatnonzero((c.time_s >= from_s) & (c.time_s <= to_s)).tolist():
            force = float(c.force_n[i]) if has_force and c.force_n is not None else None
            temp = float(c.temperature_c[i]) if has_temp and c.temperature_c is not None else None
            rows.append((float(c.time_s[i]), k, i, c.name, float(c.resistance_ohm[i]), force, temp))
    for t, _, _, name, r, force, temp in sorted(rows, key=lambda row: row[:3]):
        writer.row(t, name, r, force, temp)
    writer.close()
    return out.getvalue()


async def _serve_until_stopped(server: MetricsServer, what: str) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    with server:
        click.echo(f"tactile-gateway view - page on {server.page_url} - {what} - Ctrl-C to stop")
        sys.stdout.flush()
        await stop.wait()


@click.command("view")
@click.argument("record_path", metavar="RECORD", type=click.Path(path_type=Path))
@click.option(
    "-c",
    "--config",
    "config_path",
    default=None,
    type=click.Path(path_type=Path, dir_okay=False),
    help="the gateway configuration with the recorded device (positions, conversion)",
)
@click.option("--device", default=None, help="the device of the configuration the record is of")
@click.option("--host", default="127.0.0.1", show_default=True, help="address to serve the page on")
@click.option(
    "--port", type=click.IntRange(0, 65535), default=0, show_default=True, help="port (0: any free port)"
)
def view(record_path: Path, config_path: Path | None, device: str | None, host: str, port: int) -> None:
    """Play RECORD back on the live page: a time slider, play/pause and 1x-10x speed.

    Prints the page's address and serves until Ctrl-C (or SIGTERM). Positions and the
    resistance-to-force conversion come from --config, else from the configuration the
    record names (# config:), else a grid with the default sensor parameters (said on stderr).
    Exit status 2 for input it cannot show."""
    notes: list[str] = []
    try:
        playback = load_playback(record_path, config_path, device, notes)
    except (ViewError, RecordError, ConfigError) as exc:
        click.echo(f"tactile-gateway: {exc}", err=True)
        sys.exit(EXIT_BAD_INPUT)
    for line in notes:
        click.echo(line, err=True)
    page = PlaybackPage(playback)
    try:
        server = MetricsServer(CollectorRegistry(), host, port, None, page.install)
    except OSError as exc:
        click.echo(f"tactile-gateway: cannot serve on {host}:{port}: {exc.strerror or exc}", err=True)
        sys.exit(EXIT_BAD_INPUT)
    p = playback
    what = (
        f"{p.layout['name']}, {len(p.layout['channels'])} channels, {len(p.frames)} frames over "
        f"{p.end_s - p.start_s:.3g} s"
    )
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve_until_stopped(server, what))


if __name__ == "__main__":  # python -m gateway.cli.view_cmd RECORD ... (as tactile-gateway view)
    view()
