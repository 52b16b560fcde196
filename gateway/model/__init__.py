"""The piezoresistive sensor model (numpy and scipy only; no I/O).

Kalantari et al.: tunneling through the polymer (eq. 1-9), Holm contact resistance
(eq. 10-13), standard-linear-solid creep (eq. 14-17), read out through a divider (eq. 18);
plus the further effects named in the measurement-records spec.
"""

from .divider import ConductanceLine, Divider, DividerStatus
from .effects import (
    EFFECT_DESCRIPTIONS,
    EFFECT_NAMES,
    EFFECT_PARAMETERS,
    PAPER_EFFECTS,
    UnknownEffectError,
    parse_effects,
)
from .model import ForceStatus, Inversion, ModelState, ResistanceBreakdown, SensorModel
from .params import ChannelParams, ParameterError, SensorParams, parameter_names

__all__ = [
    "EFFECT_DESCRIPTIONS",
    "EFFECT_NAMES",
    "EFFECT_PARAMETERS",
    "PAPER_EFFECTS",
    "ChannelParams",
    "ConductanceLine",
    "Divider",
    "DividerStatus",
    "ForceStatus",
    "Inversion",
    "ModelState",
    "ParameterError",
    "ResistanceBreakdown",
    "SensorModel",
    "SensorParams",
    "UnknownEffectError",
    "parameter_names",
    "parse_effects",
]
