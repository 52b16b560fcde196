"""Diagnostics of the discrepancy workflow: where a fitted model disagrees with the record.

Residuals of ln R along the record's axes (force level, time since the last load change,
load direction, temperature, load cycle), turned into sentences with their size and counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .fitting import FitData, FitResult

FloatArray = NDArray[np.float64]
#: Readings above this are open circuits for the zero-force consistency check.
OPEN_CIRCUIT_OHM = 1e8


@dataclass(frozen=True)
class Finding:
    """One systematic disagreement, in numbers and in words."""

    axis: str  # force, time_since_change, direction, temperature, cycle
    label: str
    mean_log_residual: float
    n_rows: int
    sentence: str


def residual_axes(data: FitData) -> dict[str, FloatArray]:
    """Per-row coordinates along which residuals are examined."""
    t, f = data.time_s, data.force_n
    change = np.flatnonzero(np.abs(np.diff(f)) > 1e-9) + 1
    last_change = np.zeros(t.size, dtype=np.int64)
    if change.size:
        idx = np.searchsorted(change, np.arange(t.size), side="right") - 1
        last_change = np.where(idx >= 0, change[np.maximum(idx, 0)], 0)
    since = t - t[last_change]
    step = np.diff(f, prepend=f[0])
    direction = np.zeros(t.size)
    moving = np.flatnonzero(np.abs(step) > 1e-9)
    if moving.size:
        idx = np.searchsorted(moving, np.arange(t.size), side="right") - 1
        direction = np.where(idx >= 0, np.sign(step[moving[np.maximum(idx, 0)]]), 0.0)
    level = float(np.median(f[f > 0])) if np.any(f > 0) else 0.0
    ups = np.flatnonzero((f[1:] >= level) & (f[:-1] < level)) + 1
    cycle = np.searchsorted(ups, np.arange(t.size), side="right").astype(np.float64)
    axes = {"force": f, "time_since_change": since, "direction": direction, "cycle": cycle}
    if data.temperature_c is not None:
        axes["temperature"] = data.temperature_c
    return axes


def describe_gaps(data: FitData, fit: FitResult, limit: int = 4) -> tuple[Finding, ...]:
    """The largest systematic disagreements, most significant first."""
    res = fit.log_residual
    rows = data.usable & np.isfinite(res)
    if not rows.any():
        return ()
    noise = float(np.std(np.diff(res[rows]))) / math.sqrt(2.0) or 1e-12
    axes = residual_axes(data)
    findings: list[tuple[float, Finding]] = []

    def add(axis: str, label: str, mask: NDArray[np.bool_], words: str) -> None:
        m = mask & rows
        n = int(np.count_nonzero(m))
        if n < 10:
            return
        mean = float(np.mean(res[m]))
        z = abs(mean) / (noise / math.sqrt(n))
        pct = 100.0 * math.expm1(mean)
        if abs(pct) < 1.0 or z < 5.0:
            return
        side = "above" if mean > 0 else "below"
        findings.append(
            (
                z,
                Finding(
                    axis,
                    label,
                    mean,
                    n,
                    f"{words} the measured resistance is {abs(pct):.0f} % {side} the model",
                ),
            )
        )

    f = axes["force"]
    pos = f[rows & (f > 0)]
    if pos.size:
        edges = np.geomspace(max(float(pos.min()), 1e-3), float(pos.max()) * 1.0001, 5)
        names = ["at low force", "at low-mid force", "at mid-high force", "at high force"]
        for i in range(4):
            add(
                "force",
                f"{edges[i]:.2g}-{edges[i + 1]:.2g} N",
                (f >= edges[i]) & (f < edges[i + 1]),
                f"{names[i]} ({edges[i]:.2g}-{edges[i + 1]:.2g} N)",
            )
    since = axes["time_since_change"]
    for lo, hi, words in (
        (0, 5, "within 5 s of a load change"),
        (5, 60, "5-60 s after a load change"),
        (60, 600, "1-10 min into a hold"),
        (600, math.inf, "after 10 min of holding"),
    ):
        add("time_since_change", f"{lo}-{hi} s", (since >= lo) & (since < hi) & (f > 0), words)
    d = axes["direction"]
    add("direction", "loading", d > 0, "while loading")
    add("direction", "unloading", (d < 0) & (f > 0), "while unloading")
    if "temperature" in axes:
        temp = axes["temperature"]
        ref = float(np.median(temp[rows]))
        add("temperature", f"above {ref + 2:.0f} °C", temp > ref + 2.0, f"above {ref + 2:.0f} °C")
        add("temperature", f"below {ref - 2:.0f} °C", temp < ref - 2.0, f"below {ref - 2:.0f} °C")
    cycle = axes["cycle"]
    if cycle.max() >= 3:
        add("cycle", "first cycle", cycle <= 1, "in the first load cycle")
        add("cycle", "later cycles", cycle >= 3, "in the later load cycles")
    unloaded = data.force_n <= 0.0
    if unloaded.any() and fit.model_ohm.size:
        measured_open = data.resistance_ohm[unloaded] >= OPEN_CIRCUIT_OHM
        model_open = fit.model_ohm[unloaded] >= OPEN_CIRCUIT_OHM
        n_bad = int(np.count_nonzero(measured_open != model_open))
        if n_bad >= 5:
            if np.count_nonzero(measured_open & ~model_open) >= np.count_nonzero(~measured_open & model_open):
                model_r = float(np.median(fit.model_ohm[unloaded][measured_open & ~model_open]))
                words = (
                    f"unloaded, the sensor reads open on {n_bad} rows where the model reads "
                    f"{model_r / 1e3:.0f} kohm"
                )
            else:
                meas_r = float(np.median(data.resistance_ohm[unloaded][~measured_open & model_open]))
                words = (
                    f"unloaded, the sensor reads {meas_r / 1e3:.0f} kohm on {n_bad} rows where the model "
                    "is open"
                )
            findings.append((math.inf, Finding("zero_force", "unloaded", math.nan, n_bad, words)))
    findings.sort(key=lambda item: -item[0])
    return tuple(fd for _, fd in findings[:limit])
