"""``tactile-gateway calibrate``: fit a channel's parameters from a measurement record."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import click

from ..analysis.calibration import (
    OBJECTIVE_OPTIONS,
    Calibration,
    CalibrationModel,
    OffsetMode,
    calibrate,
    format_report,
    write_calibration,
)
from ..analysis.channel_work import FitSettings
from ..analysis.records import DEFAULT_CHANNEL, read_record
from ..config.calibration_file import check_calibration_file
from ..config.install import Installed, check_install_target, install_calibration
from ..errors import ConfigError, RecordError
from ..model import ParameterError, SensorParams, UnknownEffectError, parse_effects
from .calibrate_batch import batch_records, check_out_dir, run_batch
from .calibrate_pool import open_pool, submit_channels, wants_channel_pool
from .calibrate_progress import tracker_for
from .common import parse_assignments


@click.command("calibrate")
@click.argument("record_paths", metavar="RECORD.csv", nargs=-1, type=click.Path(path_type=Path))
@click.option("--channel", "channel_names", multiple=True, help="channel to calibrate (default: all)")
@click.option("--effects", default="tunneling,contact,creep", show_default=True, help="model effects")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE", help="prior value of a parameter")
@click.option(
    "--out",
    "out_path",
    type=click.Path(path_type=Path),
    help="calibration TOML; with several records (a folder, a glob, or more than one RECORD.csv): the "
    "folder for one <record stem>.toml each and summary.csv, summary.json",
)
@click.option(
    "--model",
    type=click.Choice([m.value for m in CalibrationModel]),
    default="physics",
    show_default=True,
    help="the channel's model to write: the physical model, the conductance line, a monotone lookup, "
    "curve (the best static curve with drift correction), or auto (whichever reads held-out force best)",
)
@click.option(
    "--objective",
    type=click.Choice(tuple(OBJECTIVE_OPTIONS)),
    default="auto",
    show_default=True,
    help="what the physical model's fit minimises: log-r (log-resistance residuals weighted by the "
    "measurement model), force (the same residuals divided by d ln R / dF: force errors, started from "
    "the log-r fit), or auto (both; keeps the one that reads held-out force better)",
)
@click.option(
    "--force-offset",
    "force_offset",
    type=click.Choice([o.value for o in OffsetMode]),
    default="auto",
    show_default=True,
    help="reference-force zero offset (the model is driven by F_ref + offset): fit it, leave it out, or "
    "auto (fit it and keep it only if it lowers the held-out force RMS); held-out errors of a fit with an "
    "offset are against F_ref + offset, and the force range written is the record's + offset",
)
@click.option(
    "--as",
    "as_name",
    default=None,
    metavar="NAME",
    help="device channel name to write (needed for a record without a channel column: its channel is '0')",
)
@click.option(
    "--plots", "plot_dir", type=click.Path(file_okay=False, path_type=Path), help="write PNGs to DIR"
)
@click.option(
    "--update",
    "update_path",
    type=click.Path(dir_okay=False, path_type=Path),
    metavar="CAL.toml",
    help="re-fit only the sensitivity of CAL's channels (curve, line, lookup: gain and offset; physical "
    "model: gain) from RECORD.csv or from --known loads, keeping each shape and its dynamics; with "
    "--first-s, the rest of RECORD.csv is the transfer test; writes CAL (or --out)",
)
@click.option(
    "--known",
    "known",
    multiple=True,
    metavar="FORCE_N=RESISTANCE_OHM",
    help="with --update: a known load read at rest (1 to 3; one fits the gain, two or more gain and offset)",
)
@click.option(
    "--first-s",
    "first_s",
    type=click.FloatRange(min=0.0, min_open=True),
    help="with --update: use only the record's first S seconds",
)
@click.option(
    "--install",
    "install_path",
    type=click.Path(dir_okay=False, path_type=Path),
    metavar="CONFIG.toml",
    help='name --out in a device of this gateway configuration (calibration = "...", relative to it; '
    "comments kept); without RECORD.csv: install --out as it is",
)
@click.option(
    "--device", "device_name", metavar="NAME", help="with --install: the device (if there are several)"
)
@click.option(
    "--replace-overrides",
    is_flag=True,
    help="with --install: drop the configuration's keys that contradict the calibration (a channel's or "
    "the device's parameter or effects); without it they are listed and nothing is installed",
)
@click.option(
    "--jobs",
    type=click.IntRange(min=1),
    default=None,
    metavar="N",
    help="processes a calibration may use (default: every core); the result is the same with any",
)
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    default=None,
    help="calibrate on the Dask cluster whose scheduler is at ADDRESS (tcp://host:8786): one task per "
    "channel, the records read here and shipped with their tasks; the result is the same as here",
)
@click.option(
    "--progress/--no-progress",
    default=None,
    help="progress on stderr: several channels or records: a bar on a terminal, else (or with --json) a "
    "line per channel done, unless --no-progress; one channel: its stages, by default on a terminal only",
)
@click.option("--json", "as_json", is_flag=True, help="print one JSON object and nothing else")
@click.option("--force", "overwrite", is_flag=True, help="replace --out even if it is not a calibration file")
def calibrate_cmd(
    record_paths: tuple[Path, ...],
    channel_names: tuple[str, ...],
    effects: str,
    params: tuple[str, ...],
    out_path: Path | None,
    model: str,
    objective: str,
    force_offset: str,
    as_name: str | None,
    plot_dir: Path | None,
    update_path: Path | None,
    known: tuple[str, ...],
    first_s: float | None,
    install_path: Path | None,
    device_name: str | None,
    replace_overrides: bool,
    jobs: int | None,
    scheduler: str | None,
    progress: bool | None,
    as_json: bool,
    overwrite: bool,
) -> None:
    """Fit R0, the contact coefficient and E0, E1, mu1 (linear in force) to RECORD.csv.

    ``--out`` replaces an earlier calibration file, but never another kind of file (a gateway
    configuration, say) unless ``--force``.

    ``--update CAL.toml`` re-fits the sensitivity of a stored calibration (any kind) from a short
    RECORD.csv (the first minutes of a new run) or from ``--known`` loads.

    ``--install CONFIG.toml [--device NAME]`` names the calibration in the device's configuration,
    so that the gateway reads it; keys of the configuration that contradict it are listed and
    nothing is installed, unless ``--replace-overrides`` drops them.

    Several records (a folder of them, a glob, or more than one RECORD.csv) need ``--out DIR``:
    each record's calibration is written as ``DIR/<record stem>.toml``, with ``DIR/summary.csv``
    and ``DIR/summary.json`` (one line per channel; a record that failed is one line with its
    error, and the others go on). Exit status of such a batch: 0 when every record was
    calibrated, 1 when any failed, 2 for a usage error (nothing calibrated)."""
    records = batch_records(record_paths)
    if records is not None:
        _batch(
            records,
            out_path,
            channel_names,
            effects,
            params,
            model,
            objective,
            force_offset,
            as_name,
            jobs,
            scheduler,
            progress,
            as_json,
            plot_dir,
            update_path,
            install_path,
            known,
            first_s,
        )
        return
    record_path = record_paths[0] if record_paths else None
    if out_path is not None and out_path.is_dir():
        raise click.BadParameter(f"File '{out_path}' is a directory.", param_hint="'--out'")
    if install_path is None and (device_name is not None or replace_overrides):
        raise click.UsageError("--device and --replace-overrides go with --install CONFIG.toml")
    if install_path is not None:
        if update_path is not None:
            raise click.UsageError(
                "--install goes with a calibration from RECORD.csv, or alone with --out CAL.toml (an "
                "existing file); a configuration that names CAL reads it as --update rewrites it"
            )
        if out_path is None:
            raise click.UsageError(
                "--install needs --out CAL.toml: the calibration file the device will name"
            )
        _install_target(install_path, device_name)
        if record_path is None:
            _install(out_path, install_path, device_name, replace_overrides, as_json, existing=True)
            return
    if scheduler is not None and (update_path is not None or record_path is None):
        raise click.UsageError("--scheduler goes with a calibration from records (not --update)")
    if update_path is not None:
        update_calibration(
            update_path, record_path, known, first_s, channel_names, as_name, out_path, as_json
        )
        return
    if known or first_s is not None:
        raise click.UsageError("--known and --first-s go with --update CAL.toml")
    if record_path is None:
        raise click.UsageError("missing argument RECORD.csv (the measurement record to calibrate from)")
    if out_path is not None:
        _check_out(out_path, overwrite)
    try:
        chosen = parse_effects(effects)
        prior = SensorParams().with_overrides(parse_assignments(params, "--param"))
        record = read_record(record_path, require_force=True)
        names = list(channel_names) or list(record.channels)
        channels = [record.channel(n) for n in names]
    except (RecordError, UnknownEffectError, ParameterError) as exc:
        raise click.UsageError(str(exc)) from None
    rename: dict[str, str] = {}
    if as_name is not None:
        if len(channels) != 1:
            raise click.UsageError(
                f"--as names one channel; this run calibrates {len(channels)} (use --channel)"
            )
        if not as_name.strip():
            raise click.UsageError("--as needs a non-empty device channel name")
        rename[channels[0].name] = as_name
    elif out_path is not None and any(c.name == DEFAULT_CHANNEL for c in channels):
        raise click.UsageError(
            f"the record has no channel column, so its channel is named {DEFAULT_CHANNEL!r}, which a device "
            f'config cannot use ([channel."{DEFAULT_CHANNEL}"]); give --as NAME, the device channel name '
            "to write"
        )
    results: list[Calibration] = []
    show = (sys.stderr.isatty() and not as_json) if progress is None else progress
    settings = FitSettings(chosen, prior, OBJECTIVE_OPTIONS[objective], force_offset)
    if wants_channel_pool(len(channels), jobs, scheduler):
        results = _fit_in_pool(
            settings, channels, record_path, record.metadata, jobs, scheduler, progress, as_json
        )
    for k, ch in enumerate([] if results else channels, start=1):
        stages = Progress(f"channel {ch.name!r} ({k}/{len(channels)})") if show else None
        try:
            results.append(
                calibrate(
                    ch,
                    chosen,
                    prior,
                    record_name=str(record_path),
                    metadata=record.metadata,
                    objective=OBJECTIVE_OPTIONS[objective],
                    force_offset=force_offset,
                    jobs=jobs,
                    progress=stages,
                )
            )
        except ValueError as exc:
            raise click.ClickException(str(exc)) from None
        if stages is not None:
            stages("done")
    if out_path is not None:
        try:
            write_calibration(out_path, results, model, rename)
        except OSError as exc:
            raise click.ClickException(f"cannot write {out_path}: {exc.strerror or exc}") from None
    written: list[str] = []
    if plot_dir is not None:
        from ..analysis.calibration_plots import plot_calibration

        for cal in results:
            written += [str(p) for p in plot_calibration(cal, ch_record(record, cal.channel), plot_dir)]
    if as_json:
        payload: dict[str, object] = {"calibrations": [c.as_dict() for c in results], "model": model}
        if out_path is not None:
            payload["written"] = str(out_path)
        if written:
            payload["plots"] = written
        if install_path is not None and out_path is not None:
            _check_effects(results, rename, out_path, install_path)
            payload["installed"] = _installed_dict(
                _do_install(out_path, install_path, device_name, replace_overrides)
            )
        click.echo(json.dumps(payload))
        return
    for cal in results:
        for w in cal.warnings:
            click.echo(f"warning: {w}", err=True)
        click.echo(format_report(cal))
        click.echo("")
    if out_path is not None:
        click.echo(f"wrote {out_path}")
    for p in written:
        click.echo(f"wrote {p}")
    if install_path is not None and out_path is not None:
        _check_effects(results, rename, out_path, install_path)
        _install(out_path, install_path, device_name, replace_overrides, as_json=False)


def _batch(
    records: list[Path],
    out_path: Path | None,
    channel_names: tuple[str, ...],
    effects: str,
    params: tuple[str, ...],
    model: str,
    objective: str,
    force_offset: str,
    as_name: str | None,
    jobs: int | None,
    scheduler: str | None,
    progress: bool | None,
    as_json: bool,
    plot_dir: Path | None,
    update_path: Path | None,
    install_path: Path | None,
    known: tuple[str, ...],
    first_s: float | None,
) -> None:
    """Several records: one calibration each in ``--out DIR`` and a summary (``calibrate_batch``)."""
    if update_path or install_path or plot_dir or known or first_s is not None:
        raise click.UsageError(
            "several records take neither --update, --install, --plots, --known nor --first-s: "
            "calibrate them into --out DIR, then install or update each file alone"
        )
    if as_name is not None and not as_name.strip():
        raise click.UsageError("--as needs a non-empty device channel name")
    out_dir = check_out_dir(out_path)
    try:
        chosen = parse_effects(effects)
        prior = SensorParams().with_overrides(parse_assignments(params, "--param"))
    except (UnknownEffectError, ParameterError) as exc:
        raise click.UsageError(str(exc)) from None
    settings = FitSettings(chosen, prior, OBJECTIVE_OPTIONS[objective], force_offset)
    tracker = tracker_for(progress, as_json, len(records))
    with open_pool(jobs, scheduler) as pool:
        code = run_batch(records, out_dir, pool, settings, channel_names, as_name, model, as_json, tracker)
    tracker.close()
    if code:
        sys.exit(code)


def _fit_in_pool(
    settings: FitSettings,
    channels: list[Any],
    record_path: Path,
    metadata: dict[str, str],
    jobs: int | None,
    scheduler: str | None,
    progress: bool | None,
    as_json: bool,
) -> list[Calibration]:
    """A record's channels side by side (``calibrate_pool``), in the channels' order."""
    tracker = tracker_for(progress, as_json)
    with open_pool(jobs, scheduler) as pool:
        futures = submit_channels(pool, settings, channels, str(record_path), metadata, tracker)
        try:
            results = [f.result() for f in futures]
        except Exception as exc:  # a fit's own refusal, or a worker lost: one line, no traceback
            raise click.ClickException(" ".join(str(exc).split()) or type(exc).__name__) from None
    tracker.record_done(str(record_path), ok=True)
    tracker.close()
    return results


def update_calibration(
    cal_path: Path,
    record_path: Path | None,
    known: tuple[str, ...],
    first_s: float | None,
    channel_names: tuple[str, ...],
    as_name: str | None,
    out_path: Path | None,
    as_json: bool,
) -> None:
    """``calibrate --update``: the sensitivity of CAL's curves from a record or known loads."""
    from ..analysis.update import (
        UpdateError,
        load_channels,
        update_from_loads,
        update_from_record,
        write_updated,
    )

    if (record_path is None) == (not known):
        raise click.UsageError(
            "--update needs either RECORD.csv or --known FORCE_N=RESISTANCE_OHM loads (one of them)"
        )
    try:
        curves = load_channels(cal_path)
        updates = []
        if known:
            loads = list(parse_assignments(known, "--known").items())
            pairs = []
            for f, r in loads:
                try:
                    pairs.append((float(f), r))
                except ValueError:
                    raise click.BadParameter(f"{f!r} is not a force in N", param_hint="--known") from None
            names = list(channel_names) or ([as_name] if as_name else list(curves))
            if len(names) != 1 or names[0] not in curves:
                raise click.UsageError(
                    "--known loads belong to one channel: name it with --channel "
                    f"(calibrated channels: {', '.join(curves)})"
                )
            updates.append(update_from_loads(names[0], curves[names[0]], pairs))
        else:
            assert record_path is not None
            record = read_record(record_path, require_force=True)
            chosen = list(channel_names) or list(record.channels)
            for rec_name in chosen:
                cal_name = as_name if as_name and len(chosen) == 1 else rec_name
                if cal_name not in curves:
                    raise click.UsageError(
                        f"{cal_path} has no table of channel {cal_name!r} for record channel {rec_name!r} "
                        f"(calibrated channels: {', '.join(curves)}; map one with --as NAME)"
                    )
                updates.append(
                    update_from_record(cal_name, curves[cal_name], record.channel(rec_name), first_s)
                )
        target = out_path or cal_path
        write_updated(cal_path, target, {u.channel: u.after for u in updates})
    except (UpdateError, RecordError, ValueError) as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        raise click.ClickException(f"cannot write {out_path or cal_path}: {exc.strerror or exc}") from None
    if as_json:
        click.echo(json.dumps({"updates": [u.as_dict() for u in updates], "written": str(target)}))
        return
    for u in updates:
        click.echo(u.describe())
    click.echo(f"wrote {target}")


