"""The simulated world: effects beyond the paper, written here independently of the gateway.

The paper's physics (tunneling eq. 2-9, Holm contact eq. 10-12, one-Kelvin creep eq. 14-17)
comes from ``sim_device.sensor.PaperSensor``. The world then modifies the sensor it produced:

``creep2``
    A second Kelvin element in series with the paper's, strain ``e2`` obeying
    ``mu2 de2/dt + E2 e2 = sigma`` with ``sigma = F / A`` (E2 = ``e2_pa``, mu2 = ``mu2_pa_s``,
    force independent). Integrated exactly per sample with the force held since the previous
    sample, as a first-order linear filter. Defaults E2 = 300 MPa, mu2 = 3e11 Pa s (tau2 =
    1000 s): at 2 N the extra strain approaches 3.4e-4, lowering R by about 8 % over ~1 h.
``hysteresis``
    Rate-independent hysteresis as a small Preisach model: three play (backlash) operators
    of radii r = (0.5, 1, 2) x ``hysteresis_force_n`` acting on the force,
    ``p <- clip(p, F - r, F + r)``; the state ``d = mean((F - p) / r)`` is +1 after loading
    and -1 after unloading, and the strain is offset by ``-hysteresis_strain * d``. Loading
    therefore reads a higher resistance than unloading at the same force. Defaults 2e-4
    strain and 0.5 N: about +-5 % resistance between the branches at mid range.
``temperature``
    Arrhenius activation of the polymer (tunneling/hopping) conduction:
    ``R_pol(T) = R_pol(T_ref) exp(Ea / k_B (1/T - 1/T_ref))`` with the activation energy
    chosen so that the slope at T_ref equals ``temperature_coeff_per_k``:
    ``Ea = -coeff k_B T_ref^2``. Default -0.5 %/K (Ea = 0.038 eV): -5 % for +10 K.
``series_resistance``
    ``series_resistance_ohm`` (default 500 ohm, 5 % of the reading at 5 N) in series.
``leakage``
    ``leakage_resistance_ohm`` (default 2 Mohm) in parallel with everything: caps the
    unloaded resistance (an unloaded sensor reads 2 Mohm instead of open) and lowers a
    0.5 N reading by about 6 %.

The magnitudes are read from each channel's ``SimSensorParams`` so the true parameters of a
channel (``SimArray.channel_params``) describe the world exactly where the forms coincide.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import constants, signal

from .sensor import PaperResistance, SimSensorParams

FloatArray = NDArray[np.float64]

#: Play-operator radii of the hysteresis model, in units of ``hysteresis_force_n``.
PLAY_RADII = (0.5, 1.0, 2.0)
_KELVIN_ZERO_C = constants.zero_Celsius
_BOLTZMANN_EV_PER_K = constants.k / constants.e


@dataclass
class WorldState:
    """Per-channel state of the world effects."""

    kv2_strain: FloatArray  # (N,)
    held_force_n: FloatArray  # (N,) force recorded at the last sample
    play_n: FloatArray  # (len(PLAY_RADII), N) play-operator outputs

    @classmethod
    def zeros(cls, n: int) -> WorldState:
        return cls(np.zeros(n), np.zeros(n), np.zeros((len(PLAY_RADII), n)))


def play_operator(force_n: FloatArray, radius_n: FloatArray, p0_n: FloatArray) -> FloatArray:
    """Backlash (play) operator over a series: p[k] = clip(p[k-1], F[k] - r, F[k] + r).

    ``force_n`` has shape (T, N), ``radius_n`` and ``p0_n`` (N,). Vectorized over time with a
    parallel prefix scan: each step is a clamp x -> clip(x, lo, hi), and a composition of
    clamps is again a clamp, ``clip(clip(x, lo1, hi1), lo2, hi2) = clip(x, clip(lo1, lo2,
    hi2), clip(hi1, lo2, hi2))``, so log2(T) vectorized passes give every prefix exactly.
    Runs of unchanged force are scanned once (a repeated clamp changes nothing).
    """
    n_t = force_n.shape[0]
    changed = np.ones(n_t, dtype=bool)
    changed[1:] = np.any(force_n[1:] != force_n[:-1], axis=1)
    compress = int(changed.sum()) < n_t
    f = force_n[changed] if compress else force_n
    lo = f - radius_n[None, :]
    hi = f + radius_n[None, :]
    d = 1
    while d < f.shape[0]:
        new_lo = np.clip(lo[:-d], lo[d:], hi[d:])
        new_hi = np.clip(hi[:-d], lo[d:], hi[d:])
        lo[d:], hi[d:] = new_lo, new_hi
        d *= 2
    out = np.clip(p0_n[None, :], lo, hi)
    return out[np.cumsum(changed) - 1] if compress else out


def kelvin_series(
    held_force_n: FloatArray,
    dt_s: float,
    area_m2: FloatArray,
    e_pa: FloatArray,
    mu_pa_s: FloatArray,
    x0: FloatArray,
) -> FloatArray:
    """Strain of a Kelvin element before each sample, shape (T, N).

    ``held_force_n[k]`` is the force held over the step into sample k (uniform step
    ``dt_s``). Exact solution of ``mu de/dt + E e = F / A`` over each step:
    ``e[k] = a e[k-1] + (1 - a) F[k] / (A E)``, ``a = exp(-E dt / mu)``, run as a linear filter
    (channels sharing a decay factor are filtered together).
    """
    a = np.exp(-e_pa * dt_s / mu_pa_s)
    target = held_force_n / (area_m2 * e_pa)[None, :]
    out = np.empty_like(target)
    for value in np.unique(a):
        cols = np.nonzero(a == value)[0]
        b_coef, a_coef = [1.0 - value], [1.0, -value]
        zi = (value * x0[cols])[None, :]
        out[:, cols], _ = signal.lfilter(b_coef, a_coef, target[:, cols], axis=0, zi=zi)
    return out


def arrhenius_factor(
    temperature_c: FloatArray, coeff_per_k: FloatArray, reference_c: FloatArray
) -> FloatArray:
    """Polymer resistance factor exp(Ea/k_B (1/T - 1/T_ref)), Ea = -coeff k_B T_ref^2 (T in K)."""
    t_ref = reference_c + _KELVIN_ZERO_C
    t = np.asarray(temperature_c) + _KELVIN_ZERO_C
    ea_over_k = -coeff_per_k * t_ref**2
    return np.asarray(np.exp(ea_over_k * (1.0 / t - 1.0 / t_ref)))


def activation_energy_ev(coeff_per_k: float, reference_c: float = 25.0) -> float:
    """The Arrhenius activation energy (eV) whose slope at ``reference_c`` is ``coeff_per_k``."""
    t_ref = reference_c + _KELVIN_ZERO_C
    return float(-coeff_per_k * t_ref**2 * _BOLTZMANN_EV_PER_K)


class World:
    """Applies the switched-on world effects to the paper sensor's resistance (``PaperResistance``)."""

    def __init__(
        self, effects: Sequence[str], params: Sequence[SimSensorParams], gamma_s0: FloatArray
    ) -> None:
        self.effects = tuple(effects)
        self.n_channels = len(params)

        def col(name: str) -> FloatArray:
            return np.array([getattr(p, name) for p in params], dtype=np.float64)

        self._area = col("area_m2")
        self._e2, self._mu2 = col("e2_pa"), col("mu2_pa_s")
        self._h_strain, self._h_force = col("hysteresis_strain"), col("hysteresis_force_n")
        self._t_coeff, self._t_ref = col("temperature_coeff_per_k"), col("reference_temperature_c")
        self._series = col("series_resistance_ohm")
        self._leak = col("leakage_resistance_ohm")
        self._gamma_s0 = np.asarray(gamma_s0, dtype=np.float64)
        self.state = WorldState.zeros(self.n_channels)

    def has(self, effect: str) -> bool:
        return effect in self.effects

    def apply(
        self,
        breakdown: PaperResistance,
        force_n: FloatArray,
        temperature_c: FloatArray,
        dt_s: float,
    ) -> FloatArray:
        """True sensor resistance (T, N) in ohm; advances the world state over the batch.

        ``dt_s`` is the uniform step between samples (and from the previous batch's last
        sample to this batch's first).
        """
        if not self.effects:
            self.state.held_force_n = force_n[-1].copy()
            return breakdown.total_ohm
        extra = np.zeros_like(force_n)
        if self.has("creep2"):
            held = np.vstack([self.state.held_force_n[None, :], force_n[:-1]])
            kv2 = kelvin_series(held, dt_s, self._area, self._e2, self._mu2, self.state.kv2_strain)
            # the state after the last sample: relaxed into it, then holding its force
            self.state.kv2_strain = kv2[-1].copy()
            extra += kv2
        if self.has("hysteresis"):
            d = np.zeros_like(force_n)
            for k, scale in enumerate(PLAY_RADII):
                radius = scale * self._h_force
                p = play_operator(force_n, radius, self.state.play_n[k])
                self.state.play_n[k] = p[-1]
                d += (force_n - p) / radius[None, :]
            extra -= self._h_strain[None, :] * d / len(PLAY_RADII)
        self.state.held_force_n = force_n[-1].copy()
        strain = breakdown.strain
        polymer = (
            breakdown.polymer_ohm
            * (1.0 - (strain + extra))
            / (1.0 - strain)
            * np.exp(-self._gamma_s0 * extra)
        )
        if self.has("temperature"):
            polymer = polymer * arrhenius_factor(temperature_c, self._t_coeff, self._t_ref)
        core = polymer + breakdown.contact_ohm
        if self.has("series_resistance"):
            core = core + self._series
        if self.has("leakage"):
            leak = np.broadcast_to(self._leak, core.shape)
            with np.errstate(invalid="ignore"):
                par = core * leak / (core + leak)
            core = np.where(np.isinf(core), leak, np.where(np.isinf(leak), core, par))
        return np.asarray(core, dtype=np.float64)
