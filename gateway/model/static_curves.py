"""Static calibration curves: the one owner of each form that maps resistance to force.

A static curve maps the measured resistance R to the force it means with no history, the
*apparent* force x (N). Every form lives here once, with its fit, its forward and inverse
evaluation and its table (lmfit keeps ``dumps``/``loads`` beside the model):

* ``PowerLawCurve``: the FSR datasheet form, conductance G = k F^n (k in S/N^n), so
  x = (G / k)^(1/n);
* ``LineCurve``: the paper's conductance line G = m F + c (eq. 18), x = (G - c) / m, fitted
  in conductance (the paper's way, ``fit_conductance``) or in force (``fit_force``);
* ``LookupCurve``: a monotone table, x by linear interpolation in ln R between knots
  (resistance increasing, force non-increasing), extended beyond its ends along its end
  segments (``KnotTable``), fitted through the medians of equal-count bins made monotone by
  pooling adjacent violators (``fit``);
* ``CountsLookupCurve``: a monotone table given in ADC counts (a vendor's table), x by linear
  interpolation in the exact code of the device's front end between knots: a table is read
  in the domain it was given in.

Each curve reports its *zero-conductance force* ``force_at_zero_conductance_n``: what it reads
for a sensor whose conductance tends to 0 S (nearly open). A line with c < 0 reads -c/m > 0
there, a phantom force at rest; ``calibrated.CurveChannel`` reads no contact below its range
on such a curve. Numpy and scipy only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .frontend_base import FrontEnd

__all__ = [
    "CURVE_KINDS",
    "LOOKUP_KNOTS",
    "CountsLookupCurve",
    "CurveError",
    "KnotTable",
    "LineCurve",
    "LookupCurve",
    "PowerLawCurve",
    "StaticCurve",
    "curve_body_from_table",
    "finite_value",
    "number_list",
    "positive_value",
]

FloatArray = NDArray[np.float64]

CURVE_KINDS = ("power_law", "line", "lookup")
#: The bins of a fitted lookup (at most; fewer on a short record).
LOOKUP_KNOTS = 24


class CurveError(ValueError):
    """A calibration table's value outside its allowed range; ``key`` names the field."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


