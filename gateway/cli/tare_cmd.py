"""``tactile-gateway tare``: measure the unloaded baseline of every channel and write it into
the configuration file (comments kept, written atomically, nothing written when refused)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import NoReturn

import click

from ..analysis.tare import TareError, compute_tare
from ..config import load_config
from ..config.editor import find_devices, set_device_array
from ..errors import ConfigError, DeviceError
from ..runtime.sampler import sample_device
from .common import config_option


def _fail(message: str, code: int = 2) -> NoReturn:
    click.echo(f"tare: {message}", err=True)
    raise SystemExit(code)


@click.command("tare")
@config_option
@click.option("--device", "device_name", default=None, help="The device to tare (default: the only one).")
@click.option(
    "--seconds", type=click.FloatRange(0.5, 600.0), default=3.0, show_default=True,
    help="How long to sample the array at rest.",
)  # fmt: skip
@click.option(
    "--max-force", "max_force_n", type=click.FloatRange(0.0, 1e3), default=0.5, show_default=True,
    help="Refuse when the model reads more than this (N) at a channel's baseline: the array is loaded.",
)  # fmt: skip
@click.option(
    "--max-noise", "max_noise_counts", type=click.FloatRange(0.0, 1e6), default=8.0, show_default=True,
    help="Refuse when a channel's noise (standard deviation, ADC counts) exceeds this.",
)  # fmt: skip
def tare(
    config_path: Path, device_name: str | None, seconds: float, max_force_n: float, max_noise_counts: float
) -> None:
    """Sample the unloaded array and write each channel's baseline into the config file.

    Lift everything off the array first. The samples must be still (no drift, little noise)
    and unloaded (the model reads at most --max-force at every baseline, and no channel
    conducts three times more than the median); otherwise nothing is written and the reason
    names the channels. A channel then reads 0 N, no contact, at its baseline.
    """
    try:
        config = load_config(config_path)
        found = find_devices(config, device_name)
    except ConfigError as exc:
        _fail(str(exc))
    if len(found) > 1:
        names = ", ".join(dev.name for _, _, _, dev in found)
        _fail(f"{config_path} has several devices ({names}); choose one with --device NAME")
    (_, _, bus, device) = found[0]
    click.echo(f"sampling device {device.name} on {bus.endpoint} for {seconds:g} s; keep the array unloaded")
    try:
        samples = asyncio.run(sample_device(bus, device, seconds))
    except DeviceError as exc:
        _fail(f"device {device.name}: {exc}; nothing was written", 1)
    try:
        result = compute_tare(
            device, [s for _, s in samples], max_force_n=max_force_n, max_noise_counts=max_noise_counts
        )
    except TareError as exc:
        _fail(f"device {device.name}: {exc}")
    other = "baseline_ohm" if result.key == "baseline_counts" else "baseline_counts"
    comment = f"tare: {result.n_polls} polls over {seconds:g} s"
    try:
        set_device_array(
            config_path, device.name, result.key, result.values, replaces=(other,), comment=comment
        )
    except ConfigError as exc:
        _fail(str(exc))
    before = [f for f in result.force_before_n if f == f]
    worst = max(before) if before else 0.0
    click.echo(
        f"{config_path}: device {device.name}: {result.key} written for {device.n_channels} channels "
        f"({result.n_polls} polls; without it the model read up to {worst:.3g} N on the empty array)"
    )
    for note in result.notes:
        click.echo(f"note: {note}")
