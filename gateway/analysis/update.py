"""Re-fit a stored calibration's sensitivity, keeping its curve's shape and its dynamics.

From one measurement run to the next an FSR's sensitivity can change by up to 2x (its
conductance at the same force), an offset that dwarfs its drift. ``calibrate --update``
re-fits only the two sensitivity parameters of each ``[curve.<name>]`` table
(``gateway.model.curves``): the ``gain`` on the conductance and the force ``offset_n``,
x = curve(R / gain) + offset_n. The static curve and the drift (creep, hysteresis) stay.

Two sources:

* a short record (the first minutes of a new run): the tracked force, as the runtime reads it
  from a relaxed start, is fitted to the reference force over the record's loaded rows;
* one to three known loads (force, resistance) read at rest: the static force is fitted to
  them; one load fits the gain alone (offset kept), two or more fit both.

The fit is a bounded least squares in (ln gain, offset): gain within [1/20, 20] x the stored
one. The file is read with the gateway's checks (``config.calibration_file.load_calibration``)
and rewritten with only the ``gain`` and ``offset_n`` values of the updated tables changed
(``set_table_values``: tomlkit, comments and every other table kept), atomically.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..atomic import atomic_write_text
from ..config.calibration_file import load_calibration, set_table_values
from ..errors import ConfigError
from ..model.curves import CurveChannel, CurveError, curve_from_table, track_series
from .records import ChannelRecord

FloatArray = NDArray[np.float64]

GAIN_SPAN = 20.0  # the gain may move this factor either way from the stored one

__all__ = [
    "SensitivityUpdate",
    "UpdateError",
    "load_curves",
    "rewrite_sensitivity",
    "update_from_loads",
    "update_from_record",
]


class UpdateError(ValueError):
    """A calibration or its update input that cannot be used (the message says why)."""


@dataclass(frozen=True)
class SensitivityUpdate:
    """One channel's sensitivity before and after, and the force errors on the update's data."""

    channel: str
    before: CurveChannel
    after: CurveChannel
    rows: int
    rms_before_n: float
    rms_after_n: float
    full_scale_n: float
    source: str  # "record" or "known loads"

    def as_dict(self) -> dict[str, object]:
        return {
            "channel": self.channel,
            "source": self.source,
            "rows": self.rows,
            "gain": [self.before.gain, self.after.gain],
            "offset_n": [self.before.offset_n, self.after.offset_n],
            "force_rms_n": {"before": self.rms_before_n, "after": self.rms_after_n},
            "force_rms_pct_fs": {"before": self.pct(self.rms_before_n), "after": self.pct(self.rms_after_n)},
        }

    def pct(self, value: float) -> float:
        return 100.0 * value / self.full_scale_n if self.full_scale_n > 0 else math.nan

    def describe(self) -> str:
        b, a = self.before, self.after
        return (
            f"channel {self.channel}: gain {b.gain:.5g} -> {a.gain:.5g}, offset {b.offset_n:+.4g} -> "
            f"{a.offset_n:+.4g} N from {self.rows} {'rows' if self.source == 'record' else 'known loads'}; "
            f"force RMS on them {self.rms_before_n:.4g} N ({self.pct(self.rms_before_n):.2f} % FS) before, "
            f"{self.rms_after_n:.4g} N ({self.pct(self.rms_after_n):.2f} % FS) after"
        )


def load_curves(path: Path) -> dict[str, CurveChannel]:
    """The ``[curve.<name>]`` tables of a calibration file (``load_calibration``), by channel name."""
    try:
        cal = load_calibration(path)
    except ConfigError as exc:
        raise UpdateError(str(exc)) from None
    tables = {name: t.values for name, t in cal.conversions.items() if t.kind == "curve"}
    if not tables:
        raise UpdateError(
            f"{path} has no [curve.<name>] table: --update re-fits the sensitivity of a curve calibration "
            "(write one with `calibrate --model curve`, or `--model auto` where a curve ranks first)"
        )
    out: dict[str, CurveChannel] = {}
    for name, body in tables.items():
        try:
            out[name] = curve_from_table(dict(body))
        except CurveError as exc:
            raise UpdateError(f"{path}: curve.{name}.{exc.key}: {exc.message}") from None
    return out


def _rms(v: FloatArray) -> float:
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else math.nan


def _solve(channel: CurveChannel, residual: object, fit_offset: bool) -> CurveChannel:
    """Bounded least squares in (ln gain, offset) from the stored values."""
    g0 = math.log(channel.gain)
    lo, hi = g0 - math.log(GAIN_SPAN), g0 + math.log(GAIN_SPAN)

    def at(p: FloatArray) -> CurveChannel:
        return channel.with_sensitivity(
            math.exp(float(p[0])), float(p[1]) if fit_offset else channel.offset_n
        )

    def fun(p: FloatArray) -> FloatArray:
        r = residual(at(p))  # type: ignore[operator]
        return np.asarray(np.where(np.isfinite(r), r, 0.0))

    x0 = np.array([g0, channel.offset_n]) if fit_offset else np.array([g0])
    bounds = ([lo, -np.inf], [hi, np.inf]) if fit_offset else ([lo], [hi])
    sol = least_squares(fun, x0, bounds=bounds, x_scale=np.ones_like(x0))
    best = at(sol.x)
    return best if _rms(residual(best)) <= _rms(residual(channel)) else channel  # type: ignore[operator]


def update_from_record(
    name: str, channel: CurveChannel, record: ChannelRecord, first_s: float | None = None
) -> SensitivityUpdate:
    """Fit gain and offset so that the tracked force reads the record's reference force."""
    if record.force_n is None:
        raise UpdateError(f"channel {record.name!r} of the update record has no force_n column")
    t = record.time_s
    keep = np.ones(t.size, dtype=bool) if first_s is None else t < t[0] + first_s
    t, r, f = t[keep], record.resistance_ohm[keep], record.force_n[keep]
    rows = np.isfinite(f) & (f > 0) & np.isfinite(r) & (r > 0)
    if np.count_nonzero(rows) < 2:
        raise UpdateError(
            f"channel {record.name!r}: {int(np.count_nonzero(rows))} loaded rows with a finite resistance "
            "in the update data; at least 2 are needed"
        )

    def residual(ch: CurveChannel) -> FloatArray:
        force, _ = track_series(ch, r, t)
        return np.asarray((force - f)[rows])

    distinct = np.ptp(f[rows]) > 0.05 * float(np.max(f[rows]))
    after = _solve(channel, residual, fit_offset=bool(distinct))
    return SensitivityUpdate(
        name, channel, after, int(np.count_nonzero(rows)), _rms(residual(channel)), _rms(residual(after)),
        float(np.max(f[rows])), "record",
    )  # fmt: skip


