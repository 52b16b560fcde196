"""The dynamics on top of a static curve: a Kelvin creep chain with its own recovery, and
rate-independent hysteresis. One owner of each dynamic element (PyBaMM keeps one option per
mechanism): its parameters, their allowed ranges and table, and its response to a force series.

The apparent force x (N) a static curve reads moves away from the applied force F:

  x_k = F_k (1 + beta s_k) exp(u_k) + z1_k + z2_k,

* z_i, a Kelvin element of the creep chain (the paper's eq. 14-15 in state form): over an
  interval dt with the previous force F_{k-1} held, z_i <- T + (z_i - T) e, T = a_i F_{k-1},
  e = exp(-dt / tau). While the held force lies above the element's own unit response z_i / a_i
  (loading) z_i moves towards a_i F with the *loading* time constant ``creep_tau_s``; below it
  (after unloading) with the *recovery* time constant ``creep_recovery_tau_s`` (default: the
  loading one). A real
  FSR recovers more slowly than it creeps: a low load right after a high one reads high for
  longer than the creep's own time constant says. One element (``creep``) or two
  (``creep2``, a slower one). A fraction may be negative: some FSRs' conductance *falls* under
  a held high load and rises again at a low one (the real records of docs/calibration.md); the
  settled reading (1 + a1 + a2) F must still rise with F, which every fit keeps.
* u, the *sensitivity* element: the log of the sensor's sensitivity relaxes towards c x_{k-1}
  (``sensitivity_per_n`` c, 1/N; the reading held over the interval) with its own loading and
  recovery time constants (``sensitivity_tau_s``, ``sensitivity_recovery_tau_s``),
  u <- T + (u - T) e, T = c x_{k-1}. Like the plays, it follows the reading, not the estimated
  force: with c < 0 an element on the estimate feeds back (a larger estimate lowers the
  sensitivity, which raises the estimate) and, above a reading of 1 / (e |c|), runs away.
  Where z_i adds a force that scales with the load (the same newtons at any later load until
  it has recovered), u scales the reading: a sensor whose sensitivity fell by a third under a
  held high load (c < 0) reads a following low hold a third low at first, not a fixed number of
  newtons off, and recovers towards it as the polymer relaxes back;
* s, hysteresis (Preisach-style): play operators of widths c_j w (N, c_j in ``PLAY_SHARES``) on
  the apparent force, p_j <- clip(p_j, x - c_j w, x + c_j w), s = mean_j (p_j - x) / (c_j w)
  in [-1, 1]: -1 while loading, +1 while unloading. The play follows the reading x, not the
  estimated force (a play on the estimate feeds back and flips between branches on noise).

The state at the first sample is the *equilibrium at the first load*: z_i = a_i F_0,
u = c x_0 and every play at x_0 (s = 0), so F_0 = x_0 / (exp(c x_0) + a1 + a2).
A sensor at rest (x_0 = 0) starts relaxed, as before; a sensor already loaded when the record
or the gateway starts is not read as if its load had just been applied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from .physics import play_series, relax_series
from .static_curves import CurveError, finite_value, positive_value

__all__ = [
    "DRIFT_FORMS",
    "DRIFT_KEYS",
    "PLAY_SHARES",
    "Drift",
    "FormParts",
    "kelvin_unit_series",
    "play_direction_series",
]

FloatArray = NDArray[np.float64]

#: The hysteresis plays' widths as shares of ``Drift.hysteresis_width_n``.
PLAY_SHARES = (0.25, 0.5, 1.0, 2.0)


class FormParts(NamedTuple):
    """What a drift form has: additive creep elements, hysteresis, the sensitivity element."""

    elements: int
    hysteresis: bool
    sensitivity: bool = False

    @property
    def time_driven(self) -> bool:
        return self.elements > 0 or self.sensitivity


#: The dynamics a curve can carry, by name.
DRIFT_FORMS: dict[str, FormParts] = {
    "static": FormParts(0, False),
    "creep": FormParts(1, False),
    "creep2": FormParts(2, False),
    "hysteresis": FormParts(0, True),
    "creep+hysteresis": FormParts(1, True),
    "creep2+hysteresis": FormParts(2, True),
    "sensitivity": FormParts(0, False, True),
    "sensitivity+hysteresis": FormParts(0, True, True),
}
#: What a file may hold for a fraction (older files: negative ones load; fits write >= 0).
_FRACTION_RANGE = {
    "creep_fraction": (-0.9, 5.0),
    "creep2_fraction": (-0.9, 5.0),
    "hysteresis_fraction": (-0.9, 0.9),
}


@dataclass(frozen=True)
class Drift:
    """The dynamics on top of a static curve (module docstring); zero fractions switch them off.

    ``creep_fraction`` a1 and ``creep2_fraction`` a2 (dimensionless: the long-time share of
    the applied force each Kelvin element adds to the reading), their loading time constants
    ``creep_tau_s`` and ``creep2_tau_s`` (s) and recovery time constants
    ``creep_recovery_tau_s`` and ``creep2_recovery_tau_s`` (s; None: the loading one);
    ``hysteresis_fraction`` beta (dimensionless) and the play's ``hysteresis_width_n`` w (N)."""

    creep_fraction: float = 0.0
    creep_tau_s: float = 10.0
    creep2_fraction: float = 0.0
    creep2_tau_s: float = 300.0
    hysteresis_fraction: float = 0.0
    hysteresis_width_n: float = 1.0
    creep_recovery_tau_s: float | None = None
    creep2_recovery_tau_s: float | None = None
    sensitivity_per_n: float = 0.0
    sensitivity_tau_s: float = 10.0
    sensitivity_recovery_tau_s: float | None = None

    def __post_init__(self) -> None:
        for name, (lo, hi) in _FRACTION_RANGE.items():
            v = finite_value(name, getattr(self, name), "")
            if not lo <= v <= hi:
                raise CurveError(name, f"{v!r} is out of range; allowed: [{lo}, {hi}]")
        for name in ("creep_tau_s", "creep2_tau_s", "sensitivity_tau_s"):
            positive_value(name, getattr(self, name), "s")
        c = finite_value("sensitivity_per_n", self.sensitivity_per_n, "1/N")
        if not -1.0 <= c <= 1.0:
            raise CurveError("sensitivity_per_n", f"{c!r} is out of range; allowed: [-1, 1] 1/N")
        for name in ("creep_recovery_tau_s", "creep2_recovery_tau_s", "sensitivity_recovery_tau_s"):
            if getattr(self, name) is not None:
                positive_value(name, getattr(self, name), "s")
        positive_value("hysteresis_width_n", self.hysteresis_width_n, "N")

    @property
    def recovery_tau1_s(self) -> float:
        return self.creep_tau_s if self.creep_recovery_tau_s is None else self.creep_recovery_tau_s

    @property
    def recovery_tau2_s(self) -> float:
        return self.creep2_tau_s if self.creep2_recovery_tau_s is None else self.creep2_recovery_tau_s

    @property
    def recovery_sensitivity_tau_s(self) -> float:
        if self.sensitivity_recovery_tau_s is None:
            return self.sensitivity_tau_s
        return self.sensitivity_recovery_tau_s

    @property
    def elements(self) -> tuple[tuple[float, float, float], ...]:
        """The active Kelvin elements: (fraction, loading tau s, recovery tau s)."""
        out = []
        if self.creep_fraction != 0.0:
            out.append((self.creep_fraction, self.creep_tau_s, self.recovery_tau1_s))
        if self.creep2_fraction != 0.0:
            out.append((self.creep2_fraction, self.creep2_tau_s, self.recovery_tau2_s))
        return tuple(out)

    @property
    def parts(self) -> FormParts:
        elements = 2 if self.creep2_fraction != 0.0 else 1 if self.creep_fraction != 0.0 else 0
        return FormParts(elements, self.hysteresis_fraction != 0.0, self.sensitivity_per_n != 0.0)

    @property
    def form(self) -> str:
        """The form's name; a combination no fit writes (creep with sensitivity) reads as both."""
        parts = self.parts
        found = [k for k, v in DRIFT_FORMS.items() if v == parts]
        if found:
            return found[0]
        base = next(k for k, v in DRIFT_FORMS.items() if v == FormParts(parts.elements, parts.hysteresis))
        return f"{base}+sensitivity"

    @property
    def active(self) -> bool:
        return self.form != "static"

    @property
    def asymmetric(self) -> bool:
        """Does any element recover with another time constant than it loads with?"""
        return any(load != rec for _, load, rec in self.elements)

    @property
    def n_parameters(self) -> int:
        elements, hyst, sens = self.parts
        asym = sum(1 for _, load, rec in self.elements if load != rec)
        if sens:
            asym += 1 + int(self.sensitivity_tau_s != self.recovery_sensitivity_tau_s)
        return 2 * elements + 2 * int(hyst) + asym + int(sens)

    def table(self) -> dict[str, float]:
        """The keys a calibration table holds (a recovery time constant only when it is set)."""
        return {f.name: float(v) for f in fields(self) if (v := getattr(self, f.name)) is not None}