def finite_value(key: str, value: object, unit: str) -> float:
    """``value`` as a float, or ``CurveError`` naming ``key`` if it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CurveError(key, f"{value!r} is out of range; allowed: a finite number ({unit})")
    return float(value)


def positive_value(key: str, value: object, unit: str) -> float:
    """``value`` as a float > 0, or ``CurveError`` naming ``key``."""
    v = finite_value(key, value, unit)
    if not v > 0.0:
        raise CurveError(key, f"{v!r} is out of range; allowed: (0, inf) {unit}")
    return v


def number_list(key: str, value: object) -> tuple[float, ...]:
    """A TOML array of numbers as a tuple, or ``CurveError`` naming ``key``."""
    if not isinstance(value, list | tuple):
        raise CurveError(key, f"expected an array of numbers, got {value!r}")
    return tuple(finite_value(f"{key}[{i}]", v, "") for i, v in enumerate(value))


def conductance_s(resistance_ohm: ArrayLike) -> FloatArray:
    """1/R in S; an open sensor (+inf) has 0 S; NaN, zero and negative R give NaN."""
    r = np.asarray(resistance_ohm, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.where(r > 0.0, 1.0 / np.where(r > 0.0, r, 1.0), np.nan))


@dataclass(frozen=True)
class PowerLawCurve:
    """G = k F^n: ``coefficient_s`` k (S at 1 N), ``exponent`` n (> 0)."""

    coefficient_s: float
    exponent: float
    kind: str = field(default="power_law", init=False)

    def __post_init__(self) -> None:
        positive_value("coefficient_s", self.coefficient_s, "S/N^n")
        e = finite_value("exponent", self.exponent, "")
        if not 0.0 < e <= 10.0:
            raise CurveError("exponent", f"{e!r} is out of range; allowed: (0, 10]")

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """x = (G / k)^(1/n) in N (0 N for an open sensor)."""
        g = conductance_s(resistance_ohm)
        with np.errstate(invalid="ignore", over="ignore"):
            return np.asarray((g / self.coefficient_s) ** (1.0 / self.exponent))

    def resistance(self, force_n: ArrayLike) -> FloatArray:
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        with np.errstate(divide="ignore"):
            return np.asarray(1.0 / (self.coefficient_s * f**self.exponent))

    @property
    def force_at_zero_conductance_n(self) -> float:
        return 0.0

    def table(self) -> dict[str, float]:
        return {"coefficient_s": float(self.coefficient_s), "exponent": float(self.exponent)}

    @property
    def n_parameters(self) -> int:
        return 2


@dataclass(frozen=True)
class LineCurve:
    """The paper's conductance line G = m F + c: ``slope_s_per_n`` m (> 0), ``intercept_s`` c."""

    slope_s_per_n: float
    intercept_s: float
    kind: str = field(default="line", init=False)

    def __post_init__(self) -> None:
        positive_value("slope_s_per_n", self.slope_s_per_n, "S/N")
        finite_value("intercept_s", self.intercept_s, "S")

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """x = (G - c) / m in N (an open sensor, 0 S, reads -c/m)."""
        return np.asarray((conductance_s(resistance_ohm) - self.intercept_s) / self.slope_s_per_n)

    def conductance(self, force_n: ArrayLike) -> FloatArray:
        """G = m F + c in S."""
        return np.asarray(self.slope_s_per_n * np.asarray(force_n, dtype=np.float64) + self.intercept_s)

    def resistance(self, force_n: ArrayLike) -> FloatArray:
        g = self.conductance(force_n)
        with np.errstate(divide="ignore"):
            return np.asarray(np.where(g > 0.0, 1.0 / np.where(g > 0.0, g, 1.0), np.inf))

    @property
    def force_at_zero_conductance_n(self) -> float:
        """-c/m (N): what a nearly open sensor reads."""
        return -self.intercept_s / self.slope_s_per_n

    def table(self) -> dict[str, float]:
        return {"slope_s_per_n": float(self.slope_s_per_n), "intercept_s": float(self.intercept_s)}

    @property
    def n_parameters(self) -> int:
        return 2

    @classmethod
    def fit_conductance(cls, force_n: ArrayLike, resistance_ohm: ArrayLike) -> LineCurve:
        """The paper's least-squares line through (F, 1/R) over finite, positive resistances."""
        f = np.asarray(force_n, dtype=np.float64).ravel()
        r = np.asarray(resistance_ohm, dtype=np.float64).ravel()
        use = np.isfinite(f) & np.isfinite(r) & (r > 0.0)
        if np.count_nonzero(use) < 2 or np.ptp(f[use]) == 0.0:
            raise ValueError("a conductance line needs at least two distinct forces")
        slope, intercept = np.polyfit(f[use], 1.0 / r[use], 1)
        if not slope > 0.0:
            raise ValueError("the conductance does not rise with force on these rows")
        return cls(float(slope), float(intercept))

    @classmethod
    def fit_force(cls, force_n: FloatArray, resistance_ohm: FloatArray) -> LineCurve:
        """Least squares in force, F = alpha G + beta, over rows with F > 0 and R > 0."""
        f, r = _loaded_rows(force_n, resistance_ohm)
        g = 1.0 / r
        g0 = float(np.median(g))
        alpha, beta = np.polyfit(g / g0, f, 1)
        if not alpha > 0.0 or not math.isfinite(alpha):
            raise ValueError("the conductance does not rise with force on these rows")
        return cls(float(g0 / alpha), float(-beta * g0 / alpha))