class Progress:
    """A calibration's stages on stderr, one line each, with the time since it started."""

    def __init__(self, what: str) -> None:
        self.what = what
        self.start_s = time.monotonic()

    def __call__(self, stage: str) -> None:
        click.echo(f"[{time.monotonic() - self.start_s:5.1f} s] {self.what}: {stage}", err=True)


def ch_record(record: object, name: str) -> object:
    from ..analysis.records import Record

    assert isinstance(record, Record)
    return record.channel(name)


def _check_out(path: Path, overwrite: bool) -> None:
    """Refuse a missing folder, and an existing file that is not a calibration file
    (``config.calibration_file.check_calibration_file``: the gateway's own reading of one)."""
    if not path.parent.is_dir():
        raise click.UsageError(f"--out: directory {path.parent} does not exist")
    if not path.exists() or overwrite:
        return
    try:
        check_calibration_file(path)
    except ConfigError as exc:
        raise click.UsageError(
            f"--out: {path} exists and is not a calibration file (it could be your gateway configuration); "
            f"refusing to replace it: choose another file, or --force ({exc})"
        ) from None


class _Refused(click.ClickException):
    """A refused install: the message, exit status 2 (as ``channels set``'s refusals)."""

    exit_code = 2


def _install_target(config_path: Path, device_name: str | None) -> None:
    """Before a fit: the configuration is a gateway's and has the device (or refuse)."""
    try:
        check_install_target(config_path, device_name)
    except ConfigError as exc:
        raise _Refused(str(exc)) from None