DRIFT_KEYS = tuple(f.name for f in fields(Drift))


def kelvin_unit_series(
    held_n: FloatArray, dt_s: FloatArray, tau_load_s: float, tau_recover_s: float, z0: float
) -> FloatArray:
    """z_k of a unit-fraction Kelvin element driven by the force held over each interval:
    z_k = T + (z_{k-1} - T) exp(-dt_k / tau), T = held_k, tau the loading time constant where
    T > z_{k-1} and the recovery one elsewhere; z_{-1} = ``z0``. One exact pass
    (``physics.relax_series``) when the two time constants are equal."""
    held = np.asarray(held_n, dtype=np.float64)
    dt = np.asarray(dt_s, dtype=np.float64)
    if tau_load_s == tau_recover_s:
        out, _ = relax_series(-dt / tau_load_s, held, np.asarray(z0, dtype=np.float64))
        return np.asarray(out)
    e_up = np.exp(-dt / tau_load_s).tolist()
    e_down = np.exp(-dt / tau_recover_s).tolist()
    out_list = [0.0] * held.size
    z = float(z0)
    for k, target in enumerate(held.tolist()):
        e = e_up[k] if target > z else e_down[k]
        z = target + (z - target) * e
        out_list[k] = z
    return np.asarray(out_list, dtype=np.float64)