def update_from_loads(
    name: str, channel: CurveChannel, loads: Sequence[tuple[float, float]]
) -> SensitivityUpdate:
    """Fit the gain (one load) or gain and offset (two or more) to known (force N, resistance ohm)."""
    if not 1 <= len(loads) <= 10:
        raise UpdateError(f"give 1 to 10 known loads, got {len(loads)}")
    f = np.array([x for x, _ in loads], dtype=np.float64)
    r = np.array([y for _, y in loads], dtype=np.float64)
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(np.isfinite(r)) and np.all(r > 0)):
        raise UpdateError("a known load needs a force > 0 N and a finite resistance > 0 ohm")

    def residual(ch: CurveChannel) -> FloatArray:
        return np.asarray(ch.static_force(r) - f)

    after = _solve(channel, residual, fit_offset=len(loads) >= 2 and bool(np.ptp(f) > 0))
    return SensitivityUpdate(
        name, channel, after, len(loads), _rms(residual(channel)), _rms(residual(after)), float(np.max(f)),
        "known loads",
    )  # fmt: skip


def rewrite_sensitivity(text: str, updates: Mapping[str, CurveChannel]) -> str:
    """``text`` with the ``gain`` and ``offset_n`` of each updated ``[curve.<name>]`` table
    set (added at the table's end when absent); every other line as it was
    (``config.calibration_file.set_table_values``)."""
    values = {name: {"gain": ch.gain, "offset_n": ch.offset_n} for name, ch in updates.items()}
    try:
        return set_table_values(text, "curve", values)
    except KeyError as exc:
        raise UpdateError(f"no [curve.{exc.args[0]}] table to update") from None


def write_updated(path: Path, out_path: Path, updates: Mapping[str, CurveChannel]) -> None:
    """Write ``path`` with the updated sensitivities to ``out_path`` (may be ``path``), atomically."""
    text = path.read_text(encoding="utf-8-sig")
    new = rewrite_sensitivity(text, updates)
    data = tomllib.loads(new)  # the rewrite must still be a calibration with these values
    for name, ch in updates.items():
        table = data["curve"][name]
        if table.get("gain") != ch.gain or table.get("offset_n") != ch.offset_n:
            raise UpdateError(f"{path}: could not rewrite curve.{name}'s gain and offset_n")
    atomic_write_text(out_path, new)
