"""Re-fit a stored calibration's sensitivity, keeping its shape and its dynamics.

From one measurement run to the next an FSR's sensitivity can change by up to 2x (its
conductance at the same force), an offset that dwarfs its drift. ``calibrate --update``
re-fits only the sensitivity of every calibrated channel, whatever its table:

* a ``[curve.<name>]`` table (``gateway.model.calibrated.CurveChannel``): the ``gain`` on the
  conductance and the force ``offset_n``, x = curve(R / gain) + offset_n; the static curve and
  the drift (creep, hysteresis) stay;
* a ``[line.<name>]`` or ``[lookup.<name>]`` table: the same two, written back as a
  ``[curve.<name>]`` table of that curve (a line or lookup table has no sensitivity keys);
* a ``[channel.<name>]`` table alone (the physical model): the gain alone, every resistance of
  the model divided by it (``r0_ohm``, ``rho1_ohm_m``, ``rho2_ohm_m``, ``series_resistance_ohm``,
  ``leakage_resistance_ohm``: the model then reads R / gain as it read R).

Two sources:

* a short record (the first minutes of a new run): the tracked force, as the runtime reads it
  from the equilibrium at the record's first load (``gateway.model.tracker``), is fitted to the
  reference force over the record's loaded rows. With ``first_s`` the rest of the record is
  the transfer test: the updated calibration keeps tracking through it (its state carried over
  from the head), and its error there is reported in % of the whole run's full scale, beside a
  lookup re-fitted on the same head (the best a static rival does treated the same way);
* one to three known loads (force, resistance) read at rest: the static force is fitted to
  them; one load fits the gain alone (offset kept), two or more fit both.

The fit is a bounded least squares in (ln gain, offset): gain within [1/20, 20] x the stored
one. The file is read with the gateway's checks (``config.calibration_file.load_calibration``)
and rewritten with only the updated values changed (tomlkit: comments and every other table
kept), atomically.
"""

from __future__ import annotations

import math
import tempfile
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..atomic import atomic_write_text
from ..config.calibration_file import calibration_effects, load_calibration, replace_table, set_table_values
from ..config.tables import read_text_file
from ..errors import ConfigError
from ..model import SensorModel, SensorParams
from ..model.calibrated import CurveChannel, channel_from_table
from ..model.effects import PAPER_EFFECTS
from ..model.static_curves import CurveError, LookupCurve
from ..model.tracker import track_series
from .records import ChannelRecord

FloatArray = NDArray[np.float64]

GAIN_SPAN = 20.0  # the gain may move this factor either way from the stored one
#: The physical model's resistances: divided by the gain, the model reads R / gain as it read R.
RESISTANCE_PARAMETERS = (
    "r0_ohm", "rho1_ohm_m", "rho2_ohm_m", "series_resistance_ohm", "leakage_resistance_ohm"
)  # fmt: skip

__all__ = [
    "PhysicsChannel",
    "SensitivityUpdate",
    "Transfer",
    "UpdateError",
    "load_channels",
    "rewrite_sensitivity",
    "update_from_loads",
    "update_from_record",
]


class UpdateError(ValueError):
    """A calibration or its update input that cannot be used (the message says why)."""


@dataclass(frozen=True)
class PhysicsChannel:
    """A channel read by the physical model (``[channel.<name>]`` parameters, the file's
    effects), with a sensitivity ``gain``: it reads a resistance R as the stored model reads
    R x gain. No offset (``offset_n`` is always 0)."""

    params: SensorParams
    effects: tuple[str, ...]
    gain: float = 1.0
    offset_n: float = 0.0

    def with_sensitivity(self, gain: float, offset_n: float) -> PhysicsChannel:
        return replace(self, gain=gain)

    def static_force(self, resistance_ohm: FloatArray) -> FloatArray:
        model = SensorModel(self.effects, [self.params])
        r = np.asarray(resistance_ohm, dtype=np.float64) * self.gain
        with np.errstate(all="ignore"):
            return np.asarray(model.invert_static(r[:, None]).force_n[:, 0])

    def track(self, resistance_ohm: FloatArray, time_s: FloatArray) -> FloatArray:
        """The drift-corrected force (N) over a series, as the physical model tracks it: from the
        equilibrium at the series' first load (its history before is not known)."""
        model = SensorModel(self.effects, [self.params])
        r = np.asarray(resistance_ohm, dtype=np.float64) * self.gain
        with np.errstate(all="ignore"):
            inv, _ = model.track_series(
                r[:, None], np.asarray(time_s, dtype=np.float64), model.unknown_state()
            )
        return np.asarray(inv.force_n[:, 0])

    def scaled_params(self) -> dict[str, float]:
        """The stored parameters with every resistance divided by the gain."""
        return {k: float(getattr(self.params, k)) / self.gain for k in RESISTANCE_PARAMETERS}