def play_direction_series(reading_n: FloatArray, width_n: float, start_n: float | None = None) -> FloatArray:
    """s at each sample (module docstring): the plays of widths ``PLAY_SHARES`` x ``width_n``
    moved by the reading x from ``start_n`` (default: the first finite reading, s = 0 there);
    a NaN reading leaves the plays where they are (its s is 0)."""
    x = np.asarray(reading_n, dtype=np.float64)
    finite = np.isfinite(x)
    if not finite.any():
        return np.zeros(x.size)
    # a repeated reading leaves every play where it is: carry the last finite one over gaps
    idx = np.where(finite, np.arange(x.size), 0)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.flatnonzero(finite)[0])
    filled = np.where(np.arange(x.size) < first, x[first], x[idx])
    widths = width_n * np.asarray(PLAY_SHARES)
    readings = np.repeat(filled[:, None], widths.size, axis=1)
    radii = np.broadcast_to(widths, readings.shape).copy()
    plays = play_series(readings, radii, np.full(widths.size, x[first] if start_n is None else start_n))
    s = np.mean((plays - filled[:, None]) / widths[None, :], axis=1)
    return np.asarray(np.where(finite, s, 0.0))


def equilibrium_force_n(apparent_n: float, drift: Drift) -> float:
    """F_0 = x_0 / (exp(c x_0) + a1 + a2) (N, at least 0): the force a reading x_0 means for a
    sensor that has held that load long enough for every element to settle."""
    if not math.isfinite(apparent_n) or apparent_n <= 0.0:
        return 0.0
    total = math.exp(drift.sensitivity_per_n * apparent_n) + sum(a for a, _, _ in drift.elements)
    return max(apparent_n / total, 0.0) if total > 0.0 else 0.0
