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
from .holds import MIN_HOLD_S, find_holds, hold_tolerance_n

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


# ----------------------------------------------------------------- residual structure
#: Outside a hold (``holds.find_holds``), a row whose force moves less than
#: max(STILL_ABS_N, STILL_REL x force) between its neighbours counts as holding too.
STILL_ABS_N = 0.01
STILL_REL = 0.01
#: Time-in-hold bins (s): the same spans as ``describe_gaps``.
HOLD_BINS_S = (
    (0.0, 5.0, "0-5 s into a hold"),
    (5.0, 60.0, "5-60 s into a hold"),
    (60.0, 600.0, "1-10 min into a hold"),
    (600.0, math.inf, "over 10 min into a hold"),
)
_FIFTHS = ("first", "second", "third", "fourth", "last")
ELAPSED_BINS = 5
#: Below this share of the residual's variance explained, the structure is called weak.
WEAK_STRUCTURE = 0.1


@dataclass(frozen=True)
class ResidualBin:
    """The final model's residuals on the rows of one bin of one axis."""

    label: str
    n_rows: int
    log_r_mean: float
    log_r_rms: float
    force_mean_n: float
    force_rms_n: float

    def as_json(self) -> dict[str, object]:
        return {
            "label": self.label,
            "n_rows": self.n_rows,
            "log_resistance_mean": _clean(self.log_r_mean),
            "log_resistance_rms": _clean(self.log_r_rms),
            "force_mean_n": _clean(self.force_mean_n),
            "force_rms_n": _clean(self.force_rms_n),
        }


@dataclass(frozen=True)
class ResidualAxis:
    """One axis of the record (force level, time in hold, ...), its bins, and how much of the
    residual's variance the bins' means explain (the correlation ratio, eta squared: 0 when
    every bin has the same mean, 1 when the rows of a bin all share its mean)."""

    name: str
    words: str
    bins: tuple[ResidualBin, ...]
    explained_log_r: float
    explained_force: float

    @property
    def spread_log_r(self) -> float:
        """Largest minus smallest bin mean of the log residual."""
        means = [b.log_r_mean for b in self.bins if math.isfinite(b.log_r_mean)]
        return max(means) - min(means) if means else math.nan

    def as_json(self) -> dict[str, object]:
        return {
            "axis": self.name,
            "words": self.words,
            "explained_share_log_resistance": _clean(self.explained_log_r),
            "explained_share_force": _clean(self.explained_force),
            "bins": [b.as_json() for b in self.bins],
        }


@dataclass(frozen=True)
class ResidualStructure:
    """The final model's residuals (log-R and force) binned along the record's axes."""

    axes: tuple[ResidualAxis, ...]
    skipped: tuple[str, ...]
    n_rows: int

    def most_varying(self, force: bool = False) -> ResidualAxis | None:
        """The axis whose bins explain most of the log-R (``force``: the force) residual."""

        def share(a: ResidualAxis) -> float:
            v = a.explained_force if force else a.explained_log_r
            return v if math.isfinite(v) else -1.0

        usable = [a for a in self.axes if len(a.bins) > 1 and share(a) >= 0.0]
        return max(usable, key=share) if usable else None

    def sentence(self) -> str:
        """The axis along which the residual varies most, in words."""
        best = self.most_varying()
        if best is None:
            return "the residual has no structure along the record's axes (too few rows)"
        bins = [b for b in best.bins if math.isfinite(b.log_r_mean)]
        low = min(bins, key=lambda b: b.log_r_mean)
        high = max(bins, key=lambda b: b.log_r_mean)
        share = f"{100 * best.explained_log_r:.0f} % of its variance"
        if best.explained_log_r < WEAK_STRUCTURE:
            share = f"only {share}: most of it is scatter that none of these axes orders"
        words = (
            f"the log-R residual varies most with {best.words} ({share}): mean {low.log_r_mean:+.3f} "
            f"{low.label} against {high.log_r_mean:+.3f} {high.label} "
            f"(measured resistance {_pct(low.log_r_mean)} / {_pct(high.log_r_mean)} the model)"
        )
        by_force = self.most_varying(force=True)
        if by_force is not None:
            same = " too" if by_force.name == best.name else ""
            words += (
                f"; the force residual varies most with {by_force.words}{same} "
                f"({100 * by_force.explained_force:.0f} % of its variance)"
            )
        return words

    def as_json(self) -> dict[str, object]:
        best, by_force = self.most_varying(), self.most_varying(force=True)
        return {
            "rows": self.n_rows,
            "most_varying_axis": None if best is None else best.name,
            "most_varying_axis_force": None if by_force is None else by_force.name,
            "sentence": self.sentence(),
            "axes": [a.as_json() for a in self.axes],
            "skipped": list(self.skipped),
        }


