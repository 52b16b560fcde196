"""An independent emulator of a force-sensing resistor (FSR) on a bench, for tests.

Records from this module are *not* produced by the gateway's physical model (tunneling +
contact + creep, ``gateway/model``) nor by the simulated MIS array (``sim_device.sensor``):
the sensor here is a generic power-law FSR with Burgers-like creep, a creep chain whose
elements load and recover with different time constants, Preisach-style hysteresis and
run-to-run sensitivity changes, read by a 2-wire ohmmeter, with a load cell as the force
reference. It imports nothing of ``gateway`` (numpy and scipy only). The modules:
``fsr_params`` (parameters), ``fsr_protocol`` (load histories), ``fsr_dynamics`` (creep,
flow, hysteresis), ``fsr_record`` (runs and their record file), ``fsr_presets`` (named
sensors, e.g. ``real_like_fsr()``); every public name is importable from here.

Symbols and units
-----------------
``F`` applied (true) force, N; ``t`` time since the start of the run, s; ``G`` conductance, S;
``R`` resistance, ohm. Parameter names carry their units (``FsrParams``).

1. Static curve (power law)
    ``G_static(F) = g_run k F^n_run`` for ``F > F_th``, and ``G = 0`` (open) for
    ``F <= F_th``. ``k`` (``k_s``) is the conductance at 1 N, S (i.e. S/N^n); ``n``
    (``exponent``) is dimensionless; ``F_th`` (``threshold_n``) is the contact threshold, N.
    A leakage resistance ``R_leak`` (``leakage_ohm``, default inf: none) is in parallel at
    all forces, so the sensor reads ``R = 1 / (G + 1/R_leak)`` (inf when both are 0).
    Defaults k = 5e-5 S, n = 0.8: R = 72.4 kohm at 0.2 N, 8.8 kohm at 5 N, 1.05 kohm at
    40 N on the static curve. (A power law through both 50 kohm at 0.2 N and 1-2 kohm at
    40 N would need n = 0.61-0.74; n = 0.8, the low end of the usual 0.8-1.1, is the
    compromise.)

2. Creep on an effective force (Burgers-like)
    The static curve is evaluated at an effective force
    ``F_eff = F + x1 + x2 + phi`` (N, plus the creep chain's states, 2b), where

    - two Kelvin elements relax towards a fraction of the applied force,
      ``dx_i/dt = (a_i F - x_i) / tau_i`` (``a_fast``, ``tau_fast_s``; ``a_slow``,
      ``tau_slow_s``); a held step F reaches ``x_i = a_i F (1 - exp(-t/tau_i))``;
    - a dashpot's accumulated flow ``phi`` (N) grows while the sensor is loaded (``F > F_th``)
      and recovers while it is unloaded (``F <= F_th``)::

          dphi/dt = F / eta            if F > F_th   (eta = ``eta_flow_s``, s)
          dphi/dt = -phi / tau_rec     if F <= F_th  (tau_rec = ``tau_recovery_s``, s)

      A true Burgers dashpot never recovers; here the flow relaxes slowly after unloading,
      so a low load after a high one reads high for a while (minutes).

    All states start at 0 (a rested sensor). Integration is exact: the emulator builds its
    own fine grid, every protocol knot and every crossing of ``F_th`` is a grid node and each
    protocol segment is cut into equal sub-steps of at most ``internal_step_s``, so the force
    is linear (slope ``s``, N/s) within each sub-step h, and each Kelvin element is advanced
    by the exact exponential update for a linear input::

        x(t+h) = c x(t) + a [F(t+h) - c F(t) + tau s expm1(-h/tau)],   c = exp(-h/tau)

    (a linear recurrence, evaluated per segment with ``scipy.signal.lfilter``); the flow by
    ``phi(t+h) = phi(t) + h (F(t) + F(t+h)) / (2 eta)`` (loaded) or ``phi(t) exp(-h/tau_rec)``
    (unloaded). A sample at time t between two nodes is propagated from the node before it
    by the same formulas with h = t - t_node. The states at the samples are therefore exact
    and do not depend on the sampling times (nor, beyond rounding, on ``internal_step_s``).

2b. Creep chain: loading and recovery time constants differ (``creep_chain``, off by default)
    Each ``CreepElement`` (``amplitude`` a, ``tau_load_s``, ``tau_recovery_s``) adds a state
    ``x`` (N, 0 at the start) to ``F_eff`` that relaxes towards ``a F``::

        dx/dt = (a F - x) / tau,  tau = tau_load if |a F| > |x| (charging) else tau_recovery

    A held step F from rest gives ``x = a F (1 - exp(-t/tau_load))``; a step down from a
    charged ``x0`` to F' gives ``x = a F' + (x0 - a F') exp(-t/tau_recovery)``. With a > 0 the
    element is creep (the reading rises under a held load); with a < 0 it is a *set*: after a
    high load the sensor reads low at a lower load and recovers with ``tau_recovery``. The
    update is exact on each linear piece of the protocol (the regime changes at most once
    on a piece, at a time solved in closed form; ``fsr_dynamics.chain_element_states``).
    ``F_eff <= 0`` (a large set at a low load) is no contact: G = 0.

3. Rate-independent hysteresis (Preisach-style, play operators)
    Play (backlash) operators of half-widths ``r_j`` (``hysteresis_widths_n``, N) act on F:
    ``p_j <- max(F - r_j, min(F + r_j, p_j))``, ``p_j = 0`` at the start (virgin sensor).
    Their normalised states ``d_j = (F - p_j) / r_j`` lie in [-1, 1]: +1 after loading by at
    least ``2 r_j``, -1 after unloading. The conductance is multiplied by
    ``1 + H``, ``H = -A sum_j w_j d_j`` (``hysteresis_amplitude`` A, weights ``w_j`` summing
    to 1, equal by default): loading reads lower than unloading at the same force. On virgin
    loading ``H = -A sum_j w_j min(F / r_j, 1)``; unloading from ``F_max`` gives
    ``d_j = max(-1, 1 - (F_max - F) / r_j)``. Defaults A = 0.07, r = 0.5, 1, 2, 4, 8 N: -7 %
    on loading and +7 % on unloading at mid-range (once F has moved 2 x 8 = 16 N from the
    last reversal, or 8 N from a virgin start). The operators are evaluated exactly at every
    sample (the protocol is monotone between its knots, where it reverses), so the loop is
    the same at any loading rate.

4. Sensitivity changing between runs
    Each run r draws, from ``SeedSequence([seed, r])``: a gain ``g_run = exp(clip(sigma_g z1,
    -ln(M)/2, ln(M)/2))`` on k (``gain_sigma`` sigma_g, ``gain_max_ratio`` M: any two runs
    differ by at most M), an exponent ``n_run = n + sigma_n z2`` (``exponent_sigma``), a load
    cell zero offset ``sigma_0 z3`` (``load_cell_offset_sigma_n``) and a humidity phase
    ``U(0, 2 pi)``; z ~ N(0, 1). The draws are kept in ``RunConditions``. ``run_gains``
    (e.g. ``(1.0, 2.0)``) sets the gains instead: run r has ``run_gains[r % len]``; a gain
    of 2 doubles G and so halves the sensor's resistance at every load.

5. Two-wire ohmmeter
    The reading is ``(R + R_lead) (1 + sigma_R z)`` (``lead_ohm``, ``ohmmeter_noise_rel``),
    or ``R + R_lead + z sqrt((sigma_R (R + R_lead))^2 + sigma_abs^2)`` with an absolute
    noise ``sigma_abs`` (``ohmmeter_noise_ohm``, ohm rms) besides,
    quantised like a 4.5-digit auto-ranging meter (``ohmmeter_reading``): ranges of full
    scale ``R_min 10^j`` (``ohmmeter_min_range_ohm`` = 200 ohm, 2 k, 20 k, ... up to
    ``ohmmeter_max_range_ohm``), each read in ``ohmmeter_counts`` counts (20000: resolution
    full scale / 20000); the lowest range whose count is below 20000 is used; above the top
    range, and for an open circuit, the reading is inf. ``ohmmeter_counts = 0``: an ideal
    meter (no quantisation, no range limit).

6. Load cell reference
    ``force_n = F(t - lag) + offset_run + sigma_F z`` (``load_cell_noise_n``; ``lag`` =
    ``load_cell_lag_s``, default 0: the reference reads the force applied that long before
    the resistance is read; F = 0 before the start), rounded to
    ``load_cell_resolution_n``; the indicator shows no negative force (readings below 0 are
    0, as the record format requires force_n >= 0).

7. Timestamps
    ``t_0 = 0``, ``t_{i+1} = t_i + dt (1 + j u_i)``, u_i ~ U(-1, 1) (``jitter_fraction`` j < 1,
    dt = ``sample_interval_s``): strictly increasing, intervals within ``dt (1 +- j)``. The run
    is sampled until the protocol's end. In bursts (``burst_size`` B > 0): every B-th interval
    is ``burst_gap_s + j dt u_i`` instead (B samples dt apart, then a gap).

8. Out-of-catalogue effects (off by default; not in the gateway's effect catalogue)
    - ``wear_per_cycle`` w: during the m-th loading of the sensor (m = 1, 2, ..., counted at
      each unload-to-load crossing of ``F_th``, plus ``prior_cycles`` before the run) k is
      multiplied by ``(1 - w)^(m - 1)``;
    - ``rate_gain_s`` b (s): G is multiplied by ``max(0.1, 1 + b (dF/dt) / F_fs)`` with the
      protocol's slope dF/dt (N/s) and ``full_scale_n`` F_fs (a viscous rate dependence);
    - ``humidity`` h: G is multiplied by ``1 + h sin(2 pi t / P + phase_run)``
      (``humidity_period_s`` P), a slow drift unrelated to the load.

The sensor's conductance is therefore::

    G = g_run k (1 - w)^(m - 1) F_eff^n_run (1 + H) rate_factor humidity_factor  (F > F_th, F_eff > 0)

``EmulatedRecord.static_resistance_ohm`` is ``1 / (g_run k F^n_run + 1/R_leak)`` (the run's
static curve at the true force, no creep, hysteresis, wear, rate or humidity, no lead).

Protocols (``Protocol``) are piecewise-linear load histories starting at 0 N, built from
``Ramp`` (to a level at a rate) and ``Hold`` steps; builders ``hold_protocol``,
``staircase``, ``calibration_run``, ``alternating_holds`` (slow loading: holds at 25.5 N and
3.3 N in turn) and ``calibration_ramp`` (one slow ramp to 49 N and a hold).
``write_record`` writes runs in the project's record format (``docs/record-format.md``),
time continuing across runs. ``EmulatedRecord.static_force_n()`` reads a resistance back
through the run's static curve (a static lookup, as a reader without a creep model would).

Example::

    emu = FsrEmulator(FsrParams(), seed=1)
    records = emu.run_many(calibration_run(), n_runs=3)
    write_record("fsr.csv", records)

    real = FsrEmulator(real_like_fsr(), seed=1)
    write_record("slow.csv", [real.run(alternating_holds(), 0, REAL_LIKE_SAMPLE_INTERVAL_S)])
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .fsr_dynamics import dynamics
from .fsr_params import CreepElement, FloatArray, FsrParams, RunConditions, require, require_finite
from .fsr_presets import PRESETS, REAL_LIKE_SAMPLE_INTERVAL_S, fast_creep_fsr, real_like_fsr
from .fsr_protocol import (
    DEFAULT_HOLD_LEVELS_N,
    PROTOCOLS,
    Hold,
    Protocol,
    Ramp,
    alternating_holds,
    calibration_ramp,
    calibration_run,
    hold_protocol,
    staircase,
)
from .fsr_record import EmulatedRecord, write_record

__all__ = [
    "DEFAULT_HOLD_LEVELS_N",
    "PRESETS",
    "PROTOCOLS",
    "REAL_LIKE_SAMPLE_INTERVAL_S",
    "CreepElement",
    "EmulatedRecord",
    "FsrEmulator",
    "FsrParams",
    "Hold",
    "Protocol",
    "Ramp",
    "RunConditions",
    "alternating_holds",
    "calibration_ramp",
    "calibration_run",
    "fast_creep_fsr",
    "hold_protocol",
    "ohmmeter_reading",
    "real_like_fsr",
    "staircase",
    "write_record",
]

_MIN_RATE_FACTOR = 0.1


def ohmmeter_reading(
    resistance_ohm: FloatArray | Sequence[float],
    counts: int = 20000,
    min_range_ohm: float = 200.0,
    max_range_ohm: float = 20e6,
) -> FloatArray:
    """What an auto-ranging ohmmeter of ``counts`` counts per range displays (noise-free).

    Ranges have full scales ``min_range_ohm * 10^j`` up to ``max_range_ohm``; a range shows
    ``round(R / (full_scale / counts))`` counts, valid below ``counts``; the lowest valid range
    is used. Beyond the top range, and for inf, the reading is inf. ``counts = 0``: no
    quantisation and no range limit.
    """
    r = np.asarray(resistance_ohm, dtype=np.float64)
    if counts == 0:
        return r.copy()
    out = np.full(r.shape, np.inf)
    finite = np.isfinite(r) & (r >= 0.0)
    x = r[finite]
    with np.errstate(divide="ignore"):
        j = np.floor(np.log10(np.maximum(x, 1e-300) / min_range_ohm)) + 1.0
    j = np.maximum(j, 0.0)
    n_ranges = math.floor(math.log10(max_range_ohm / min_range_ohm) + 1e-9) + 1
    value = np.full(x.shape, np.inf)
    pending = np.ones(x.shape, dtype=bool)
    for _ in range(2):  # the estimate j, or one range up when rounding reaches ``counts``
        full_scale = min_range_ohm * 10.0**j
        q = np.round(x / (full_scale / counts))
        ok = pending & (q < counts) & (j < n_ranges)
        shown = q * full_scale / counts  # 12345 * 2000 / 20000 = 1234.5, not 12345 * 0.1
        value = np.where(ok, shown, value)
        pending &= ~ok
        j = j + 1.0
    out[finite] = value
    return out


@dataclass(frozen=True)
class FsrEmulator:
    """Emulates runs of one FSR; deterministic for a given ``seed`` and run index."""

    params: FsrParams = field(default_factory=FsrParams)
    seed: int = 0

    def __post_init__(self) -> None:
        ok = int(self.seed) == self.seed and self.seed >= 0
        require(ok, f"seed must be an int >= 0, got {self.seed!r}")

    def _generators(self, run_index: int) -> tuple[np.random.Generator, np.random.Generator]:
        require(int(run_index) == run_index and run_index >= 0, f"run_index must be >= 0, got {run_index!r}")
        a, b = np.random.SeedSequence([int(self.seed), int(run_index)]).spawn(2)
        return np.random.default_rng(a), np.random.default_rng(b)

    def conditions(self, run_index: int, prior_cycles: int = 0) -> RunConditions:
        """The run's sensitivity gain, exponent, load cell offset and humidity phase (the gain
        is ``run_gains[run_index % len(run_gains)]`` when ``run_gains`` is given)."""
        p = self.params
        rng, _ = self._generators(run_index)
        z = rng.standard_normal(3)
        phase = float(rng.uniform(0.0, 2.0 * math.pi))
        half = 0.5 * math.log(p.gain_max_ratio)
        gain = math.exp(min(max(p.gain_sigma * float(z[0]), -half), half))
        if p.run_gains:
            gain = p.run_gains[int(run_index) % len(p.run_gains)]
        return RunConditions(
            gain=gain,
            exponent=p.exponent + p.exponent_sigma * float(z[1]),
            load_cell_offset_n=p.load_cell_offset_sigma_n * float(z[2]),
            humidity_phase_rad=phase,
            prior_cycles=prior_cycles,
        )

    def run(
        self,
        protocol: Protocol,
        run_index: int = 0,
        sample_interval_s: float = 0.1,
        *,
        prior_cycles: int = 0,
    ) -> EmulatedRecord:
        """Play ``protocol`` on a rested sensor and record it every ``sample_interval_s`` (+ jitter)."""
        p = self.params
        require_finite(sample_interval_s, "sample_interval_s", low=0.0, strict=True)
        require(prior_cycles >= 0, "prior_cycles must be >= 0")
        cond = self.conditions(run_index, prior_cycles)
        _, rng = self._generators(run_index)

        # 7. timestamps
        duration = protocol.duration_s
        shortest = sample_interval_s * (1.0 - p.jitter_fraction)
        if p.burst_size > 0:
            jitter_s = p.jitter_fraction * sample_interval_s
            require(
                p.burst_gap_s > jitter_s,
                f"burst_gap_s must be > jitter_fraction x sample_interval_s = {jitter_s:g} s, "
                f"got {p.burst_gap_s!r}",
            )
            shortest = min(shortest, p.burst_gap_s - jitter_s)
        n_max = math.ceil(duration / shortest) + 2
        steps = sample_interval_s * (1.0 + p.jitter_fraction * rng.uniform(-1.0, 1.0, n_max))
        if p.burst_size > 0:
            steps[p.burst_size - 1 :: p.burst_size] += p.burst_gap_s - sample_interval_s
        t = np.concatenate(([0.0], np.cumsum(steps)))
        t = t[t <= duration * (1.0 + 1e-12)]
        noise_r = rng.standard_normal(t.size)
        noise_f = rng.standard_normal(t.size)

        dyn = dynamics(p, protocol, t)
        force, f_eff, hyst, slope, cycle_no = (
            dyn.force_n,
            dyn.effective_force_n,
            dyn.hysteresis,
            dyn.slope_n_per_s,
            dyn.cycle_no,
        )

        # 1-4, 8: conductance
        loaded = force > p.threshold_n
        gain = cond.gain * p.k_s
        g_static = np.where(loaded, gain * np.power(np.maximum(force, 1e-300), cond.exponent), 0.0)
        wear = (1.0 - p.wear_per_cycle) ** (np.maximum(cycle_no - 1, 0) + prior_cycles)
        rate = np.maximum(_MIN_RATE_FACTOR, 1.0 + p.rate_gain_s * slope / p.full_scale_n)
        humid = 1.0 + p.humidity * np.sin(2.0 * math.pi * t / p.humidity_period_s + cond.humidity_phase_rad)
        # a set (negative creep chain) can take F_eff to 0 or below: no contact, G = 0
        contact = f_eff > 0.0
        g_dyn = gain * np.power(np.where(contact, f_eff, 1.0), cond.exponent) * (1.0 + hyst)
        g_dyn = np.where(contact, g_dyn, 0.0)
        g = np.where(loaded, g_dyn * wear * rate * humid, 0.0)
        r_sensor = _resistance(g, p.leakage_ohm)
        r_static = _resistance(g_static, p.leakage_ohm)

        # 5. ohmmeter
        if p.ohmmeter_noise_ohm > 0.0:
            wired = r_sensor + p.lead_ohm
            finite = np.isfinite(wired)
            base = np.where(finite, wired, 0.0)
            sigma = np.hypot(p.ohmmeter_noise_rel * base, p.ohmmeter_noise_ohm)
            noisy = np.where(finite, np.maximum(base + sigma * noise_r, 1e-6 * base), np.inf)
        else:
            noisy = (r_sensor + p.lead_ohm) * np.maximum(1.0 + p.ohmmeter_noise_rel * noise_r, 1e-6)
        reading = ohmmeter_reading(
            noisy, p.ohmmeter_counts, p.ohmmeter_min_range_ohm, p.ohmmeter_max_range_ohm
        )

        # 6. load cell
        lagged = protocol.force_at(t - p.load_cell_lag_s) if p.load_cell_lag_s > 0.0 else force
        cell = lagged + cond.load_cell_offset_n + p.load_cell_noise_n * noise_f
        if p.load_cell_resolution_n > 0.0:
            cell = np.round(cell / p.load_cell_resolution_n) * p.load_cell_resolution_n
        cell = np.maximum(cell, 0.0)

        return EmulatedRecord(
            time_s=t,
            force_n=cell,
            true_force_n=force,
            resistance_ohm=reading,
            sensor_resistance_ohm=r_sensor,
            static_resistance_ohm=r_static,
            effective_force_n=f_eff,
            run=int(run_index),
            conditions=cond,
            cycles=dyn.cycles,
            protocol_name=protocol.name,
            seed=int(self.seed),
            params=p,
            sample_interval_s=float(sample_interval_s),
        )

    def run_many(
        self, protocol: Protocol, n_runs: int, sample_interval_s: float = 0.1
    ) -> list[EmulatedRecord]:
        """Runs 0 .. n_runs-1 of ``protocol``; wear carries over from run to run."""
        require(n_runs >= 1, f"n_runs must be >= 1, got {n_runs}")
        out: list[EmulatedRecord] = []
        prior = 0
        for i in range(n_runs):
            rec = self.run(protocol, i, sample_interval_s, prior_cycles=prior)
            prior += rec.cycles
            out.append(rec)
        return out


def _resistance(conductance_s: FloatArray, leakage_ohm: float) -> FloatArray:
    g = conductance_s + (0.0 if math.isinf(leakage_ohm) else 1.0 / leakage_ohm)
    with np.errstate(divide="ignore"):
        return np.asarray(np.where(g > 0.0, 1.0 / np.where(g > 0.0, g, 1.0), np.inf))
