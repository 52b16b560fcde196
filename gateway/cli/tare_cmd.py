"""``tactile-gateway tare``: measure the unloaded baseline of every channel and write it into
the configuration file (comments kept, written atomically, nothing written when refused)."""

from __future__ import annotations

import asyncio
import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import click
import numpy as np

from ..analysis.records import names_text, read_record
from ..analysis.tare import (
    MIN_POLLS,
    ChannelSeries,
    TareError,
    TareResult,
    compute_tare,
    compute_tare_series,
    samples_to_series,
)
from ..analysis.tare_window import WindowTare, compute_window_tare
from ..config import DeviceConfig, Encoding, load_config
from ..config.editor import find_devices, read_config_text, set_device_array
from ..config.readout import NO_BASELINE
from ..config.rois import select_channels
from ..errors import ConfigError, DeviceError, RecordError
from ..runtime.sampler import sample_device
from .action_cmd import one_device, run_device_action
from .common import config_option


def _fail(message: str, code: int = 2) -> NoReturn:
    click.echo(f"tare: {message}", err=True)
    raise SystemExit(code)


def parse_channels(spec: str, device: DeviceConfig) -> list[int]:
    """``ch00,ch05,0-11`` -> channel indices (ascending): ``config.rois.select_channels`` (names,
    indices, ranges ``A-B``, region and group names); ``ValueError`` naming a bad entry."""
    names = [ch.name for ch in device.channels]
    return select_channels(spec.split(","), names, device.regions, device.name, "--channels", spec)


def record_series(
    path: Path,
    device: DeviceConfig,
    channels: Sequence[int] | None,
    start_s: float | None,
    end_s: float | None,
) -> tuple[list[ChannelSeries], str]:
    """The resistances (ohm) of the record's channels of ``device`` between ``start_s`` and
    ``end_s`` (s, inclusive; default the whole record), and the window in words. A record
    channel is a device channel by name (or ``DEVICE/NAME``); ``ValueError`` for a channel of
    another device, a chosen channel the record lacks, or an empty window."""
    record = read_record(path)
    names = {ch.name: ch.index for ch in device.channels}
    found: dict[int, str] = {}
    foreign: list[str] = []
    for label in record.channels:
        name = label.removeprefix(f"{device.name}/")
        if name in names:
            found[names[name]] = label
        else:
            foreign.append(label)
    if foreign:
        shown = ", ".join(foreign[:6]) + (f" and {len(foreign) - 6} more" if len(foreign) > 6 else "")
        raise ValueError(
            f"{path}: channels {shown} are not channels of device {device.name} "
            f"({device.channels[0].name}..{device.channels[-1].name}); a record of another device?"
        )
    wanted = sorted(found) if channels is None else list(channels)
    missing = [device.channels[i].name for i in wanted if i not in found]
    if missing:
        raise ValueError(
            f"{path}: no rows of {', '.join(missing[:6])} (the record has {names_text(record.channels)})"
        )
    times = np.concatenate([record.channels[found[i]].time_s for i in wanted])
    first, last = float(times.min()), float(times.max())
    lo = first if start_s is None else start_s
    hi = last if end_s is None else end_s
    window = f"{lo:g}-{hi:g} s of {path.name}"
    if hi <= lo:
        raise ValueError(f"the window {window} is empty: --end-s must be after --start-s")
    series: list[ChannelSeries] = []
    for i in wanted:
        rows = record.channels[found[i]]
        inside = (rows.time_s >= lo) & (rows.time_s <= hi)
        if not inside.any():
            raise ValueError(
                f"the window {window} holds no rows of {device.channels[i].name} "
                f"(the record spans {first:g}-{last:g} s)"
            )
        series.append(ChannelSeries(i, rows.resistance_ohm[inside], rows.time_s[inside]))
    return series, window


def merged_baselines(
    config_path: Path, bus_index: int, device_index: int, device: DeviceConfig, result: TareResult
) -> tuple[str, list[float | None], list[str]]:
    """The whole array to write for a tare of ``result.channels``: (key, one value per channel,
    notes). The other channels keep what the file gives them: the device table's array as
    written, or a calibration file's ``baseline_ohm``; a channel with no baseline at all gets
    ``"none"`` (``config.readout.NO_BASELINE``): still no baseline, its idle reading guarded."""
    if len(result.channels) == device.n_channels:
        return result.key, list(result.values), []
    raw: Any = tomllib.loads(read_config_text(config_path).removeprefix("\ufeff"))
    table = raw["bus"][bus_index]["device"][device_index]
    existing = next((k for k in ("baseline_counts", "baseline_ohm") if k in table), None)
    key = result.key if existing == result.key else "baseline_ohm"
    tared = dict(
        zip(result.channels, result.values if key == result.key else result.resistance_ohm, strict=True)
    )
    values: list[float | None] = []
    zeroed: list[str] = []
    for ch in device.channels:
        if ch.index in tared:
            values.append(tared[ch.index])
        elif existing == key:
            kept = table[key][ch.index]
            values.append(None if kept == NO_BASELINE else float(kept))
        elif ch.baseline_ohm is not None:
            values.append(ch.baseline_ohm)
        elif ch.conversion is not None:
            raise ValueError(
                f"{ch.name} has no baseline and reads force by its calibration's conversion, whose "
                "unloaded resistance a baseline cannot spell; tare it too (--channels)"
            )
        else:
            values.append(None)
            zeroed.append(ch.name)
    notes = [f"the other {device.n_channels - len(tared)} channels keep their baselines"]
    if zeroed:
        shown = ", ".join(zeroed[:6]) + (f" and {len(zeroed) - 6} more" if len(zeroed) > 6 else "")
        notes.append(
            f'{shown} had no baseline: written as "{NO_BASELINE}", nothing taken off, an idle reading still '
            "flagged no_zero"
        )
    return key, values, notes


