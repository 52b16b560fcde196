"""``tactile-gateway calibrate``: fit a channel's parameters from a measurement record."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..analysis.calibration import calibrate, format_report, write_calibration
from ..analysis.records import read_record
from ..errors import RecordError
from ..model import ParameterError, SensorParams, UnknownEffectError, parse_effects
from .common import parse_assignments


@click.command("calibrate")
@click.argument("record_path", metavar="RECORD.csv", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--channel", "channel_names", multiple=True, help="channel to calibrate (default: all)")
@click.option("--effects", default="tunneling,contact,creep", show_default=True, help="model effects")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE", help="prior value of a parameter")
@click.option("--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), help="calibration TOML")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object and nothing else")
def calibrate_cmd(
    record_path: Path,
    channel_names: tuple[str, ...],
    effects: str,
    params: tuple[str, ...],
    out_path: Path | None,
    as_json: bool,
) -> None:
    """Fit R0, the contact coefficient and E0, E1, mu1 (linear in force) to RECORD.csv."""
    try:
        chosen = parse_effects(effects)
        prior = SensorParams().with_overrides(parse_assignments(params, "--param"))
        record = read_record(record_path, require_force=True)
        names = list(channel_names) or list(record.channels)
        channels = [record.channel(n) for n in names]
    except (RecordError, UnknownEffectError, ParameterError) as exc:
        raise click.UsageError(str(exc)) from None
    results = []
    for ch in channels:
        try:
            results.append(calibrate(ch, chosen, prior, record_name=str(record_path)))
        except ValueError as exc:
            raise click.ClickException(str(exc)) from None
    if out_path is not None:
        write_calibration(out_path, results)
    if as_json:
        payload: dict[str, object] = {"calibrations": [c.as_dict() for c in results]}
        if out_path is not None:
            payload["written"] = str(out_path)
        click.echo(json.dumps(payload))
        return
    for cal in results:
        click.echo(format_report(cal))
        click.echo("")
    if out_path is not None:
        click.echo(f"wrote {out_path}")
