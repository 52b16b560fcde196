"""Named emulated FSRs: parameter sets of ``FsrParams`` for sensors that fail like real ones.

``real_like_fsr()``
    Chosen by hand so that its records have the shapes of real records of one FSR read by a
    2-wire multimeter against a load cell (records not in the repository): a power-law
    static curve ``G = k F^n`` with a parallel leakage, a creep chain whose creep is small and
    whose *set* is large and recovers slowly, and per-run sensitivity changes of up to 2x.
    Run on ``alternating_holds()`` (``slow-loading``) and ``calibration_ramp()``
    (``calibration-ramp``) with ``REAL_LIKE_SAMPLE_INTERVAL_S``:

    - in a 25.5 N hold (after 13 s at 3.3 N) the conductance still rises a little: the static
      reading goes from 24.49 N 2 s into the hold to 24.83 N at 20 s (+0.69 % of 49 N, ln G
      +0.02): the loading creep;
    - a 3.3 N hold right after 20 s at 25.5 N starts *low*: 0.5 s into it ln G is 0.55 below
      the same load after rest (the static reading 2.20 N), and it rises quickly for a
      second, then slowly, to 0.19 below at 10 s (2.81 N): the set recovers with time
      constants (0.8 s, 12 s) other than the ones it loads with (0.1 s, 0.3 s), and the
      creep recovers within 0.05 s: recovery is not the mirror image of creep;
    - a slow set (150 s to load, 1500 s to recover) lowers the low-load readings over the
      cycles of a run;
    - the sensitivity changes from run to run: gain ``exp(clip(0.3 z, +-ln(2)/2))``, any two
      runs within 2x, and the exponent by 0.05 rms;
    - the force column lags the resistance by 0.4 s, samples come in bursts of 5 about
      0.02 s apart with 0.12 s between bursts, and the meter's noise is 0.3 % plus 60 ohm rms.

    (Those figures are the sensor's own, at instants, from its creep chain; the tests in
    ``tests/unit/sim_device/test_fsr_presets.py`` work them out by hand.)

``fast_creep_fsr()``
    A sensor with fast, strong creep: a 25.5 N hold from rest drifts by 25 % of 49 N on its
    static curve from 2 s to 20 s into the hold (36.06 N to 48.34 N; quickly at first, then
    slowly), and after unloading its resistance stays low and recovers over minutes
    (recovery time constants 10-17 x its loading ones): 3.3 N read as 20.9 N 10 s after 20 s
    at 25.5 N. Its static curve and bench are those of ``real_like_fsr()``.

Both are functions returning a fresh ``FsrParams``; change a field with
``dataclasses.replace(real_like_fsr(), gain_sigma=0.0)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

from .fsr_params import CreepElement, FsrParams

__all__ = ["PRESETS", "REAL_LIKE_SAMPLE_INTERVAL_S", "fast_creep_fsr", "real_like_fsr"]

#: The sampling interval within a burst that goes with ``real_like_fsr()``, s.
REAL_LIKE_SAMPLE_INTERVAL_S = 0.02

#: The creep chain of ``real_like_fsr()``: (amplitude, tau_load_s, tau_recovery_s).
REAL_LIKE_CHAIN: tuple[CreepElement, ...] = (
    CreepElement(+0.020, 3.0, 0.05),  # creep, recovers at once on unloading
    CreepElement(+0.015, 30.0, 0.05),
    CreepElement(-0.012, 0.1, 0.8),  # set: loads within a ramp, recovers in about a second
    CreepElement(-0.040, 0.3, 12.0),
    CreepElement(-0.015, 150.0, 1500.0),  # set that builds up over the cycles of a run
)

#: The creep chain of ``fast_creep_fsr()``.
FAST_CREEP_CHAIN: tuple[CreepElement, ...] = (
    CreepElement(0.3, 1.0, 10.0),
    CreepElement(0.5, 6.0, 100.0),
    CreepElement(0.4, 60.0, 600.0),
)


def real_like_fsr() -> FsrParams:
    """An FSR whose records have the shapes of real ones (see the module docstring)."""
    return FsrParams(
        k_s=3.5e-6,  # S at F_eff = 1 N: 286 kohm (before the leakage), 2.6 kohm at 25.5 N
        exponent=1.45,
        threshold_n=0.05,
        leakage_ohm=270e3,  # what the unloaded sensor reads
        a_fast=0.0,
        a_slow=0.0,
        eta_flow_s=math.inf,
        hysteresis_amplitude=0.0,  # the set makes unloading read low instead
        creep_chain=REAL_LIKE_CHAIN,
        gain_sigma=0.3,
        gain_max_ratio=2.0,
        exponent_sigma=0.05,
        lead_ohm=1.0,
        ohmmeter_noise_rel=0.003,
        ohmmeter_noise_ohm=60.0,
        ohmmeter_counts=2_000_000,
        load_cell_noise_n=0.01,
        load_cell_resolution_n=0.0001,
        load_cell_lag_s=0.4,
        jitter_fraction=0.5,
        burst_size=5,
        burst_gap_s=0.12,
    )


def fast_creep_fsr() -> FsrParams:
    """An FSR with fast, strong creep and slow recovery (see the module docstring)."""
    return replace(real_like_fsr(), creep_chain=FAST_CREEP_CHAIN)


#: The presets the command line offers, by name.
PRESETS: dict[str, Callable[[], FsrParams]] = {
    "default": FsrParams,
    "real-like": real_like_fsr,
    "fast-creep": fast_creep_fsr,
}
