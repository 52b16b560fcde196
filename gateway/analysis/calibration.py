"""Calibration: fit a channel's model to a record and compare with the paper's line (eq. 18).

Two calibrations of the same sensor are fitted on the same training rows and judged on the
same held-out rows: the physical model (``fitting.fit_channel``, drift-corrected inversion)
and the paper's linear conductance calibration C = m F + n.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write_text
from ..model import ConductanceLine, SensorParams, parameter_names
from .fitting import FitData, FitResult, fit_channel
from .records import ChannelRecord


@dataclass(frozen=True)
class Calibration:
    """Result of calibrating one channel."""

    channel: str
    record: str
    fit: FitResult
    line: ConductanceLine
    line_force_rms_n: float
    unusable: dict[str, int]

    def as_dict(self) -> dict[str, Any]:
        fit = self.fit
        return {
            "record": self.record,
            "channel": self.channel,
            "effects": list(fit.effects),
            "parameters": [
                {
                    "name": e.name,
                    "value": e.value,
                    "ci95_low": e.low,
                    "ci95_high": e.high,
                    "fitted": e.fitted,
                    "note": e.note,
                }
                for e in fit.estimates
            ],
            "correlation": {
                "names": list(fit.correlation_names),
                "matrix": [[round(float(v), 4) for v in row] for row in fit.correlation],
            },
            "fit_quality": {"train": fit.gap_train.as_dict(), "held_out": fit.gap_test.as_dict()},
            "rows": {"train": fit.n_train, "held_out": fit.n_test, "unusable": self.unusable},
            "conductance_line": {
                "slope_s_per_n": self.line.slope_s_per_n,
                "intercept_s": self.line.intercept_s,
                "held_out_force_rms_n": self.line_force_rms_n,
            },
        }


def calibrate(
    channel: ChannelRecord,
    effects: Iterable[str] = ("tunneling", "contact", "creep"),
    prior: SensorParams | None = None,
    record_name: str = "",
) -> Calibration:
    """Fit the model and the conductance line to one channel of a record."""
    data = FitData.from_channel(channel)
    if not data.train.any() or not data.test.any():
        raise ValueError(
            f"channel {channel.name!r}: not enough usable rows to fit and to hold out "
            f"({int(data.train.sum())} training, {int(data.test.sum())} held-out rows)"
        )
    fit = fit_channel(data, effects, prior)
    train = data.train
    line = ConductanceLine.fit(data.force_n[train], data.resistance_ohm[train])
    err = line.force(data.resistance_ohm[data.test]) - data.force_n[data.test]
    return Calibration(
        channel=channel.name,
        record=record_name,
        fit=fit,
        line=line,
        line_force_rms_n=float(np.sqrt(np.mean(err * err))),
        unusable=channel.unusable_counts(),
    )


def calibration_toml(calibrations: Iterable[Calibration]) -> str:
    """A calibration file: ``[channel.<name>]`` tables the gateway config can reference."""
    items = list(calibrations)
    lines = ["# Written by `tactile-gateway calibrate`; the gateway reads the [channel.<name>] tables."]
    if items:
        effects = ", ".join(f'"{e}"' for e in items[0].fit.effects)
        lines += ["", "[meta]", f'record = "{items[0].record}"', f"effects = [{effects}]"]
    names = set(parameter_names())
    for cal in items:
        lines += ["", f'[channel."{cal.channel}"]']
        for est in cal.fit.estimates:
            if est.name in names:
                lines.append(f"{est.name} = {_toml_float(est.value)}")
    return "\n".join(lines) + "\n"


def _toml_float(value: float) -> str:
    return "inf" if math.isinf(value) else repr(float(value))


def write_calibration(path: Path, calibrations: Iterable[Calibration]) -> None:
    """Write the calibration file atomically."""
    atomic_write_text(path, calibration_toml(calibrations))


def format_report(cal: Calibration) -> str:
    """Human-readable calibration report."""
    fit = cal.fit
    out = [f"channel {cal.channel} of {cal.record}: effects {', '.join(fit.effects)}"]
    out.append(f"rows: {fit.n_train} training, {fit.n_test} held out, unusable {cal.unusable}")
    out.append("")
    out.append(f"{'parameter':<24} {'value':>12} {'95 % interval':>27}  note")
    for e in fit.estimates:
        interval = f"[{e.low:.4g}, {e.high:.4g}]" if e.fitted else "fixed at prior"
        out.append(f"{e.name:<24} {e.value:>12.5g} {interval:>27}  {e.note}")
    if fit.correlation.size:
        out.append("")
        out.append("strongest parameter correlations:")
        pairs = []
        n = len(fit.correlation_names)
        for i in range(n):
            for j in range(i + 1, n):
                pairs.append((abs(float(fit.correlation[i, j])), i, j))
        for value, i, j in sorted(pairs, reverse=True)[:5]:
            sign = "+" if fit.correlation[i, j] >= 0 else "-"
            out.append(f"  {fit.correlation_names[i]} ~ {fit.correlation_names[j]}: {sign}{value:.3f}")
    out.append("")
    out.append("held-out data                      log-resistance RMS   force RMS (N)")
    out.append(
        f"  physical model (drift-corrected) {fit.gap_test.log_resistance_rms:>18.4f} "
        f"{fit.gap_test.force_rms_n:>15.4f}"
    )
    out.append(f"  conductance line C = m F + n     {'-':>18} {cal.line_force_rms_n:>15.4f}")
    out.append(f"    m = {cal.line.slope_s_per_n:.6g} S/N, n = {cal.line.intercept_s:.6g} S")
    return "\n".join(out)
