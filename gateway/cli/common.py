"""Shared helpers for the CLI: number lists, NAME=VALUE pairs, clean errors."""

from __future__ import annotations

import math
from pathlib import Path

import click

#: ``-c/--config FILE``: the gateway configuration, for every command that reads one.
config_option = click.option(
    "-c",
    "--config",
    "config_path",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="the gateway configuration file (TOML)",
)


def finite_seconds(ctx: click.Context, param: click.Parameter, value: float | None) -> float | None:
    """A click callback: a number of seconds must be finite (``nan`` passes a ``FloatRange``,
    which compares, and ``inf`` would never end)."""
    if value is not None and not math.isfinite(value):
        raise click.BadParameter(f"{value} is not a number of seconds; expected a finite number, e.g. 30")
    return value


def parse_float_list(text: str, what: str) -> list[float]:
    """Parse ``"0.5,2,5"`` into floats, with an error that names the bad item."""
    values: list[float] = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        try:
            values.append(float(item))
        except ValueError:
            raise click.BadParameter(f"{item!r} is not a number", param_hint=what) from None
    if not values:
        raise click.BadParameter("needs at least one number", param_hint=what)
    return values


def parse_assignments(pairs: tuple[str, ...], what: str) -> dict[str, float]:
    """Parse ``NAME=VALUE`` pairs into a dict of floats."""
    out: dict[str, float] = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name.strip():
            raise click.BadParameter(f"{pair!r} is not NAME=VALUE", param_hint=what)
        try:
            number = float(value)
        except ValueError:
            raise click.BadParameter(f"{value!r} in {pair!r} is not a number", param_hint=what) from None
        if math.isnan(number):
            raise click.BadParameter(f"{pair!r}: NaN is not a parameter value", param_hint=what)
        out[name.strip()] = number
    return out