def window_lines(device: DeviceConfig, moving: WindowTare, key: str) -> list[str]:
    """One line per zeroed channel (its baseline as written under ``key``, and when it was
    taken), then one per channel not zeroed (why, with numbers)."""
    result = moving.tare
    lines: list[str] = []
    for k, i in enumerate(result.channels):
        a, b = moving.spans_s[k]
        when = f"{a:.4g}-{b:.4g} s" if moving.timed else f"polls {a:.0f}-{b:.0f}"
        if key == "baseline_counts":
            value = f"{result.values[k]:g} counts ({result.resistance_ohm[k]:.4g} ohm)"
        elif result.key == "baseline_counts":
            value = f"{result.resistance_ohm[k]:.5g} ohm ({result.values[k]:g} counts)"
        else:
            value = f"{result.values[k]:.5g} ohm"
        lines.append(f"  {device.channels[i].name}: {value} at {when} ({moving.n_polls[k]} polls)")
    lines.extend(f"not zeroed: {device.channels[i].name} ({why})" for i, why in moving.skipped)
    return lines


@click.command("tare")
@config_option
@click.option("--device", "device_name", default=None, help="The device to tare (default: the only one).")
@click.option(
    "--seconds", type=click.FloatRange(0.5, 600.0), default=None,
    help="How long to sample the array (s; default 3, and 30 with --moving-load).",
)  # fmt: skip
@click.option(
    "--moving-load", is_flag=True,
    help="The array is never wholly unloaded but the load moves: zero each channel from its own "
    "latest still stretch at its least loaded level within the window (the sampled seconds, or "
    "the record's --start-s..--end-s); a channel loaded throughout is named and not zeroed.",
)  # fmt: skip
@click.option(
    "--max-force", "max_force_n", type=click.FloatRange(0.0, 1e3), default=0.5, show_default=True,
    help="Refuse when the model reads more than this (N) at a channel's baseline: the array is loaded.",
)  # fmt: skip
@click.option(
    "--max-noise", "max_noise_counts", type=click.FloatRange(0.0, 1e6), default=8.0, show_default=True,
    help="Refuse when a channel's noise (standard deviation, ADC counts) exceeds this.",
)  # fmt: skip
@click.option(
    "--channels", "channels_spec", default=None, metavar="LIST",
    help="Tare only these channels (names, indices 0..N-1 or ranges A-B, and the regions and "
    "groups of a device made of regions, e.g. palm or index; comma separated); the others keep "
    "the baselines the file gives them.",
)  # fmt: skip
@click.option(
    "--from-record", "record_path", type=click.Path(path_type=Path), default=None,
    help="Take the baselines from a record (docs/record-format.md) of an unloaded moment "
    "instead of sampling the device (written as baseline_ohm).",
)  # fmt: skip
@click.option(
    "--start-s", type=click.FloatRange(min=0.0), default=None,
    help="With --from-record: the window's start (s, the record's time_s; default its start).",
)  # fmt: skip
@click.option(
    "--end-s", type=click.FloatRange(min=0.0), default=None,
    help="With --from-record: the window's end (s, the record's time_s; default its end).",
)  # fmt: skip
@click.option(
    "--device-zero", is_flag=True,
    help="Zero the device itself: run its `zero` action ([bus.device.actions]) instead of sampling.",
)  # fmt: skip
def tare(
    config_path: Path,
    device_name: str | None,
    seconds: float | None,
    moving_load: bool,
    max_force_n: float,
    max_noise_counts: float,
    channels_spec: str | None,
    record_path: Path | None,
    start_s: float | None,
    end_s: float | None,
    device_zero: bool,
) -> None:
    """Sample the unloaded array and write each channel's baseline into the config file.

    Lift everything off the array first. The samples must be still (no drift, little noise)
    and unloaded (the model reads at most --max-force at every baseline, and no channel
    conducts three times more than the median); otherwise nothing is written and the reason
    names the first cause (loaded, moving, noisy), the channels and their numbers. A channel
    then reads 0 N, no contact, at its baseline.

    With --channels only those channels are sampled into baselines (and checked); the others
    keep theirs. With --from-record the baselines come from a record's resistances over
    --start-s..--end-s (default: the whole record) and the device is not polled.

    With --moving-load (a load that moves, never off the whole array at once) each channel's
    baseline comes from its own unloaded moments within the window: its latest still stretch
    (at least 10 polls) at its least loaded level, which leaves out the creep back after a
    lift; the output says when each was taken, and a channel loaded throughout is named,
    with its numbers, and not zeroed (docs/bring-your-own-array.md).

    With --device-zero the device zeroes itself (its configured `zero` action) and nothing is
    written to the configuration file.
    """
    if device_zero and moving_load:
        _fail(
            "--moving-load takes baselines from samples, --device-zero has the device zero itself: choose one"
        )
    if seconds is None:
        seconds = 30.0 if moving_load else 3.0
    if device_zero:
        bus, device = one_device("tare", config_path, device_name)
        run_device_action("tare", bus, device, "zero")
        return
    try:
        config = load_config(config_path)
        found = find_devices(config, device_name)
    except ConfigError as exc:
        _fail(str(exc))
    if len(found) > 1:
        names = ", ".join(dev.name for _, _, _, dev in found)
        _fail(f"{config_path} has several devices ({names}); choose one with --device NAME")
    (b, d, bus, device) = found[0]
    if record_path is None and (start_s is not None or end_s is not None):
        _fail("--start-s and --end-s choose a window of a record: give --from-record RECORD.csv")
    try:
        chosen = None if channels_spec is None else parse_channels(channels_spec, device)
    except ValueError as exc:
        _fail(str(exc))
    limits = {"max_force_n": max_force_n, "max_noise_counts": max_noise_counts}
    moving: WindowTare | None = None
    if record_path is not None:
        try:
            series, window = record_series(record_path, device, chosen, start_s, end_s)
            if moving_load:
                moving = compute_window_tare(device, series, counts=False, window=window, **limits)
                result = moving.tare
            else:
                result = compute_tare_series(device, series, counts=False, window=window, **limits)
        except (RecordError, ValueError) as exc:
            _fail(f"{exc}; nothing was written")
        except TareError as exc:
            _fail(f"device {device.name}: {exc}")
        comment = f"tare{' --moving-load' if moving_load else ''}: {window}"
    else:
        wanted = (
            f"the load may move: each channel must rest, still and unloaded, for {MIN_POLLS} polls of it"
            if moving_load
            else "keep the array unloaded"
        )
        click.echo(f"sampling device {device.name} on {bus.endpoint} for {seconds:g} s; {wanted}")
        try:
            samples = asyncio.run(sample_device(bus, device, seconds))
        except DeviceError as exc:
            _fail(f"device {device.name}: {exc}; nothing was written", 1)
        window = f"the {seconds:g} s sampled"
        # times from the first poll, so that a stretch reads as seconds into the window
        times = [t - samples[0][0] for t, _ in samples] if samples else []
        try:
            if moving_load:
                series = samples_to_series(device, [s for _, s in samples], channels=chosen, times_s=times)
                moving = compute_window_tare(
                    device, series, counts=device.encoding is Encoding.ADC, window=window, **limits
                )
                result = moving.tare
            else:
                result = compute_tare(
                    device, [s for _, s in samples], channels=chosen, times_s=times, window=window, **limits
                )
        except TareError as exc:
            _fail(f"device {device.name}: {exc}")
        comment = (
            f"tare --moving-load: {window}"
            if moving_load
            else f"tare: {result.n_polls} polls over {seconds:g} s"
        )
    try:
        key, values, notes = merged_baselines(config_path, b, d, device, result)
    except ValueError as exc:
        _fail(f"device {device.name}: {exc}; nothing was written")
    other = "baseline_ohm" if key == "baseline_counts" else "baseline_counts"
    try:
        set_device_array(config_path, device.name, key, values, replaces=(other,), comment=comment)
    except ConfigError as exc:
        _fail(str(exc))
    before = [f for f in result.force_before_n if not math.isnan(f)]
    worst = max(before) if before else 0.0
    how = "" if moving is None else f", each from its own still, unloaded stretch of {window}"
    polls = f"{result.n_polls} polls" if moving is None else f"at least {result.n_polls} polls each"
    click.echo(
        f"{config_path}: device {device.name}: {key} written for {len(result.channels)} of "
        f"{device.n_channels} channels{how} ({polls}; without it the model read up to "
        f"{worst:.3g} N there at rest)"
    )
    if moving is not None:
        for line in window_lines(device, moving, key):
            click.echo(line)
    for note in [*notes, *result.notes]:
        click.echo(f"note: {note}")
