"""The simulated sensor's own physics, written from the paper and ``docs/parameters.md``.

An independent witness: nothing here comes from ``gateway``. Where the gateway and the
simulator agree, two implementations of the same equations agree
(``tests/crosscheck/test_sim_and_model_agree.py``). SI units throughout, vectorized over the
N channels on the last axis.

Per channel, for a force F (N) applied to the sensing area A (m^2):

* tunneling through the polymer (eq. 4, 8, 9/16):
  gamma = (4 pi / h) sqrt(2 m_e phi_b), s0 = D ((pi / (6 phi_v))^(1/3) - 1),
  R_pol = R0 (1 - eps) exp(-gamma s0 eps);
* Holm contact resistance at the two electrodes (eq. 12): each
  R_con = (rho1 + rho2) / 4 sqrt(pi H / F), open (infinite) while F <= 0;
* strain of the standard linear solid (eq. 14): eps = sigma / E0 + e_kv with sigma = F / A,
  where the Kelvin strain obeys mu1 de_kv/dt + E1 e_kv = sigma. E0, E1 and mu1 are linear in
  the applied force (``docs/parameters.md``: E0 = 15 MPa + 1 MPa/N F, ...).

The Kelvin element is integrated numerically as an ODE: between two samples the force is the
one of the earlier sample (a zero-order hold, the way a sampled load is applied), and the
interval is crossed in classic fourth-order Runge-Kutta steps no longer than a hundredth of
the element's time constant mu1/E1 (100 s by default, so steps of at most 1 s). RK4's local
truncation error on this linear ODE is z^5/120 of the distance to equilibrium, z = -h E1/mu1;
relative to the Kelvin strain it is about z^4/120: 1e-18 for a 10 ms sample, at most 1e-10 for
any longer one (``tests/unit/sim_device/test_sim_sensor.py`` measures it against the paper's
closed form, eq. 15). That is far below the ADC's resolution (1.5e-5 of full scale at 16 bit).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import constants

FloatArray = NDArray[np.float64]

#: RK4 steps are at most this fraction of the Kelvin time constant mu1 / E1.
MAX_STEP_OF_TAU = 0.01


class SensorParamsError(ValueError):
    """A simulated sensor parameter is missing, unknown or outside its allowed range."""


#: Allowed ranges: (low, high, low inclusive, high inclusive). Every parameter is finite except
#: the leakage resistance, whose +inf means "no leakage path".
_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "barrier_height_ev": (0.0, 10.0, False, True),
    "particle_diameter_m": (0.0, 1e-3, False, True),
    "volume_fraction": (0.0, math.pi / 6.0, False, False),
    "area_m2": (0.0, 1.0, False, True),
    "r0_ohm": (0.0, math.inf, False, False),
    "rho1_ohm_m": (0.0, math.inf, True, False),
    "rho2_ohm_m": (0.0, math.inf, True, False),
    "hardness_pa": (0.0, math.inf, False, False),
    "e0_pa": (0.0, math.inf, False, False),
    "e0_slope_pa_per_n": (0.0, math.inf, True, False),
    "e1_pa": (0.0, math.inf, False, False),
    "e1_slope_pa_per_n": (0.0, math.inf, True, False),
    "mu1_pa_s": (0.0, math.inf, False, False),
    "mu1_slope_pa_s_per_n": (0.0, math.inf, True, False),
    "e2_pa": (0.0, math.inf, False, False),
    "mu2_pa_s": (0.0, math.inf, False, False),
    "hysteresis_strain": (0.0, 0.1, True, True),
    "hysteresis_force_n": (0.0, math.inf, False, False),
    "temperature_coeff_per_k": (-0.2, 0.2, True, True),
    "reference_temperature_c": (-273.15, 1000.0, False, True),
    "series_resistance_ohm": (0.0, math.inf, True, False),
    "leakage_resistance_ohm": (0.0, math.inf, False, True),
}


def _describe(low: float, high: float, low_inclusive: bool, high_inclusive: bool) -> str:
    return f"{'[' if low_inclusive else '('}{low:g}, {high:g}{']' if high_inclusive else ')'}"


@dataclass(frozen=True)
class SimSensorParams:
    """The true parameters of one simulated sensor (``docs/parameters.md`` defaults).

    The names are those of the interchange contract, so a channel's truth can be handed to
    any tool that speaks it (``as_dict``). The paper's physics uses the first fourteen; the
    rest size the world effects of ``sim_device.world``.
    """

    barrier_height_ev: float = 0.05
    particle_diameter_m: float = 500e-9
    volume_fraction: float = 0.2873
    area_m2: float = 1.9635e-5
    r0_ohm: float = 200e3
    rho1_ohm_m: float = 1.68e-8
    rho2_ohm_m: float = 1.0
    hardness_pa: float = 30e6
    e0_pa: float = 15e6
    e0_slope_pa_per_n: float = 1.0e6
    e1_pa: float = 150e6
    e1_slope_pa_per_n: float = 10e6
    mu1_pa_s: float = 1.5e10
    mu1_slope_pa_s_per_n: float = 1.0e9
    e2_pa: float = 300e6
    mu2_pa_s: float = 3.0e11
    hysteresis_strain: float = 2e-4
    hysteresis_force_n: float = 0.5
    temperature_coeff_per_k: float = -0.005
    reference_temperature_c: float = 25.0
    series_resistance_ohm: float = 500.0
    leakage_resistance_ohm: float = 2e6

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
                raise SensorParamsError(f"{f.name} = {value!r} must be a number")
            number = float(value)
            low, high, low_inclusive, high_inclusive = _RANGES[f.name]
            above = number >= low if low_inclusive else number > low
            below = number <= high if high_inclusive else number < high
            if not (above and below):  # also refuses NaN
                allowed = _describe(low, high, low_inclusive, high_inclusive)
                raise SensorParamsError(f"{f.name} = {value!r} is outside {allowed}")
            object.__setattr__(self, f.name, number)

    def as_dict(self) -> dict[str, float]:
        """Every parameter by its contract name."""
        return {k: float(v) for k, v in asdict(self).items()}

    def with_overrides(self, overrides: Mapping[str, Any]) -> SimSensorParams:
        """A copy with some parameters replaced (validated again); unknown names are refused."""
        unknown = sorted(set(overrides) - {f.name for f in fields(self)})
        if unknown:
            raise SensorParamsError(f"unknown sensor parameter {unknown[0]!r}")
        return SimSensorParams(**{**self.as_dict(), **overrides})


def parameter_names() -> tuple[str, ...]:
    return tuple(f.name for f in fields(SimSensorParams))


@dataclass(frozen=True)
class PaperResistance:
    """The paper's sensor resistance for a load history; arrays (T, N), ohm and strain."""

    total_ohm: FloatArray
    contact_ohm: FloatArray  # both electrode contacts, 2 R_con (inf at F <= 0)
    polymer_ohm: FloatArray
    strain: FloatArray