Calibrated = CurveChannel | PhysicsChannel


def _track(channel: Calibrated, resistance_ohm: FloatArray, time_s: FloatArray) -> FloatArray:
    if isinstance(channel, PhysicsChannel):
        return channel.track(resistance_ohm, time_s)
    return track_series(channel, resistance_ohm, time_s)[0]


@dataclass(frozen=True)
class Transfer:
    """The rest of a run after the update's head: rows, its full scale (the whole run's largest
    reference force, N) and the force RMS (N) there of the stored calibration, the updated one
    and a lookup re-fitted on the same head."""

    rows: int
    full_scale_n: float
    rms_before_n: float
    rms_after_n: float
    refitted_lookup_rms_n: float

    def pct(self, value: float) -> float:
        return 100.0 * value / self.full_scale_n if self.full_scale_n > 0 else math.nan

    def as_dict(self) -> dict[str, object]:
        return {
            "rows": self.rows,
            "full_scale_n": self.full_scale_n,
            "force_rms_pct_fs": {
                "before": self.pct(self.rms_before_n),
                "after": self.pct(self.rms_after_n),
                "lookup_refitted_on_head": self.pct(self.refitted_lookup_rms_n),
            },
        }


@dataclass(frozen=True)
class SensitivityUpdate:
    """One channel's sensitivity before and after, and the force errors on the update's data."""

    channel: str
    before: Calibrated
    after: Calibrated
    rows: int
    rms_before_n: float
    rms_after_n: float
    full_scale_n: float
    source: str  # "record" or "known loads"
    transfer: Transfer | None = None

    @property
    def kind(self) -> str:
        return "physics" if isinstance(self.before, PhysicsChannel) else self.before.table_kind

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {
            "channel": self.channel,
            "kind": self.kind,
            "source": self.source,
            "rows": self.rows,
            "gain": [self.before.gain, self.after.gain],
            "offset_n": [self.before.offset_n, self.after.offset_n],
            "force_rms_n": {"before": self.rms_before_n, "after": self.rms_after_n},
            "force_rms_pct_fs": {"before": self.pct(self.rms_before_n), "after": self.pct(self.rms_after_n)},
        }
        if self.transfer is not None:
            out["rest_of_run"] = self.transfer.as_dict()
        return out

    def pct(self, value: float) -> float:
        return 100.0 * value / self.full_scale_n if self.full_scale_n > 0 else math.nan

    def describe(self) -> str:
        b, a = self.before, self.after
        out = (
            f"channel {self.channel} ({self.kind}): gain {b.gain:.5g} -> {a.gain:.5g}, offset "
            f"{b.offset_n:+.4g} -> {a.offset_n:+.4g} N from {self.rows} "
            f"{'rows' if self.source == 'record' else 'known loads'}; force RMS on them "
            f"{self.rms_before_n:.4g} N ({self.pct(self.rms_before_n):.2f} % of their largest force) "
            f"before, {self.rms_after_n:.4g} N ({self.pct(self.rms_after_n):.2f} %) after"
        )
        x = self.transfer
        if x is not None:
            out += (
                f"\n  the rest of the run ({x.rows} rows, full scale {x.full_scale_n:.4g} N): force RMS "
                f"{x.pct(x.rms_before_n):.2f} % FS before, {x.pct(x.rms_after_n):.2f} % FS after; a lookup "
                f"re-fitted on the same head reads it at {x.pct(x.refitted_lookup_rms_n):.2f} % FS"
            )
        return out


