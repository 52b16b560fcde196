"""Static curves with drift correction on top: any calibration curve, tracked like the model.

A channel read through a *curve* separates the sensor's static curve from its dynamics:

* the static curve maps the measured resistance R to the force it would mean with no
  history, the *apparent* force x (N). Kinds (``CURVE_KINDS``):

  - ``power_law``: the FSR datasheet form, conductance G = k F^n (k in S/N^n), so
    x = (G / k)^(1/n);
  - ``line``: the paper's conductance line G = m F + c (eq. 18), x = (G - c) / m;
  - ``lookup``: the vendor's table, x by linear interpolation in ln R between knots
    (resistance increasing, force non-increasing), extended linearly beyond its ends.

  Every kind carries a sensitivity (``gain``, ``offset_n``): the curve reads the conductance
  ``gain`` x G and adds ``offset_n``, so x = curve(R / gain) + offset_n. A re-calibration from
  a few known loads refits only these two (``calibrate --update``).
* the dynamics (``Drift``) move the apparent force away from the applied force F:

  x_k = F_k (1 + beta s_k) + z1_k + z2_k,

  - z_i, a Kelvin element of the creep chain: over an interval dt with the previous force
    F_{k-1} held, z_i <- e z_i + (1 - e) a_i F_{k-1}, e = exp(-dt / tau_i). Under a held load
    z_i rises to a_i F with time constant tau_i (the reading creeps up); after unloading it
    decays with the same tau_i (recovery: a low load after a high one reads high at first).
    One element (``creep``) or two (``creep2``, a slower one);
  - s, rate-independent hysteresis (Preisach-style): play operators of widths c_j w (N,
    c_j in ``PLAY_SHARES``) on the apparent force, p_j <- clip(p_j, x - c_j w, x + c_j w), and
    s = mean_j (p_j - x) / (c_j w) in [-1, 1]: -1 while loading, +1 while unloading, so
    loading reads (1 - beta) F and unloading (1 + beta) F at the same force; after a small
    reversal only the narrow plays turn, so s moves gradually, as a Preisach loop does.
    The play follows the reading x, not the estimated force: a play on the estimate would
    feed back (a dip in F turns s towards unloading, which lowers F further) and, with
    beta F > w, flip between branches on noise.

Tracking inverts that exactly, sample by sample: relax the Kelvin elements over dt with the
previous force held, move the play with x_k, F_k = (x_k - z1 - z2) / (1 + beta s_k), then
record F_k as the held force. The Kelvin convention is ``SensorModel.track``'s, so a record
and the live runtime give the same forces. With no dynamics the force is x.

Forces outside the calibrated range [force_min_n, force_max_n] are still read (extrapolated
along the curve) and flagged ``extrapolated``; a force at or below 0 N reads 0 N no contact;
a NaN, zero or negative resistance is invalid (NaN). Numpy only, nothing else of ours but
the inversion's statuses.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .inversion import ForceStatus

__all__ = [
    "CURVE_KINDS",
    "DRIFT_FORMS",
    "DRIFT_KEYS",
    "CurveChannel",
    "CurveError",
    "CurveSet",
    "CurveState",
    "Drift",
    "LineCurve",
    "LookupCurve",
    "PowerLawCurve",
    "StaticCurve",
    "curve_from_table",
    "track_series",
]

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]
BoolArray = NDArray[np.bool_]

CURVE_KINDS = ("power_law", "line", "lookup")
#: The hysteresis plays' widths as shares of ``Drift.hysteresis_width_n``.
PLAY_SHARES = (0.25, 0.5, 1.0, 2.0)
#: The dynamics a curve can carry, by name: (creep elements, hysteresis).
DRIFT_FORMS: dict[str, tuple[int, bool]] = {
    "static": (0, False),
    "creep": (1, False),
    "creep2": (2, False),
    "hysteresis": (0, True),
    "creep+hysteresis": (1, True),
    "creep2+hysteresis": (2, True),
}

_OK, _NO_CONTACT, _SATURATED, _INVALID = (
    int(ForceStatus.OK),
    int(ForceStatus.NO_CONTACT),
    int(ForceStatus.SATURATED),
    int(ForceStatus.INVALID),
)


class CurveError(ValueError):
    """A curve table's value outside its allowed range; ``key`` names the offending field."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