class PaperSensor:
    """Tunneling + contact + creep (eq. 4-17) of N sensors, with the Kelvin strain as state."""

    def __init__(self, params: Sequence[SimSensorParams]) -> None:
        def col(name: str) -> FloatArray:
            return np.array([getattr(p, name) for p in params], dtype=np.float64)

        phi_j = col("barrier_height_ev") * constants.e
        gamma = 4.0 * math.pi / constants.h * np.sqrt(2.0 * constants.m_e * phi_j)
        s0 = col("particle_diameter_m") * ((math.pi / (6.0 * col("volume_fraction"))) ** (1.0 / 3.0) - 1.0)
        self.gamma_s0: FloatArray = gamma * s0
        self.n_channels = len(params)
        self._r0 = col("r0_ohm")
        self._area = col("area_m2")
        self._e0, self._e0_slope = col("e0_pa"), col("e0_slope_pa_per_n")
        self._e1, self._e1_slope = col("e1_pa"), col("e1_slope_pa_per_n")
        self._mu1, self._mu1_slope = col("mu1_pa_s"), col("mu1_slope_pa_s_per_n")
        # one electrode: (rho1 + rho2) / 4 sqrt(pi H / F); the sensor has two in series
        self._one_contact = (
            (col("rho1_ohm_m") + col("rho2_ohm_m")) / 4.0 * np.sqrt(math.pi * col("hardness_pa"))
        )
        #: Kelvin strain (N,) and the force held since the last sample (N,)
        self.kelvin_strain: FloatArray = np.zeros(self.n_channels)
        self.held_force_n: FloatArray = np.zeros(self.n_channels)

    def settle(self, force_n: FloatArray) -> None:
        """Make ``force_n`` (N, per sensor) a load carried since long ago: held, with the
        Kelvin strain at its equilibrium sigma / E1(F)."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0) * np.ones(self.n_channels)
        self.held_force_n = f.copy()
        self.kelvin_strain = np.asarray(f / self._area / (self._e1 + self._e1_slope * f))

    def contact_ohm(self, force_n: FloatArray) -> FloatArray:
        """Both electrode contacts, 2 R_con (eq. 12); +inf for F <= 0 (open at rest)."""
        f = np.asarray(force_n, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            one = self._one_contact / np.sqrt(np.where(f > 0.0, f, 0.0))
        return np.asarray(np.where(f > 0.0, 2.0 * one, np.inf))

    def elastic_strain(self, force_n: FloatArray) -> FloatArray:
        """sigma / E0(F) of the instantaneous spring, sigma = F / A."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        return np.asarray(f / self._area / (self._e0 + self._e0_slope * f))

    def polymer_ohm(self, strain: FloatArray) -> FloatArray:
        """R0 (1 - eps) exp(-gamma s0 eps) (eq. 9/16)."""
        return np.asarray(self._r0 * (1.0 - strain) * np.exp(-self.gamma_s0 * strain))

    def _kelvin_steps(self, held_force_n: FloatArray, dt_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """For each interval (rows of ``held_force_n``, widths ``dt_s``): the Kelvin element's
        equilibrium strain sigma / E1 and the factor RK4 multiplies the distance to it by.

        mu1 de/dt + E1 e = sigma is linear with constant coefficients while the force is
        held, so the four stages of one classic Runge-Kutta step of width h reduce to
        e <- e* + (e - e*) R(z), R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24, z = -h E1 / mu1.
        An interval is crossed in m equal steps with |z| <= ``MAX_STEP_OF_TAU``: R(z)^m.
        """
        f = np.maximum(held_force_n, 0.0)
        e1 = self._e1 + self._e1_slope * f
        mu1 = self._mu1 + self._mu1_slope * f
        z_total = -np.asarray(dt_s, dtype=np.float64).reshape(-1, *([1] * (f.ndim - 1))) * e1 / mu1
        steps = np.maximum(1.0, np.ceil(-z_total / MAX_STEP_OF_TAU))
        z = z_total / steps
        factor = (1.0 + z * (1.0 + z / 2.0 * (1.0 + z / 3.0 * (1.0 + z / 4.0)))) ** steps
        return f / self._area / e1, np.asarray(factor)

    def run(self, force_n: FloatArray, times_s: FloatArray, start_s: float) -> PaperResistance:
        """Resistance at each sample of a load history (T, N) at times (T,), advancing the state.

        Before each sample the Kelvin strain is integrated from the previous sample (from
        ``start_s`` for the first) with the previous force held; then the sample's force
        loads the instantaneous spring and becomes the held force.
        """
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        t = np.asarray(times_s, dtype=np.float64).reshape(-1)
        held = np.vstack([self.held_force_n[None, :], f[:-1]])
        dt = np.diff(t, prepend=float(start_s))
        target, factor = self._kelvin_steps(held, dt)
        kelvin = np.empty_like(f)
        e = self.kelvin_strain
        for k in range(f.shape[0]):
            e = target[k] + (e - target[k]) * factor[k]
            kelvin[k] = e
        self.kelvin_strain, self.held_force_n = np.array(e), f[-1].copy()
        strain = self.elastic_strain(f) + kelvin
        polymer = self.polymer_ohm(strain)
        contact = self.contact_ohm(f)
        return PaperResistance(polymer + contact, contact, polymer, strain)