def load_channels(path: Path) -> dict[str, Calibrated]:
    """Every calibrated channel of a calibration file (``load_calibration``), by name: its
    line, lookup or curve table, else its ``[channel.<name>]`` parameters (the physical model,
    with the file's ``[meta] effects``)."""
    try:
        cal = load_calibration(path)
        effects = calibration_effects(path) or PAPER_EFFECTS
    except ConfigError as exc:
        raise UpdateError(str(exc)) from None
    out: dict[str, Calibrated] = {}
    for name, table in cal.conversions.items():
        try:
            out[name] = channel_from_table(table.kind, dict(table.values), 0.01, math.inf)
        except CurveError as exc:
            raise UpdateError(f"{path}: {table.kind}.{name}.{exc.key}: {exc.message}") from None
    for name, params in cal.params().items():
        if name not in out:
            out[name] = PhysicsChannel(SensorParams(**params), tuple(effects))
    if not out:
        raise UpdateError(
            f"{path} has no calibrated channel: no [channel], [line], [lookup] or [curve] table"
        )
    return out


def _rms(v: FloatArray) -> float:
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else math.nan


def _solve(channel: Calibrated, residual: Callable[[Calibrated], FloatArray], fit_offset: bool) -> Calibrated:
    """Bounded least squares in (ln gain, offset) from the stored values."""
    g0 = math.log(channel.gain)
    lo, hi = g0 - math.log(GAIN_SPAN), g0 + math.log(GAIN_SPAN)

    def at(p: FloatArray) -> Calibrated:
        return channel.with_sensitivity(
            math.exp(float(p[0])), float(p[1]) if fit_offset else channel.offset_n
        )

    def fun(p: FloatArray) -> FloatArray:
        r = residual(at(p))
        return np.asarray(np.where(np.isfinite(r), r, 0.0))

    x0 = np.array([g0, channel.offset_n]) if fit_offset else np.array([g0])
    bounds = ([lo, -np.inf], [hi, np.inf]) if fit_offset else ([lo], [hi])
    sol = least_squares(fun, x0, bounds=bounds, x_scale=np.ones_like(x0))
    best = at(sol.x)
    return best if _rms(residual(best)) <= _rms(residual(channel)) else channel


def update_from_record(
    name: str, channel: Calibrated, record: ChannelRecord, first_s: float | None = None
) -> SensitivityUpdate:
    """Fit the sensitivity so that the tracked force reads the record's reference force (over
    its first ``first_s`` seconds; the rest is the transfer test, ``Transfer``)."""
    if record.force_n is None:
        raise UpdateError(f"channel {record.name!r} of the update record has no force_n column")
    t_all, r_all, f_all = record.time_s, record.resistance_ohm, record.force_n
    keep = np.ones(t_all.size, dtype=bool) if first_s is None else t_all < t_all[0] + first_s
    t, r, f = t_all[keep], r_all[keep], f_all[keep]
    rows = np.isfinite(f) & (f > 0) & np.isfinite(r) & (r > 0)
    if np.count_nonzero(rows) < 2:
        raise UpdateError(
            f"channel {record.name!r}: {int(np.count_nonzero(rows))} loaded rows with a finite resistance "
            "in the update data; at least 2 are needed"
        )

    def residual(ch: Calibrated) -> FloatArray:
        return np.asarray((_track(ch, r, t) - f)[rows])

    distinct = np.ptp(f[rows]) > 0.05 * float(np.max(f[rows]))
    fit_offset = bool(distinct) and not isinstance(channel, PhysicsChannel)
    after = _solve(channel, residual, fit_offset=fit_offset)
    transfer = None
    rest = ~keep & np.isfinite(f_all) & np.isfinite(r_all)
    if first_s is not None and np.count_nonzero(rest) >= 2:
        # the whole run tracked: the state at the cut carried over from the head
        before_all, after_all = _track(channel, r_all, t_all), _track(after, r_all, t_all)
        lookup = LookupCurve.fit(f[rows], r[rows])
        lookup_ch = channel_from_table("lookup", lookup.table(), 0.0, 0.0)
        lookup_all, _ = track_series(lookup_ch, r_all, t_all)
        transfer = Transfer(
            int(np.count_nonzero(rest)), float(np.nanmax(f_all)), _rms((before_all - f_all)[rest]),
            _rms((after_all - f_all)[rest]), _rms((lookup_all - f_all)[rest]),
        )  # fmt: skip
    return SensitivityUpdate(
        name, channel, after, int(np.count_nonzero(rows)), _rms(residual(channel)), _rms(residual(after)),
        float(np.max(f[rows])), "record", transfer,
    )  # fmt: skip


