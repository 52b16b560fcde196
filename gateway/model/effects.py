"""Named, switchable model effects (the names of ``docs/record-format.md``) and their table.

A model is the ``tunneling`` baseline plus a set of named effects. Each effect is a submodel
(``submodels/<effect>.py``) with a null variant that adds nothing (zero added resistance,
zero added strain, an infinite parallel path, a unit temperature factor), so switching one
off reduces the model exactly to the one without it. ``EFFECTS`` is the table: adding an
effect is one new submodel module and one row here.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

from .submodels import (
    Contact,
    Creep,
    Creep2,
    Hysteresis,
    Leakage,
    NoContact,
    NoCreep,
    NoCreep2,
    NoHysteresis,
    NoLeakage,
    NoSeriesResistance,
    NoTemperature,
    SeriesResistance,
    Submodel,
    Temperature,
    Tunneling,
)

#: Every effect of the interchange contract, in canonical order: (on form, off form).
EFFECTS: dict[str, tuple[type[Submodel], type[Submodel] | None]] = {
    "tunneling": (Tunneling, None),
    "contact": (Contact, NoContact),
    "creep": (Creep, NoCreep),
    "creep2": (Creep2, NoCreep2),
    "hysteresis": (Hysteresis, NoHysteresis),
    "temperature": (Temperature, NoTemperature),
    "series_resistance": (SeriesResistance, NoSeriesResistance),
    "leakage": (Leakage, NoLeakage),
}

#: Every effect name of the interchange contract, in canonical order.
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)

#: What each effect adds, in words (for help texts and reports).
EFFECT_DESCRIPTIONS: dict[str, str] = {name: on.description for name, (on, _) in EFFECTS.items()}

#: The sensor parameters each effect brings into a fit.
EFFECT_PARAMETERS: dict[str, tuple[str, ...]] = {name: on.parameters for name, (on, _) in EFFECTS.items()}

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