def _clean(x: float) -> float | None:
    return None if not math.isfinite(x) else round(float(x), 6)


def _pct(log_mean: float) -> str:
    pct = 100.0 * math.expm1(log_mean)
    return f"{abs(pct):.1f} % {'above' if pct >= 0 else 'below'}"


def hold_segments(time_s: FloatArray, force_n: FloatArray, real_time: bool = True) -> list[tuple[int, int]]:
    """``[start, stop)`` row ranges where the reference force holds a level (``holds.find_holds``
    with its defaults); without real time, any run of three rows or more."""
    if force_n.size == 0:
        return []
    min_s = MIN_HOLD_S
    if not real_time:
        dt = np.diff(time_s)
        min_s = 2.0 * float(np.median(dt)) if dt.size else 0.0
    return [(h.start, h.stop) for h in find_holds(time_s, force_n, min_duration_s=min_s)]


def direction_bins(
    data: FitData, fit: FitResult, real_time: bool = True
) -> list[tuple[str, NDArray[np.bool_]]]:
    """The rows of the report's loading-direction table, one mask each: while loading, while
    holding (a hold of the reference force, or a step within the hold tolerance), while
    unloading; of the usable rows with a finite log-R residual. The residual plot counts and
    colours the same rows (``calibration_plots``)."""
    held = np.zeros(data.force_n.size, dtype=bool)
    for a, b in hold_segments(data.time_s, data.force_n, real_time):
        held[a:b] = True
    return _direction_masks(_direction(data.force_n, held), data.usable & np.isfinite(fit.log_residual))


def _direction_masks(d: FloatArray, rows: NDArray[np.bool_]) -> list[tuple[str, NDArray[np.bool_]]]:
    """``direction_bins`` from the direction of every row (+1, 0, -1) and the rows counted."""
    return [
        ("while loading", rows & (d > 0)),
        ("while holding", rows & (d == 0)),
        ("while unloading", rows & (d < 0)),
    ]


def _direction(force_n: FloatArray, held: NDArray[np.bool_]) -> FloatArray:
    """+1 loading, -1 unloading, 0 holding (a detected hold, or a central step within the
    hold tolerance)."""
    f = force_n
    if f.size < 2:
        return np.zeros(f.size)
    central = np.empty(f.size)
    central[1:-1] = f[2:] - f[:-2]
    central[0], central[-1] = f[1] - f[0], f[-1] - f[-2]
    tol = np.maximum(STILL_ABS_N, STILL_REL * np.abs(f))
    d = np.where(np.abs(central) <= tol, 0.0, np.sign(central))
    return np.asarray(np.where(held, 0.0, d))


def parse_runs(metadata: dict[str, str] | None) -> list[float] | None:
    """The run start times of a ``# runs: 0, 1200, 2400`` metadata line (seconds), or None."""
    text = (metadata or {}).get("runs", "").strip()
    if not text:
        return None
    try:
        starts = sorted(float(x) for x in text.replace(";", ",").split(",") if x.strip())
    except ValueError:
        return None
    return starts if starts and all(math.isfinite(s) for s in starts) else None