@dataclass(frozen=True)
class LookupCurve:
    """x against ln R through knots ``(resistance_ohm[i], force_n[i])``: resistance strictly
    increasing, force non-increasing; beyond the ends along the end segments (``KnotTable``)."""

    resistance_ohm: tuple[float, ...]
    force_n: tuple[float, ...]
    kind: str = field(default="lookup", init=False)

    def __post_init__(self) -> None:
        for key, values in (("resistance_ohm", self.resistance_ohm), ("force_n", self.force_n)):
            if not isinstance(values, tuple) or len(values) < 2:
                raise CurveError(key, f"expected at least 2 points, got {values!r}")
        if len(self.resistance_ohm) != len(self.force_n):
            raise CurveError(
                "force_n",
                f"{len(self.force_n)} forces for {len(self.resistance_ohm)} resistances; one per resistance",
            )
        r = [finite_value(f"resistance_ohm[{i}]", v, "ohm") for i, v in enumerate(self.resistance_ohm)]
        f = [finite_value(f"force_n[{i}]", v, "N") for i, v in enumerate(self.force_n)]
        for i in range(len(r)):
            if not r[i] > 0.0:
                raise CurveError(f"resistance_ohm[{i}]", f"{r[i]!r} is out of range; allowed: (0, inf) ohm")
            if i and not r[i] > r[i - 1]:
                raise CurveError(
                    f"resistance_ohm[{i}]",
                    f"{r[i]!r} after {r[i - 1]!r}: resistances must be strictly increasing",
                )
            if i and f[i] > f[i - 1]:
                raise CurveError(
                    f"force_n[{i}]",
                    f"{f[i]!r} after {f[i - 1]!r}: forces must not increase with resistance (non-increasing)",
                )
        if not f[0] > f[-1]:
            raise CurveError("force_n", f"all forces are {f[0]!r}: the lookup needs a force range")

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """x by the table (``KnotTable``): an open sensor reads -inf N (no contact)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(r > 0.0, np.log(np.where(r > 0.0, r, 1.0)), np.nan).reshape(-1)
        table = KnotTable([(self.knot_abscissa(), self.force_n)])
        return table.force(x, np.zeros(x.size, dtype=np.intp)).reshape(r.shape)

    def knot_abscissa(self) -> tuple[float, ...]:
        """The knots where the table is linear: ln R (increasing; numpy's log, as ever)."""
        return tuple(np.log(np.asarray(self.resistance_ohm, dtype=np.float64)).tolist())

    def abscissa(self, resistance_ohm: FloatArray) -> FloatArray:
        """ln R of readings (ohm; NaN where R is not > 0)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(np.where(r > 0.0, np.log(np.where(r > 0.0, r, 1.0)), np.nan))

    def resistance_at(self, abscissa: float) -> float:
        """The resistance (ohm) at a point of the abscissa (ln R)."""
        return math.exp(abscissa)

    def resistance(self, force_n: ArrayLike) -> FloatArray:
        f = np.asarray(force_n, dtype=np.float64)
        lr = np.log(np.asarray(self.resistance_ohm))[::-1]
        fk = np.asarray(self.force_n)[::-1]
        return np.asarray(np.exp(np.interp(f, fk, lr)))

    @property
    def force_at_zero_conductance_n(self) -> float:
        return -math.inf

    def table(self) -> dict[str, list[float]]:
        return {
            "resistance_ohm": [float(v) for v in self.resistance_ohm],
            "force_n": [float(v) for v in self.force_n],
        }

    @property
    def n_parameters(self) -> int:
        return 2 * len(self.force_n)

    @classmethod
    def fit(cls, force_n: ArrayLike, resistance_ohm: ArrayLike, knots: int = LOOKUP_KNOTS) -> LookupCurve:
        """The medians of ``knots`` equal-count bins of the rows in ln R, made non-increasing
        by pooling adjacent violators; knots closer than 1e-9 in ln R are merged."""
        f = np.asarray(force_n, dtype=np.float64).ravel()
        r = np.asarray(resistance_ohm, dtype=np.float64).ravel()
        ok = np.isfinite(f) & np.isfinite(r) & (r > 0)
        if np.count_nonzero(ok) < 4:
            raise ValueError("a lookup needs at least four rows with a finite resistance")
        lr, f = np.log(r[ok]), f[ok]
        order = np.argsort(lr, kind="stable")
        lr, f = lr[order], f[order]
        groups = np.array_split(np.arange(lr.size), min(knots, lr.size // 2))
        xs = [float(np.median(lr[g])) for g in groups]
        ys = [float(np.median(f[g])) for g in groups]
        ws = [float(g.size) for g in groups]
        bx, by = _pav_non_increasing(xs, ys, ws)
        x, y = np.asarray(bx), np.asarray(by)
        keep = np.concatenate([[True], np.diff(x) > 1e-9])
        x, y = x[keep], y[keep]
        if x.size < 2 or not y[0] > y[-1]:
            raise ValueError("the lookup found no force range on these rows")
        return cls(tuple(float(math.exp(v)) for v in x), tuple(float(v) for v in y))


@dataclass(frozen=True)
class CountsLookupCurve:
    """x against the ADC code through knots ``(counts[i], force_n[i])`` given in counts (a
    vendor's table), linear in the code between them, and beyond the ends along the end
    segments (``KnotTable``). A reading R (ohm, or r / R_ref for a ratio front end) is read at
    its exact, unrounded code ``x(R) = offset + V(R) / V_ref FS`` of ``front_end``; counts
    strictly increasing within [0, FS], forces monotone the way the front end's counts go with
    load (rising counts: non-decreasing forces)."""

    counts: tuple[float, ...]
    force_n: tuple[float, ...]
    front_end: FrontEnd
    kind: str = field(default="lookup", init=False)

    def __post_init__(self) -> None:
        for key, values in (("counts", self.counts), ("force_n", self.force_n)):
            if not isinstance(values, tuple) or len(values) < 2:
                raise CurveError(key, f"expected at least 2 points, got {values!r}")
        if len(self.counts) != len(self.force_n):
            raise CurveError(
                "force_n", f"{len(self.force_n)} forces for {len(self.counts)} counts; one per count"
            )
        c = [finite_value(f"counts[{i}]", v, "counts") for i, v in enumerate(self.counts)]
        f = [finite_value(f"force_n[{i}]", v, "N") for i, v in enumerate(self.force_n)]
        fs = self.front_end.full_scale
        rising = self.rises_with_load
        for i in range(len(c)):
            if not 0.0 <= c[i] <= fs:
                raise CurveError(f"counts[{i}]", f"{c[i]!r} is out of range; allowed: [0, {fs}] counts")
            if i and not c[i] > c[i - 1]:
                raise CurveError(
                    f"counts[{i}]", f"{c[i]!r} after {c[i - 1]!r}: counts must be strictly increasing"
                )
            if i and (f[i] < f[i - 1] if rising else f[i] > f[i - 1]):
                way = "rise" if rising else "fall"
                must = "not decrease" if rising else "not increase"
                raise CurveError(
                    f"force_n[{i}]",
                    f"{f[i]!r} after {f[i - 1]!r}: this front end's counts {way} with load, so forces "
                    f"must {must} with counts",
                )
        if f[0] == f[-1]:
            raise CurveError("force_n", f"all forces are {f[0]!r}: the lookup needs a force range")

    @property
    def rises_with_load(self) -> bool:
        """Whether the code rises as the resistance falls (under load): the open sensor's code
        lies below the shorted one's."""
        x_open, x_short = self.front_end._code_edges()
        return bool(x_open < x_short)

    @property
    def _sign(self) -> float:
        """The abscissa is sign x code, so that it increases with the resistance."""
        return -1.0 if self.rises_with_load else 1.0

    def knot_abscissa(self) -> tuple[float, ...]:
        """The knots where the table is linear, as signed codes increasing with R."""
        u = [self._sign * v for v in self.counts]
        return tuple(u if u[0] < u[-1] else u[::-1])

    def _knot_forces(self) -> tuple[float, ...]:
        return self.force_n if self._sign > 0.0 else self.force_n[::-1]

    def abscissa(self, resistance_ohm: FloatArray) -> FloatArray:
        """The signed exact code of readings (NaN where R is NaN or negative)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        fe = self.front_end
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            x = fe.output_voltage(r) / fe.reference_v * fe.full_scale + fe.adc_offset_counts
        return np.asarray(self._sign * x)

    def resistance_at(self, abscissa: float) -> float:
        """The resistance at a signed code (the front end's inverse; +inf at the open code)."""
        r, _ = self.front_end.resistance(np.array([self._sign * abscissa]))
        return float(r[0])

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """x by the table at the readings' exact codes."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        u = self.abscissa(r).reshape(-1)
        table = KnotTable([(self.knot_abscissa(), self._knot_forces())])
        return table.force(u, np.zeros(u.size, dtype=np.intp)).reshape(r.shape)

    def resistance(self, force_n: ArrayLike) -> FloatArray:
        f = np.asarray(force_n, dtype=np.float64)
        u = np.interp(f, np.asarray(self._knot_forces())[::-1], np.asarray(self.knot_abscissa())[::-1])
        return np.asarray(np.vectorize(self.resistance_at, otypes=[np.float64])(u))

    @property
    def force_at_zero_conductance_n(self) -> float:
        """What the table reads at the open sensor's code (N)."""
        return float(self.force(np.array([math.inf]))[0])

    def table(self) -> dict[str, list[float]]:
        return {"counts": [float(v) for v in self.counts], "force_n": [float(v) for v in self.force_n]}

    @property
    def n_parameters(self) -> int:
        return 2 * len(self.force_n)


def _pav_non_increasing(xs: list[float], ys: list[float], ws: list[float]) -> tuple[list[float], list[float]]:
    """Pool adjacent violators so that y does not increase with x (x pooled the same way)."""
    blocks: list[list[float]] = []  # [sum w x, sum w y, sum w]
    for x, y, w in zip(xs, ys, ws, strict=True):
        blocks.append([w * x, w * y, w])
        while len(blocks) > 1 and blocks[-1][1] / blocks[-1][2] > blocks[-2][1] / blocks[-2][2]:
            last = blocks.pop()
            for k in range(3):
                blocks[-1][k] += last[k]
    return [b[0] / b[2] for b in blocks], [b[1] / b[2] for b in blocks]


def _loaded_rows(force_n: ArrayLike, resistance_ohm: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The rows with a finite F > 0 and a finite R > 0; ``ValueError`` without two forces."""
    f = np.asarray(force_n, dtype=np.float64).ravel()
    r = np.asarray(resistance_ohm, dtype=np.float64).ravel()
    ok = np.isfinite(f) & np.isfinite(r) & (r > 0) & (f > 0)
    if np.count_nonzero(ok) < 4 or np.ptp(f[ok]) <= 0.0:
        raise ValueError("a curve needs at least four rows at two or more distinct forces")
    return f[ok], r[ok]


StaticCurve = PowerLawCurve | LineCurve | LookupCurve | CountsLookupCurve

#: Each curve kind's own keys in a calibration table.
CURVE_KEYS: dict[str, tuple[str, ...]] = {
    "power_law": ("coefficient_s", "exponent"),
    "line": ("slope_s_per_n", "intercept_s"),
    "lookup": ("resistance_ohm", "force_n"),
}


def curve_body_from_table(
    kind: str, data: Mapping[str, object], front_end: FrontEnd | None = None
) -> StaticCurve:
    """The static curve of ``kind`` from a calibration table's keys (``CURVE_KEYS[kind]``; a
    lookup in ``counts`` instead of ``resistance_ohm`` is read through ``front_end``, the
    device's ADC front end); ``CurveError`` names a missing or bad key."""
    if kind == "lookup" and "counts" in data:
        if "resistance_ohm" in data:
            raise CurveError("counts", "give resistance_ohm or counts, not both")
        if front_end is None:
            raise CurveError(
                "counts",
                'a table in ADC counts needs the device\'s ADC front end (encoding = "adc"); give '
                "resistance_ohm",
            )
        if "force_n" not in data:
            raise CurveError("force_n", "required key is missing (lookup tables need counts and force_n)")
        counts, forces = (number_list(k, data[k]) for k in ("counts", "force_n"))
        return CountsLookupCurve(counts, forces, front_end)
    keys = CURVE_KEYS[kind]
    for key in keys:
        if key not in data:
            raise CurveError(key, f"required key is missing ({kind} tables need {' and '.join(keys)})")
    if kind == "lookup":
        r_knots, f_knots = (number_list(k, data[k]) for k in keys)
        return LookupCurve(r_knots, f_knots)
    a, b = (finite_value(k, data[k], "") for k in keys)
    return PowerLawCurve(a, b) if kind == "power_law" else LineCurve(a, b)


class KnotTable:
    """Lookup tables, one per row, as padded arrays: force against each table's abscissa (ln R,
    or a counts table's signed code: ``knot_abscissa``), increasing with the resistance, through
    its knots (force non-increasing), linear between them and, beyond
    them, along the end segments. An end segment runs from the end knot to the nearest knot
    of another force: a flat end (a bench's holds give bins of equal median force) extended
    flat would read the end force at any resistance beyond it, a phantom force at rest. An
    open sensor (ln R = +inf) reads -inf N (no contact), a NaN stays NaN."""

    def __init__(self, tables: Sequence[tuple[Sequence[float], Sequence[float]]]) -> None:
        width = max((len(f) for _, f in tables), default=2)
        n = len(tables)
        self.log_r = np.full((n, width), np.inf)
        self.knot_f = np.zeros((n, width))
        self.last = np.array([max(len(f) - 1, 1) for _, f in tables], dtype=np.intp)
        low_other, high_other = np.ones(n, dtype=np.intp), np.zeros(n, dtype=np.intp)
        for i, (r, f) in enumerate(tables):
            self.log_r[i, : len(f)] = np.asarray(r, dtype=np.float64)
            self.knot_f[i] = f[-1]
            self.knot_f[i, : len(f)] = f
            fa = np.asarray(f, dtype=np.float64)
            low_other[i] = int(np.flatnonzero(fa > fa[-1])[-1])
            high_other[i] = int(np.flatnonzero(fa < fa[0])[0])
        rows = np.arange(n)
        #: the highest and lowest force of each table (N)
        self.high_n = self.knot_f[:, 0].copy()
        self.low_n = self.knot_f[rows, self.last].copy()
        self.low_end = self._end_line(rows, self.last, low_other)
        self.high_end = self._end_line(rows, np.zeros(n, dtype=np.intp), high_other)

    def _end_line(
        self, rows: NDArray[np.intp], end: NDArray[np.intp], other: NDArray[np.intp]
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Per table: the end knot's ln R and force, and the slope dF/d(ln R) (< 0) of the
        segment from it to the knot ``other``."""
        x0, f0 = self.log_r[rows, end], self.knot_f[rows, end]
        x1, f1 = self.log_r[rows, other], self.knot_f[rows, other]
        return x0, f0, (f1 - f0) / (x1 - x0)

    def force(self, log_r: FloatArray, rows: NDArray[np.intp] | None = None) -> FloatArray:
        """The force (N) at ln R = ``log_r[k]`` on table ``rows[k]`` (default: table k)."""
        x = np.asarray(log_r, dtype=np.float64)
        rows = np.arange(x.size) if rows is None else rows
        with np.errstate(invalid="ignore", over="ignore"):
            log_r_k = self.log_r[rows]
            above = np.count_nonzero(log_r_k <= x[:, None], axis=1)  # knots at or below x
            j = np.clip(above, 1, self.last[rows])
            x0, x1 = self.log_r[rows, j - 1], self.log_r[rows, j]
            f0, f1 = self.knot_f[rows, j - 1], self.knot_f[rows, j]
            t = np.clip((x - x0) / (x1 - x0), 0.0, 1.0)
            inside = f0 * (1.0 - t) + f1 * t  # exactly a knot's force at t = 0 and 1
            (lx, lf, ls), (hx, hf, hs) = (
                tuple(v[rows] for v in end) for end in (self.low_end, self.high_end)
            )
            return np.asarray(
                np.where(x > lx, lf + ls * (x - lx), np.where(x < hx, hf + hs * (x - hx), inside))
            )
