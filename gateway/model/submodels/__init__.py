"""The model's effects as submodels, each with its null variant (see ``base``).

One module per effect of ``docs/record-format.md``: ``tunneling`` (the baseline, always on),
``contact``, ``creep``, ``creep2``, ``hysteresis``, ``temperature``, ``series_resistance``,
``leakage``. ``gateway.model.effects.EFFECTS`` is the table of their two forms.
"""

from .base import Factor, ParallelPath, SeriesTerm, StrainState, Submodel
from .contact import Contact, NoContact
from .creep import Creep, NoCreep
from .creep2 import Creep2, NoCreep2
from .hysteresis import HYSTERESIS_DEAD_BAND, Hysteresis, NoHysteresis
from .leakage import Leakage, NoLeakage
from .series_resistance import NoSeriesResistance, SeriesResistance
from .temperature import NoTemperature, Temperature
from .tunneling import Tunneling

__all__ = [
    "HYSTERESIS_DEAD_BAND",
    "Contact",
    "Creep",
    "Creep2",
    "Factor",
    "Hysteresis",
    "Leakage",
    "NoContact",
    "NoCreep",
    "NoCreep2",
    "NoHysteresis",
    "NoLeakage",
    "NoSeriesResistance",
    "NoTemperature",
    "ParallelPath",
    "SeriesResistance",
    "SeriesTerm",
    "StrainState",
    "Submodel",
    "Temperature",
    "Tunneling",
]