def finite_value(key: str, value: object, unit: str) -> float:
    """``value`` as a float, or ``CurveError`` naming ``key`` if it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CurveError(key, f"{value!r} is out of range; allowed: a finite number ({unit})")
    return float(value)


def _positive(key: str, value: object, unit: str) -> float:
    v = finite_value(key, value, unit)
    if not v > 0.0:
        raise CurveError(key, f"{v!r} is out of range; allowed: (0, inf) {unit}")
    return v


def _conductance(resistance_ohm: FloatArray) -> FloatArray:
    """1/R in S; an open sensor (+inf) has 0 S; NaN, zero and negative R give NaN."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(resistance_ohm > 0.0, 1.0 / resistance_ohm, np.nan)


@dataclass(frozen=True)
class PowerLawCurve:
    """G = k F^n: ``coefficient_s`` k (S at 1 N), ``exponent`` n (> 0)."""

    coefficient_s: float
    exponent: float
    kind: str = field(default="power_law", init=False)

    def __post_init__(self) -> None:
        _positive("coefficient_s", self.coefficient_s, "S/N^n")
        e = finite_value("exponent", self.exponent, "")
        if not 0.0 < e <= 10.0:
            raise CurveError("exponent", f"{e!r} is out of range; allowed: (0, 10]")

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """x = (G / k)^(1/n) in N (0 N for an open sensor)."""
        g = _conductance(np.asarray(resistance_ohm, dtype=np.float64))
        with np.errstate(invalid="ignore", over="ignore"):
            return np.asarray((g / self.coefficient_s) ** (1.0 / self.exponent))

    def resistance(self, force_n: ArrayLike) -> FloatArray:
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        with np.errstate(divide="ignore"):
            return np.asarray(1.0 / (self.coefficient_s * f**self.exponent))

    def table(self) -> dict[str, float]:
        return {"coefficient_s": self.coefficient_s, "exponent": self.exponent}

    @property
    def n_parameters(self) -> int:
        return 2


@dataclass(frozen=True)
class LineCurve:
    """G = m F + c: ``slope_s_per_n`` m (> 0), ``intercept_s`` c."""

    slope_s_per_n: float
    intercept_s: float
    kind: str = field(default="line", init=False)

    def __post_init__(self) -> None:
        _positive("slope_s_per_n", self.slope_s_per_n, "S/N")
        finite_value("intercept_s", self.intercept_s, "S")

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """x = (G - c) / m in N (an open sensor reads -c/m)."""
        g = _conductance(np.asarray(resistance_ohm, dtype=np.float64))
        return np.asarray((g - self.intercept_s) / self.slope_s_per_n)

    def resistance(self, force_n: ArrayLike) -> FloatArray:
        g = self.slope_s_per_n * np.asarray(force_n, dtype=np.float64) + self.intercept_s
        with np.errstate(divide="ignore"):
            return np.asarray(np.where(g > 0.0, 1.0 / g, np.inf))

    def table(self) -> dict[str, float]:
        return {"slope_s_per_n": self.slope_s_per_n, "intercept_s": self.intercept_s}

    @property
    def n_parameters(self) -> int:
        return 2


