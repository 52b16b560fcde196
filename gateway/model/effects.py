"""Named, switchable model effects (the names of ``shared/spec/measurement-records.md``).

A model is the ``tunneling`` baseline plus a set of named effects. Each effect is a term
with an "off" form (zero added resistance, zero added strain, an infinite parallel path,
a unit temperature factor), so switching one off reduces the model exactly to the one
without it.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

#: Every effect name of the interchange contract, in canonical order.
EFFECT_NAMES: tuple[str, ...] = (
    "tunneling",
    "contact",
    "creep",
    "creep2",
    "hysteresis",
    "temperature",
    "series_resistance",
    "leakage",
)

#: What each effect adds, in words (for help texts and reports).
EFFECT_DESCRIPTIONS: dict[str, str] = {
    "tunneling": "polymer resistance from inter-particle tunneling (eq. 2-9), always on",
    "contact": "Holm contact resistance of the two electrodes (eq. 10-12)",
    "creep": "standard-linear-solid creep, one Kelvin element (eq. 14-16, 19)",
    "creep2": "a second, slower Kelvin element (Prony series)",
    "hysteresis": "loading and unloading follow different curves at the same force",
    "temperature": "polymer resistance depends on sensor temperature",
    "series_resistance": "a constant resistance in series (leads, traces)",
    "leakage": "a constant resistance in parallel that caps the unloaded resistance",
}

#: The sensor parameters each effect brings into a fit.
EFFECT_PARAMETERS: dict[str, tuple[str, ...]] = {
    "tunneling": ("r0_ohm", "e0_pa", "e0_slope_pa_per_n"),
    "contact": ("rho2_ohm_m",),
    "creep": ("e1_pa", "e1_slope_pa_per_n", "mu1_pa_s", "mu1_slope_pa_s_per_n"),
    "creep2": ("e2_pa", "mu2_pa_s"),
    "hysteresis": ("hysteresis_strain", "hysteresis_force_n"),
    "temperature": ("temperature_coeff_per_k",),
    "series_resistance": ("series_resistance_ohm",),
    "leakage": ("leakage_resistance_ohm",),
}

#: The paper's full model (eq. 17).
PAPER_EFFECTS: tuple[str, ...] = ("tunneling", "contact", "creep")


class UnknownEffectError(ValueError):
    """An effect name that is not part of the contract."""


def parse_effects(names: str | Iterable[str]) -> tuple[str, ...]:
    """Validate effect names and return them in canonical order, ``tunneling`` included.

    Accepts a comma-separated string or an iterable. An unknown name raises
    ``UnknownEffectError`` naming the closest valid effect.
    """
    items = names.split(",") if isinstance(names, str) else list(names)
    chosen = {"tunneling"}
    for raw in items:
        name = raw.strip()
        if not name:
            continue
        if name not in EFFECT_NAMES:
            close = difflib.get_close_matches(name, EFFECT_NAMES, n=1, cutoff=0.4)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise UnknownEffectError(f"unknown effect {name!r}{hint} (valid: {', '.join(EFFECT_NAMES)})")
        chosen.add(name)
    return tuple(n for n in EFFECT_NAMES if n in chosen)