def residual_structure(
    data: FitData,
    fit: FitResult,
    real_time: bool = True,
    metadata: dict[str, str] | None = None,
) -> ResidualStructure:
    """The final model's residuals, log-R and force (inverted with the tracked state minus the
    offset-corrected reference), on every usable row (fitted and held-out), binned against
    force level, time in hold, loading direction, loading rate (real time), temperature (when
    the record has it), load history (what came before each hold), measurement run (when its
    metadata lists the run starts, ``# runs:``) and position in the record; per bin the mean
    and RMS of both."""
    res = fit.log_residual
    if res.size != data.force_n.size:
        return ResidualStructure((), ("the fit has no per-row residuals",), 0)
    rows = data.usable & np.isfinite(res)
    n = int(np.count_nonzero(rows))
    skipped: list[str] = []
    if n < 20:
        return ResidualStructure((), ("fewer than 20 usable rows",), n)
    t, f = data.time_s, data.force_n
    with np.errstate(invalid="ignore"):
        fres = fit.force_inverted_n - (f + fit.force_offset_n)
    axes: list[ResidualAxis] = []

    def axis(name: str, words: str, bins: list[tuple[str, NDArray[np.bool_]]]) -> None:
        built = [_bin(label, m & rows, res, fres) for label, m in bins]
        built = [b for b in built if b.n_rows > 0]
        groups = [m & rows for _, m in bins]
        axes.append(
            ResidualAxis(
                name, words, tuple(built), _explained(res, rows, groups), _explained(fres, rows, groups)
            )
        )

    # force level: four log-spaced bins over the loaded rows
    pos = f[rows]
    edges = np.geomspace(max(float(pos.min()), 1e-3), float(pos.max()) * 1.0001, 5)
    axis(
        "force",
        "force level",
        [(f"at {edges[i]:.2g}-{edges[i + 1]:.2g} N", (f >= edges[i]) & (f < edges[i + 1])) for i in range(4)],
    )
    # time in hold (holds of the reference force)
    segments = hold_segments(t, f, real_time)
    held = np.zeros(f.size, dtype=bool)
    since = np.full(f.size, math.nan)
    for a, b in segments:
        held[a:b] = True
        since[a:b] = t[a:b] - t[a]
    if real_time:
        bins = [("while the force moves (not in a hold)", ~held)]
        bins += [(words, held & (since >= lo) & (since < hi)) for lo, hi, words in HOLD_BINS_S]
        axis("time_in_hold", "time in hold", bins)
    else:
        skipped.append("time in hold and loading rate: the record has no real time")
    if segments:
        axis("load_history", "load history (the load before a hold)", _history_bins(f, segments))
    else:
        skipped.append("load history: the record has no hold of its reference force")
    # loading direction
    d = _direction(f, held)
    axis("direction", "loading direction", _direction_masks(d, rows))
    # loading rate (signed dF/dt), split at the median speed of the moving rows
    if real_time and t.size > 2 and float(np.ptp(t)) > 0:
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = np.gradient(f, t)
        moving = rows & (d != 0) & np.isfinite(rate)
        if np.count_nonzero(moving) >= 10:
            mid = float(np.median(np.abs(rate[moving])))
            axis(
                "rate",
                "loading rate",
                [
                    (f"unloading faster than {mid:.2g} N/s", (d < 0) & (rate <= -mid)),
                    (f"unloading slower than {mid:.2g} N/s", (d < 0) & (rate > -mid)),
                    ("while holding", d == 0),
                    (f"loading slower than {mid:.2g} N/s", (d > 0) & (rate < mid)),
                    (f"loading faster than {mid:.2g} N/s", (d > 0) & (rate >= mid)),
                ],
            )
        else:
            skipped.append("loading rate: fewer than 10 rows with the force moving")
    # temperature: four equal-count bins
    if data.temperature_c is not None:
        temp = data.temperature_c
        ok = rows & np.isfinite(temp)
        if ok.any() and float(np.ptp(temp[ok])) >= 0.2:
            q = np.unique(np.percentile(temp[ok], [0, 25, 50, 75, 100]))
            q[-1] += 1e-9
            axis(
                "temperature",
                "temperature",
                [
                    (f"at {q[i]:.1f}-{q[i + 1]:.1f} °C", (temp >= q[i]) & (temp < q[i + 1]))
                    for i in range(q.size - 1)
                ],
            )
        else:
            skipped.append("temperature: the record's temperature varies by less than 0.2 K")
    else:
        skipped.append("temperature: the record has no temperature column")
    # measurement run, from the metadata's run start times
    starts = parse_runs(metadata)
    if starts is None:
        skipped.append("measurement run: the record's metadata has no '# runs:' line of start times")
    else:
        run = np.searchsorted(np.asarray(starts), t, side="right") - 1
        bins = [(f"in run {i + 1} (from {s:g} s)", run == i) for i, s in enumerate(starts)]
        if np.any(run < 0):
            bins.insert(0, (f"before the first run's start ({starts[0]:g} s)", run < 0))
        axis("run", "measurement run", bins)
    # position in the record: equal spans of its time
    span = float(t[-1] - t[0]) if t.size else 0.0
    if span > 0:
        cut = np.minimum(((t - t[0]) / span * ELAPSED_BINS).astype(np.int64), ELAPSED_BINS - 1)
        fifths = []
        for i, name in enumerate(_FIFTHS):
            lo, hi = t[0] + i * span / ELAPSED_BINS, t[0] + (i + 1) * span / ELAPSED_BINS
            when = f"{lo:.0f}-{hi:.0f} s" if real_time else f"record time {lo:.0f}-{hi:.0f}"
            fifths.append((f"in the {name} fifth of the record ({when})", cut == i))
        axis("elapsed", "time since the record's start", fifths)
    return ResidualStructure(tuple(axes), tuple(skipped), n)


