"""``tactile-gateway model ...``: evaluate, invert and plot the sensor model."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click
import numpy as np

from ..model import EFFECT_NAMES, ForceStatus, ParameterError, SensorModel, SensorParams, UnknownEffectError
from .common import parse_assignments, parse_float_list


def _build(effects: str, params: tuple[str, ...], n: int = 1) -> SensorModel:
    try:
        p = SensorParams().with_overrides(parse_assignments(params, "--param"))
        return SensorModel(effects, [p] * n)
    except (ParameterError, UnknownEffectError) as exc:
        raise click.UsageError(str(exc)) from None


_effects_option = click.option(
    "--effects",
    default="tunneling,contact,creep",
    show_default=True,
    help=f"comma-separated effects ({', '.join(EFFECT_NAMES)})",
)
_param_option = click.option(
    "--param", "params", multiple=True, metavar="NAME=VALUE", help="override a sensor parameter (SI units)"
)


@click.group()
def model() -> None:
    """Evaluate, invert and plot the sensor model."""


def _number(x: float) -> float | str:
    return x if math.isfinite(x) else ("inf" if x > 0 else "-inf") if not math.isnan(x) else "nan"


def _cell(value: float | str, width: int, spec: str) -> str:
    """A table cell: numbers with ``spec``, the words inf/-inf/nan as they are."""
    return f"{value:>{width}}" if isinstance(value, str) else f"{value:>{width}{spec}}"


#: The largest force ``model eval`` evaluates (N): far beyond any sensor, below float overflow.
MAX_EVAL_FORCE_N = 1e6


@model.command("eval")
@click.option("--force", "force_text", required=True, help="forces in N, e.g. 0.5,2,5 (each held from t=0)")
@click.option("--time", "time_text", default="0", show_default=True, help="times in s, e.g. 0,600")
@_effects_option
@_param_option
@click.option("--json", "as_json", is_flag=True, help="print a JSON list and nothing else")
def eval_cmd(force_text: str, time_text: str, effects: str, params: tuple[str, ...], as_json: bool) -> None:
    """Resistance of the sensor for forces held as steps from t = 0 (eq. 15-17)."""
    forces = parse_float_list(force_text, "--force")
    times = parse_float_list(time_text, "--time")
    if any(not 0.0 <= f <= MAX_EVAL_FORCE_N for f in forces):
        raise click.BadParameter(
            f"forces must be in [0, {MAX_EVAL_FORCE_N:g}] N (finite, not negative)", param_hint="--force"
        )
    if any(t < 0 or not math.isfinite(t) for t in times):
        raise click.BadParameter("times must be finite and >= 0 s", param_hint="--time")
    m = _build(effects, params)
    rows = []
    for f in forces:
        for t in times:
            with np.errstate(all="ignore"):
                b = m.held_step(np.array([f]), t)
            rows.append(
                {
                    "force_n": f,
                    "time_s": t,
                    "resistance_ohm": _number(float(b.total_ohm[0])),
                    "contact_ohm": _number(float(b.contact_ohm[0])),
                    "polymer_ohm": _number(float(b.polymer_ohm[0])),
                    "strain": float(b.strain[0]),
                }
            )
    if as_json:
        click.echo(json.dumps(rows))
        return
    header = ("force_n", 9), ("time_s", 9), ("resistance_ohm", 15), ("contact_ohm", 12), ("polymer_ohm", 12)
    click.echo(" ".join(f"{name:>{width}}" for name, width in header) + f" {'strain':>9}")
    for r in rows:
        click.echo(
            f"{_cell(r['force_n'], 9, '.4g')} {_cell(r['time_s'], 9, '.4g')} "
            f"{_cell(r['resistance_ohm'], 15, '.6g')} {_cell(r['contact_ohm'], 12, '.6g')} "
            f"{_cell(r['polymer_ohm'], 12, '.6g')} {_cell(r['strain'], 9, '.5f')}"
        )


@model.command("invert")
@click.option("--resistance", "resistance_text", required=True, help="resistances in ohm, e.g. 9980,46900")
@_effects_option
@_param_option
@click.option("--json", "as_json", is_flag=True, help="print a JSON list and nothing else")
def invert_cmd(resistance_text: str, effects: str, params: tuple[str, ...], as_json: bool) -> None:
    """Static inverse: the force that gives each resistance with no creep state."""
    values = parse_float_list(resistance_text, "--resistance")
    bad = [v for v in values if not v >= 0.0]
    if bad:
        raise click.BadParameter(
            f"{_number(bad[0])} ohm: a resistance is >= 0 ohm (0: a short, read invalid; inf: open)",
            param_hint="--resistance",
        )
    m = _build(effects, params, n=len(values))
    inv = m.invert_static(np.array(values))
    rows = [
        {
            "resistance_ohm": _number(r),
            "force_n": None if math.isnan(f) else f,
            "status": ForceStatus(int(s)).name.lower(),
        }
        for r, f, s in zip(values, inv.force_n.tolist(), inv.status.tolist(), strict=True)
    ]
    if as_json:
        click.echo(json.dumps(rows))
        return
    click.echo(f"{'resistance_ohm':>15} {'force_n':>10} status")
    for r in rows:
        force = "-" if r["force_n"] is None else f"{r['force_n']:.6g}"
        click.echo(f"{r['resistance_ohm']!s:>15} {force:>10} {r['status']}")


@model.command("plot")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@_effects_option
@_param_option
def plot_cmd(out_dir: Path, effects: str, params: tuple[str, ...]) -> None:
    """Write PNGs that replay the paper's Fig. 5, 9b and 10 from the model."""
    from ..analysis.plots import plot_model_figures

    m = _build(effects, params)
    try:
        paths = plot_model_figures(m, out_dir)
    except OSError as exc:
        raise click.ClickException(
            f"cannot write the figures into {out_dir}: {exc.strerror or exc}"
        ) from None
    for path in paths:
        click.echo(str(path))