def _do_install(cal_path: Path, config_path: Path, device_name: str | None, replace: bool) -> Installed:
    try:
        return install_calibration(config_path, cal_path, device_name, replace_overrides=replace)
    except ConfigError as exc:
        again = f"tactile-gateway calibrate --out {cal_path} --install {config_path}" + (
            f" --device {device_name}" if device_name else ""
        )
        raise _Refused(
            f"{exc}\n({cal_path} is written; to install it: {again} [--replace-overrides])"
        ) from None


def _installed_dict(done: Installed) -> dict[str, object]:
    return {
        "config": str(done.config),
        "device": done.device,
        "calibration": done.calibration,
        "previous": done.previous,
        "changed": done.changed,
        "dropped": [
            {
                "channel": c.channel,
                "key": c.key,
                "where": c.where,
                "config_value": list(c.config_value) if isinstance(c.config_value, tuple) else c.config_value,
                "calibrated_value": (
                    list(c.calibrated_value) if isinstance(c.calibrated_value, tuple) else c.calibrated_value
                ),
            }
            for c in done.dropped
        ],
    }


def _install(
    cal_path: Path,
    config_path: Path,
    device_name: str | None,
    replace: bool,
    as_json: bool,
    existing: bool = False,
) -> None:
    """``--install``: name ``cal_path`` in the device, and say what changed."""
    if existing:
        try:
            check_calibration_file(cal_path)
        except ConfigError as exc:
            raise _Refused(
                f"--install: --out {cal_path} is not a calibration file to install ({exc})"
            ) from None
    done = _do_install(cal_path, config_path, device_name, replace)
    if as_json:
        click.echo(json.dumps({"installed": _installed_dict(done)}))
        return
    for line in done.lines():
        click.echo(line)


def _check_effects(
    results: list[Calibration], rename: dict[str, str], cal_path: Path, config_path: Path
) -> None:
    """Refuse to install a file whose channels were fitted with different effects: its ``[meta]
    effects`` are the first channel's, and the gateway reads every calibrated channel with them."""
    fitted = {rename.get(c.channel, c.channel): tuple(c.fit.effects) for c in results}
    if len(set(fitted.values())) > 1:
        listed = "; ".join(f"{name}: {', '.join(effects)}" for name, effects in fitted.items())
        raise _Refused(
            f"refused, {config_path} is unchanged: the channels were fitted with different effects "
            f"({listed}), and {cal_path} names one list ([meta] effects), which the gateway reads every "
            "calibrated channel with (a channel gets hysteresis only where it reads held-out force better): "
            "name hysteresis in --effects, so that every channel has it"
        )