def _history_bins(
    force_n: FloatArray, segments: list[tuple[int, int]]
) -> list[tuple[str, NDArray[np.bool_]]]:
    """The rows of every hold by what came before it: right after a higher load (the reference
    rose more than twice the hold tolerance above the hold's level since the previous hold
    began, as ``holds.hold_drifts`` groups them), after a lower load or rest, or at the
    record's very start (what came before is not in the record)."""
    tol = hold_tolerance_n(force_n)
    higher = np.zeros(force_n.size, dtype=bool)
    lower = np.zeros(force_n.size, dtype=bool)
    start = np.zeros(force_n.size, dtype=bool)
    previous = 0
    for a, b in segments:
        before = force_n[previous:a]
        if a == 0:
            start[a:b] = True
        elif float(np.max(before)) > float(np.mean(force_n[a:b])) + 2.0 * tol:
            higher[a:b] = True
        else:
            lower[a:b] = True
        previous = a
    return [
        ("in the hold the record starts in (what came before is unknown)", start),
        ("in a hold right after a higher load", higher),
        ("in a hold after a lower load or rest", lower),
    ]


def _bin(label: str, m: NDArray[np.bool_], res: FloatArray, fres: FloatArray) -> ResidualBin:
    r = res[m]
    fr = fres[m]
    fr = fr[np.isfinite(fr)]

    def stats(x: FloatArray) -> tuple[float, float]:
        if not x.size:
            return math.nan, math.nan
        return float(np.mean(x)), float(np.sqrt(np.mean(x * x)))

    lm, lr = stats(r)
    fm, frms = stats(fr)
    return ResidualBin(label, int(r.size), lm, lr, fm, frms)


def _explained(values: FloatArray, rows: NDArray[np.bool_], groups: list[NDArray[np.bool_]]) -> float:
    """eta squared: the between-bin share of the variance of ``values`` on ``rows``."""
    ok = rows & np.isfinite(values)
    x = values[ok]
    if x.size < 2:
        return math.nan
    total = float(np.sum((x - x.mean()) ** 2))
    if total <= 0:
        return 0.0
    between = 0.0
    for g in groups:
        y = values[g & ok]
        if y.size:
            between += y.size * (float(y.mean()) - float(x.mean())) ** 2
    return between / total