def update_from_loads(
    name: str, channel: Calibrated, loads: Sequence[tuple[float, float]]
) -> SensitivityUpdate:
    """Fit the gain (one load) or gain and offset (two or more) to known (force N, resistance ohm)."""
    if not 1 <= len(loads) <= 10:
        raise UpdateError(f"give 1 to 10 known loads, got {len(loads)}")
    f = np.array([x for x, _ in loads], dtype=np.float64)
    r = np.array([y for _, y in loads], dtype=np.float64)
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(np.isfinite(r)) and np.all(r > 0)):
        raise UpdateError("a known load needs a force > 0 N and a finite resistance > 0 ohm")

    def residual(ch: Calibrated) -> FloatArray:
        return np.asarray(ch.static_force(r) - f)

    physics = isinstance(channel, PhysicsChannel)
    after = _solve(channel, residual, fit_offset=not physics and len(loads) >= 2 and bool(np.ptp(f) > 0))
    return SensitivityUpdate(
        name, channel, after, len(loads), _rms(residual(channel)), _rms(residual(after)), float(np.max(f)),
        "known loads",
    )  # fmt: skip


def rewrite_sensitivity(text: str, updates: Mapping[str, Calibrated]) -> str:
    """``text`` with each updated channel's sensitivity set, every other line as it was: a
    ``[curve]`` table's ``gain`` and ``offset_n`` (``set_table_values``); a ``[line]`` or
    ``[lookup]`` table replaced by the ``[curve]`` table of the same curve with them
    (``replace_table``); a physical model's resistances divided by its gain."""
    curves: dict[str, dict[str, float]] = {}
    physics: dict[str, dict[str, float]] = {}
    for name, ch in updates.items():
        if isinstance(ch, PhysicsChannel):
            physics[name] = ch.scaled_params()
        elif ch.table_kind == "curve":
            curves[name] = {"gain": ch.gain, "offset_n": ch.offset_n}
        else:
            as_curve = replace(ch, table_kind="curve")
            text = replace_table(text, ch.table_kind, name, "curve", as_curve.table())
    try:
        if curves:
            text = set_table_values(text, "curve", curves)
        if physics:
            text = set_table_values(text, "channel", physics)
    except KeyError as exc:
        raise UpdateError(f"no table of channel {exc.args[0]!r} to update") from None
    return text


def write_updated(path: Path, out_path: Path, updates: Mapping[str, Calibrated]) -> None:
    """Write ``path`` with the updated sensitivities to ``out_path`` (may be ``path``), atomically;
    the rewrite must read back, with the gateway's checks, to the updated channels."""
    try:  # a regular file, never a FIFO waited on
        text = read_text_file(path, "calibration file").lstrip("\ufeff")
    except ConfigError as exc:
        raise UpdateError(str(exc)) from None
    new = rewrite_sensitivity(text, updates)
    tomllib.loads(new)
    with tempfile.TemporaryDirectory(prefix="tactile-update-") as folder:
        check = Path(folder) / path.name
        check.write_text(new, encoding="utf-8")
        reread = load_channels(check)
    for name, ch in updates.items():
        got = reread.get(name)
        same = (
            got is not None
            and math.isclose(got.gain, ch.gain, rel_tol=1e-12)
            and math.isclose(got.offset_n, ch.offset_n, rel_tol=1e-12, abs_tol=1e-15)
            if not isinstance(ch, PhysicsChannel)
            else isinstance(got, PhysicsChannel)
            and all(
                math.isclose(getattr(got.params, k), v, rel_tol=1e-12) for k, v in ch.scaled_params().items()
            )
        )
        if not same:
            raise UpdateError(f"{path}: could not rewrite channel {name}'s sensitivity")
    atomic_write_text(out_path, new)