@dataclass(frozen=True)
class LookupCurve:
    """x against ln R through knots ``(resistance_ohm[i], force_n[i])``: resistance strictly
    increasing, force non-increasing; linear beyond the ends along the end segments."""

    resistance_ohm: tuple[float, ...]
    force_n: tuple[float, ...]
    kind: str = field(default="lookup", init=False)

    def __post_init__(self) -> None:
        for key, values in (("resistance_ohm", self.resistance_ohm), ("force_n", self.force_n)):
            if not isinstance(values, tuple) or len(values) < 2:
                raise CurveError(key, f"expected at least 2 points, got {values!r}")
        if len(self.resistance_ohm) != len(self.force_n):
            raise CurveError(
                "force_n", f"{len(self.force_n)} forces for {len(self.resistance_ohm)} resistances"
            )
        r = [_positive(f"resistance_ohm[{i}]", v, "ohm") for i, v in enumerate(self.resistance_ohm)]
        f = [finite_value(f"force_n[{i}]", v, "N") for i, v in enumerate(self.force_n)]
        for i in range(1, len(r)):
            if not r[i] > r[i - 1]:
                raise CurveError(f"resistance_ohm[{i}]", f"{r[i]!r} after {r[i - 1]!r}: must increase")
            if f[i] > f[i - 1]:
                raise CurveError(f"force_n[{i}]", f"{f[i]!r} after {f[i - 1]!r}: must not increase")
        if not f[0] > f[-1]:
            raise CurveError("force_n", f"all forces are {f[0]!r}: the lookup needs a force range")

    def force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """x by the table (``KnotTable``): an open sensor reads -inf N (no contact)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(r > 0.0, np.log(np.where(r > 0.0, r, 1.0)), np.nan).reshape(-1)
        table = KnotTable([(self.resistance_ohm, self.force_n)])
        return table.force(x, np.zeros(x.size, dtype=np.intp)).reshape(r.shape)

    def resistance(self, force_n: ArrayLike) -> FloatArray:
        f = np.asarray(force_n, dtype=np.float64)
        lr = np.log(np.asarray(self.resistance_ohm))[::-1]
        fk = np.asarray(self.force_n)[::-1]
        return np.asarray(np.exp(np.interp(f, fk, lr)))

    def table(self) -> dict[str, list[float]]:
        return {"resistance_ohm": list(self.resistance_ohm), "force_n": list(self.force_n)}

    @property
    def n_parameters(self) -> int:
        return 2 * len(self.force_n)


StaticCurve = PowerLawCurve | LineCurve | LookupCurve


class KnotTable:
    """Lookup tables, one per row, as padded arrays: force against ln R through each table's
    knots (resistance increasing, force non-increasing), linear between them and, beyond
    them, along the end segments. An end segment runs from the end knot to the nearest knot
    of another force: a flat end (a bench's holds give bins of equal median force) extended
    flat would read the end force at any resistance beyond it, a phantom force at rest. An
    open sensor (ln R = +inf) reads -inf N (no contact), a NaN stays NaN. Shared by the
    curves and the runtime's stateless lookups (``conversion.ConversionSet``)."""

    def __init__(self, tables: Sequence[tuple[Sequence[float], Sequence[float]]]) -> None:
        width = max((len(f) for _, f in tables), default=2)
        n = len(tables)
        self.log_r = np.full((n, width), np.inf)
        self.knot_f = np.zeros((n, width))
        self.last = np.array([max(len(f) - 1, 1) for _, f in tables], dtype=np.intp)
        low_other, high_other = np.ones(n, dtype=np.intp), np.zeros(n, dtype=np.intp)
        for i, (r, f) in enumerate(tables):
            self.log_r[i, : len(f)] = np.log(np.asarray(r, dtype=np.float64))
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


@dataclass(frozen=True)
class Drift:
    """The dynamics on top of a static curve (module docstring); zero fractions switch them off.

    ``creep_fraction`` a1 and ``creep2_fraction`` a2 (dimensionless, the long-time share of
    the applied force each Kelvin element adds to the reading), their time constants
    ``creep_tau_s`` and ``creep2_tau_s`` (s); ``hysteresis_fraction`` beta (dimensionless) and
    the play's ``hysteresis_width_n`` w (N)."""

    creep_fraction: float = 0.0
    creep_tau_s: float = 10.0
    creep2_fraction: float = 0.0
    creep2_tau_s: float = 300.0
    hysteresis_fraction: float = 0.0
    hysteresis_width_n: float = 1.0

    def __post_init__(self) -> None:
        for name, lo, hi in (
            ("creep_fraction", -0.9, 5.0),
            ("creep2_fraction", -0.9, 5.0),
            ("hysteresis_fraction", -0.9, 0.9),
        ):
            v = finite_value(name, getattr(self, name), "")
            if not lo <= v <= hi:
                raise CurveError(name, f"{v!r} is out of range; allowed: [{lo}, {hi}]")
        for name in ("creep_tau_s", "creep2_tau_s"):
            _positive(name, getattr(self, name), "s")
        _positive("hysteresis_width_n", self.hysteresis_width_n, "N")

    @property
    def form(self) -> str:
        elements = 2 if self.creep2_fraction != 0.0 else 1 if self.creep_fraction != 0.0 else 0
        hyst = self.hysteresis_fraction != 0.0
        return next(k for k, v in DRIFT_FORMS.items() if v == (elements, hyst))

    @property
    def active(self) -> bool:
        return self.form != "static"

    @property
    def n_parameters(self) -> int:
        elements, hyst = DRIFT_FORMS[self.form]
        return 2 * elements + 2 * int(hyst)

    def table(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class CurveChannel:
    """One channel read through a curve: static curve, sensitivity, dynamics, calibrated range."""

    curve: StaticCurve
    drift: Drift = Drift()
    gain: float = 1.0
    offset_n: float = 0.0
    force_min_n: float = 0.0
    force_max_n: float = math.inf

    def __post_init__(self) -> None:
        _positive("gain", self.gain, "")
        finite_value("offset_n", self.offset_n, "N")
        low = self.force_min_n
        if isinstance(low, bool) or not isinstance(low, int | float) or math.isnan(low) or low < 0.0:
            raise CurveError("force_min_n", f"{low!r} is out of range; allowed: [0, inf) N")
        high = self.force_max_n
        if isinstance(high, bool) or not isinstance(high, int | float) or not high > low:
            raise CurveError(
                "force_max_n", f"{high!r} is out of range; allowed: (force_min_n = {low!r}, inf] N"
            )

    def static_force(self, resistance_ohm: ArrayLike) -> FloatArray:
        """The apparent force x = curve(R / gain) + offset_n (N), before any drift correction."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        x = self.curve.force(r / self.gain) + self.offset_n
        return np.asarray(np.where(np.isposinf(r), 0.0, x))  # open: no load

    def with_sensitivity(self, gain: float, offset_n: float) -> CurveChannel:
        return replace(self, gain=gain, offset_n=offset_n)

    @property
    def n_parameters(self) -> int:
        return self.curve.n_parameters + self.drift.n_parameters

    def describe(self) -> str:
        return f"{self.curve.kind} + {self.drift.form}"


@dataclass(frozen=True)
class CurveState:
    """Per-channel state of curve channels (arrays over the device's curve channels)."""

    z1: FloatArray
    z2: FloatArray
    play_n: FloatArray  # (channels, len(PLAY_SHARES))
    last_force_n: FloatArray

    @classmethod
    def zeros(cls, n: int) -> CurveState:
        return cls(np.zeros(n), np.zeros(n), np.zeros((n, len(PLAY_SHARES))), np.zeros(n))

    def select(self, idx: NDArray[np.intp]) -> CurveState:
        return CurveState(self.z1[idx], self.z2[idx], self.play_n[idx], self.last_force_n[idx])


_DUMMY: tuple[tuple[float, ...], tuple[float, ...]] = ((1.0, 2.0), (1.0, 0.0))


class CurveSet:
    """The curve channels of a device at positions ``positions``, tracked together (vectorised
    over channels, each kind of curve with its own arrays)."""

    def __init__(self, channels: Sequence[CurveChannel], positions: Sequence[int] | None = None) -> None:
        self.channels = tuple(channels)
        n = len(self.channels)
        self.positions = np.asarray(range(n) if positions is None else positions, dtype=np.intp)

        chans = self.channels
        power = [c.curve if isinstance(c.curve, PowerLawCurve) else PowerLawCurve(1.0, 1.0) for c in chans]
        line = [c.curve if isinstance(c.curve, LineCurve) else LineCurve(1.0, 0.0) for c in chans]
        self.kind = np.array([CURVE_KINDS.index(c.curve.kind) for c in chans], dtype=np.intp)
        self.gain = np.array([c.gain for c in chans], dtype=np.float64)
        self.offset = np.array([c.offset_n for c in chans], dtype=np.float64)
        self.low = np.array([c.force_min_n for c in chans], dtype=np.float64)
        self.high = np.array([c.force_max_n for c in chans], dtype=np.float64)
        self.k = np.array([p.coefficient_s for p in power], dtype=np.float64)
        self.inv_n = np.array([1.0 / p.exponent for p in power], dtype=np.float64)
        self.m = np.array([x.slope_s_per_n for x in line], dtype=np.float64)
        self.c = np.array([x.intercept_s for x in line], dtype=np.float64)
        # every channel has a row (a dummy table where the curve is not a lookup)
        self.knots = KnotTable(
            [
                (c.curve.resistance_ohm, c.curve.force_n) if isinstance(c.curve, LookupCurve) else _DUMMY
                for c in chans
            ]
        )
        self.is_power = self.kind == 0
        self.is_line = self.kind == 1
        self.is_lookup = self.kind == 2
        d = [c.drift for c in self.channels]
        self.a1 = np.array([x.creep_fraction for x in d])
        self.tau1 = np.array([x.creep_tau_s for x in d])
        self.a2 = np.array([x.creep2_fraction for x in d])
        self.tau2 = np.array([x.creep2_tau_s for x in d])
        self.beta = np.array([x.hysteresis_fraction for x in d])
        self.width = np.array([x.hysteresis_width_n for x in d])
        #: each channel's plays' widths (channels, len(PLAY_SHARES)), N
        self.play_widths = self.width[:, None] * np.asarray(PLAY_SHARES)[None, :]
        self.dynamic = bool(any(x.active for x in d))

    def __len__(self) -> int:
        return len(self.channels)

    def initial_state(self) -> CurveState:
        return CurveState.zeros(len(self.channels))

    def static_force(self, resistance_ohm: FloatArray) -> FloatArray:
        """Each channel's apparent force x (N) at its resistance (one value per channel)."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            r = np.asarray(resistance_ohm, dtype=np.float64) / self.gain
            g = np.where(r > 0.0, 1.0 / np.where(r > 0.0, r, 1.0), np.nan)
            g = np.where(np.isposinf(r), 0.0, g)
            x = np.zeros_like(r)
            if self.is_power.any():
                x = np.where(self.is_power, (g / self.k) ** self.inv_n, x)
            if self.is_line.any():
                x = np.where(self.is_line, (g - self.c) / self.m, x)
            if self.is_lookup.any():
                lr = np.where(r > 0.0, np.log(np.where(r > 0.0, r, 1.0)), np.nan)
                x = np.where(self.is_lookup, self.knots.force(lr), x)
            # an open sensor (no current) carries no load, whatever the curve reads at 0 S
            return np.asarray(np.where(np.isnan(g), np.nan, np.where(g == 0.0, 0.0, x + self.offset)))

    def track(
        self, resistance_ohm: FloatArray, state: CurveState, dt_s: float
    ) -> tuple[FloatArray, StatusArray, FloatArray, BoolArray, CurveState]:
        """One sample per channel: force (N), ``ForceStatus``, static force x (N), the
        extrapolated flag (outside the calibrated range) and the new state."""
        return self.track_apparent(self.static_force(resistance_ohm), state, dt_s)

    def track_apparent(
        self, x: FloatArray, state: CurveState, dt_s: float
    ) -> tuple[FloatArray, StatusArray, FloatArray, BoolArray, CurveState]:
        """``track`` from the apparent force x (N) itself: a device that calibrates its own
        static curve reports x, and only the dynamics are corrected here."""
        held = np.maximum(state.last_force_n, 0.0)
        if self.dynamic:
            dt = max(float(dt_s), 0.0) if math.isfinite(dt_s) else 0.0
            e1 = np.exp(-dt / self.tau1)
            e2 = np.exp(-dt / self.tau2)
            z1 = e1 * state.z1 + (1.0 - e1) * self.a1 * held
            z2 = e2 * state.z2 + (1.0 - e2) * self.a2 * held
            widths = self.play_widths
            xs = x[:, None]
            play = np.where(~np.isnan(xs), np.clip(state.play_n, xs - widths, xs + widths), state.play_n)
            s = np.mean((play - xs) / widths, axis=1)
            f = (x - z1 - z2) / (1.0 + self.beta * s)
        else:
            z1, z2, play, f = state.z1, state.z2, state.play_n, x
        invalid = np.isnan(f)
        no_contact = ~invalid & (f <= 0.0)
        status = np.where(invalid, _INVALID, np.where(no_contact, _NO_CONTACT, _OK)).astype(np.int8)
        force = np.where(invalid, np.nan, np.where(no_contact, 0.0, f))
        with np.errstate(invalid="ignore"):
            extrapolated = ~invalid & ~no_contact & ((force < self.low) | (force > self.high))
        new_held = np.where(invalid, held, force)
        return force, status, x, extrapolated, CurveState(z1, z2, play, new_held)


def track_series(
    channel: CurveChannel, resistance_ohm: ArrayLike, time_s: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """One channel's tracked force and apparent (static) force over a series (N), sample by
    sample with ``CurveSet.track``'s arithmetic on floats (fast for long records).

    Invalid samples read NaN and keep the held force; forces <= 0 read 0 N."""
    x = channel.static_force(resistance_ohm)
    t = np.asarray(time_s, dtype=np.float64)
    d = channel.drift
    if not d.active:
        return np.where(np.isnan(x), np.nan, np.maximum(x, 0.0)), x
    dt = np.maximum(np.diff(t, prepend=t[:1]), 0.0)
    e1 = np.exp(-dt / d.creep_tau_s).tolist()
    e2 = np.exp(-dt / d.creep2_tau_s).tolist()
    a1, a2, beta = d.creep_fraction, d.creep2_fraction, d.hysteresis_fraction
    s = preisach_direction(x, d.hysteresis_width_n).tolist() if d.hysteresis_fraction else [0.0] * x.size
    out = [0.0] * len(e1)
    z1 = z2 = held = 0.0
    for k, xk in enumerate(x.tolist()):
        z1 = e1[k] * z1 + (1.0 - e1[k]) * a1 * held
        z2 = e2[k] * z2 + (1.0 - e2[k]) * a2 * held
        if xk != xk:  # NaN: invalid, the held force stays
            out[k] = xk
            continue
        f = (xk - z1 - z2) / (1.0 + beta * s[k])
        if f <= 0.0:
            f = 0.0
        out[k] = f
        held = f
    return np.asarray(out, dtype=np.float64), x


def preisach_direction(reading_n: FloatArray, width_n: float) -> FloatArray:
    """s at each sample (module docstring): the plays of widths ``PLAY_SHARES`` x ``width_n``
    moved by the reading x from 0 (a NaN reading leaves them), averaged."""
    widths = [c * width_n for c in PLAY_SHARES]
    plays = [0.0] * len(widths)
    out = [0.0] * reading_n.size
    for k, x in enumerate(np.asarray(reading_n, dtype=np.float64).tolist()):
        if x != x:
            continue
        total = 0.0
        for j, w in enumerate(widths):
            p = plays[j]
            p = x - w if p < x - w else x + w if p > x + w else p
            plays[j] = p
            total += (p - x) / w
        out[k] = total / len(widths)
    return np.asarray(out)


_CURVE_KEYS: dict[str, tuple[str, ...]] = {
    "power_law": ("coefficient_s", "exponent"),
    "line": ("slope_s_per_n", "intercept_s"),
    "lookup": ("resistance_ohm", "force_n"),
}
DRIFT_KEYS = tuple(f.name for f in fields(Drift))
_COMMON_KEYS = ("kind", "gain", "offset_n", "force_min_n", "force_max_n", "held_out_force_rms_n")


def curve_from_table(data: Mapping[str, object]) -> CurveChannel:
    """A curve channel from a calibration file's ``[curve.<name>]`` table; ``CurveError``
    names the key at fault."""
    kind = data.get("kind")
    if kind not in CURVE_KINDS:
        raise CurveError("kind", f"{kind!r} is not a curve kind; allowed: {', '.join(CURVE_KINDS)}")
    assert isinstance(kind, str)
    allowed = _COMMON_KEYS + _CURVE_KEYS[kind] + DRIFT_KEYS
    for key in data:
        if key not in allowed:
            raise CurveError(key, f"unknown key for a {kind} curve; allowed: {', '.join(allowed)}")
    for key in _CURVE_KEYS[kind]:
        if key not in data:
            raise CurveError(
                key, f"required key is missing ({kind} curves need {' and '.join(_CURVE_KEYS[kind])})"
            )
    curve: StaticCurve
    if kind == "power_law":
        curve = PowerLawCurve(data["coefficient_s"], data["exponent"])  # type: ignore[arg-type]
    elif kind == "line":
        curve = LineCurve(data["slope_s_per_n"], data["intercept_s"])  # type: ignore[arg-type]
    else:
        knots = []
        for key in _CURVE_KEYS["lookup"]:
            values = data[key]
            if not isinstance(values, list):
                raise CurveError(key, f"expected an array of numbers, got {values!r}")
            knots.append(tuple(values))
        curve = LookupCurve(knots[0], knots[1])
    drift = Drift(**{k: data[k] for k in DRIFT_KEYS if k in data})  # type: ignore[arg-type]
    return CurveChannel(
        curve,
        drift,
        gain=data.get("gain", 1.0),  # type: ignore[arg-type]
        offset_n=data.get("offset_n", 0.0),  # type: ignore[arg-type]
        force_min_n=data.get("force_min_n", 0.0),  # type: ignore[arg-type]
        force_max_n=data.get("force_max_n", math.inf),  # type: ignore[arg-type]
    )
