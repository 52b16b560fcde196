"""``tactile-gateway apply``: a calibration file applied to a recorded file by the runtime's tracker."""

from __future__ import annotations

import json
import os
from pathlib import Path

import click

from ..analysis.apply import (
    ApplyError,
    apply_calibration,
    apply_report,
    channel_errors,
    format_apply_report,
    write_applied,
)
from ..analysis.records import read_record
from ..errors import ConfigError, RecordError
from ..runtime.replay import ReplayError


def _mapping(pairs: tuple[str, ...]) -> dict[str, str]:
    """``--as RECORD_CH=CAL_CH`` pairs."""
    out: dict[str, str] = {}
    for pair in pairs:
        name, sep, target = (part.strip() for part in pair.partition("="))
        if not sep or not name or not target:
            raise click.BadParameter(f"{pair!r} is not RECORD_CH=CAL_CH", param_hint="--as")
        if name in out and out[name] != target:
            raise click.BadParameter(
                f"{name!r} is mapped twice ({out[name]!r}, {target!r})", param_hint="--as"
            )
        out[name] = target
    return out


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _check_out(out: Path, what: str, *inputs: Path) -> None:
    if out.is_dir():
        raise click.UsageError(f"{what}: {out} is a directory")
    if not out.parent.is_dir():
        raise click.UsageError(f"{what}: directory {out.parent} does not exist")
    for source in inputs:
        if _same_file(out, source):
            raise click.UsageError(f"{what}: {out} is an input of this command; refusing to replace it")


@click.command("apply")
@click.argument("calibration_path", metavar="CAL.toml", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("record_path", metavar="RECORD.csv", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--out",
    "out_path",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="record CSV to write: the record with force_tracked_n, force_static_n and status",
)
@click.option("--channel", "channel_names", multiple=True, help="record channel to read (default: all)")
@click.option(
    "--as",
    "pairs",
    multiple=True,
    metavar="RECORD_CH=CAL_CH",
    help="read record channel RECORD_CH with the calibration's table CAL_CH (default: the same name)",
)
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False, path_type=Path), help="PNG to write")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object and nothing else")
def apply_cmd(
    calibration_path: Path,
    record_path: Path,
    out_path: Path,
    channel_names: tuple[str, ...],
    pairs: tuple[str, ...],
    plot_path: Path | None,
    as_json: bool,
) -> None:
    """Read RECORD.csv with calibration CAL.toml as the gateway reads a device live.

    Each record channel is read with the calibration table of its name (or the one --as maps it
    to) by the runtime's own per-channel tracker, the device clock taken from the record's
    time_s. With a reference force (force_n) it prints the RMS error of the tracked and of the
    static force, and their errors at the start and end of each hold."""
    rename = _mapping(pairs)
    _check_out(out_path, "--out", calibration_path, record_path)
    if plot_path is not None:
        _check_out(plot_path, "--plot", calibration_path, record_path, out_path)
    try:
        record = read_record(record_path)
        applied = apply_calibration(calibration_path, record, channel_names, rename)
    except ApplyError as exc:
        raise click.UsageError(str(exc).replace("(RECORD_CH=CAL_CH)", "with --as RECORD_CH=CAL_CH")) from None
    except (RecordError, ConfigError) as exc:
        raise click.UsageError(str(exc)) from None
    except ReplayError as exc:
        raise click.UsageError(f"{record_path}: {exc}") from None
    meta = {
        "source": "tactile-gateway apply",
        "record": str(record_path),
        "calibration": str(calibration_path),
        "channels": ", ".join(f"{c.name}={c.calibration_channel}" for c in applied.channels),
    }
    if "source" in record.metadata:
        meta["record_source"] = record.metadata["source"]
    try:
        write_applied(out_path, applied, meta)
    except OSError as exc:
        raise click.ClickException(f"cannot write {out_path}: {exc.strerror or exc}") from None
    errors = [channel_errors(c) for c in applied.channels]
    if plot_path is not None:
        from ..analysis.apply_plots import plot_applied

        try:
            plot_applied(applied, errors, plot_path)
        except OSError as exc:
            raise click.ClickException(f"cannot write {plot_path}: {exc.strerror or exc}") from None
    if as_json:
        payload = apply_report(applied, errors)
        payload["written"] = str(out_path)
        if plot_path is not None:
            payload["plot"] = str(plot_path)
        click.echo(json.dumps(payload))
        return
    click.echo(format_apply_report(applied, errors), nl=False)
    click.echo(f"wrote {out_path}")
    if plot_path is not None:
        click.echo(f"wrote {plot_path}")
