"""``tactile-gateway discrepancy``: find the physical effect the model is missing."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..analysis.discrepancy import decimate, parse_baseline, prepare, run_discrepancy
from ..analysis.measurement import time_is_real
from ..analysis.records import read_record
from ..errors import RecordError
from ..model import ParameterError, SensorParams, UnknownEffectError, parse_effects
from .common import parse_assignments


@click.command("discrepancy")
@click.argument("record_path", metavar="RECORD.csv", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--channel", "channel_name", default=None, help="channel to examine (needed if several)")
@click.option(
    "--baseline",
    default="auto",
    show_default=True,
    help="where to start: auto (the best static form on held-out force: the paper's physics or a "
    "static curve), effects of a physical model (tunneling,contact), or a curve kind "
    "(power_law, line, lookup)",
)
@click.option(
    "--candidates", default=None, help="effects to try (default: every spec effect not in the model)"
)
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE", help="prior value of a parameter")
@click.option(
    "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), help="write DIR/report.md"
)
@click.option(
    "--jobs",
    type=click.IntRange(min=1),
    default=None,
    metavar="N",
    help="processes a step's candidate fits may use (default: every core); the report is the same with any",
)
@click.option("--json", "as_json", is_flag=True, help="print the spec's JSON object and nothing else")
def discrepancy_cmd(
    record_path: Path,
    channel_name: str | None,
    baseline: str,
    candidates: str | None,
    params: tuple[str, ...],
    out_dir: Path | None,
    jobs: int | None,
    as_json: bool,
) -> None:
    """Start from the sensor's best static form (or the baseline given), find where it
    disagrees, add the missing effects one by one."""
    try:
        base = parse_baseline(baseline.split(","))
        cands = None if candidates is None else parse_effects(candidates)
        prior = SensorParams().with_overrides(parse_assignments(params, "--param"))
        record = read_record(record_path, require_force=True)
        channel = record.channel(channel_name)
    except (RecordError, UnknownEffectError, ParameterError, ValueError) as exc:
        raise click.UsageError(str(exc)) from None
    try:
        report = run_discrepancy(
            channel,
            None if base[0] == "auto" else baseline.split(","),
            cands,
            prior,
            record_name=str(record_path),
            metadata=record.metadata,
            jobs=jobs,
        )
    except ValueError as exc:
        raise click.ClickException(str(exc)) from None
    if out_dir is not None:
        from ..analysis.discrepancy_report import write_report

        data, _, _ = prepare(decimate(channel), record.metadata, prior)
        write_report(report, data, out_dir, real_time=time_is_real(record.metadata))
    if as_json:
        click.echo(json.dumps(report.as_json()))
        return
    if report.static_choice is not None:
        click.echo(report.static_choice.sentence())
    if report.start is not None:
        click.echo(report.start.sentence())
    for i, step in enumerate(report.steps, start=1):
        click.echo(f"step {i}: model {step.label}")
        for f in step.findings:
            click.echo(f"  - {f.sentence}")
        click.echo(f"  -> {'add ' + step.added if step.added else 'add nothing'}: {step.evidence}")
        if step.added:
            before, after = step.tracked_before, step.tracked_after
            click.echo(f"  tracked held-out force RMS {before:.4g} -> {after:.4g} N")
    j = report.as_json()
    effects = ", ".join(j["final"]) or "no effect"
    click.echo(f"added: {', '.join(j['added']) or 'nothing'}; final model: {j['final_model']} ({effects})")
    click.echo(f"held-out gap before: {j['gap_before']}, after: {j['gap_after']}")
    click.echo(f"noise floor (log-R): {report.noise_floor_log:.4g}; {report.noise_description}")
    click.echo(report.rival_summary())
    if report.unexplained is not None:
        click.echo(report.unexplained.sentence())
    for note in report.notes:
        click.echo(f"note: {note}")
    if out_dir is not None:
        click.echo(f"wrote {out_dir / 'report.md'}")
