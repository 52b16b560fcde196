"""The piezoresistive sensor model (numpy and scipy only; no I/O, nothing else of ours).

Kalantari et al.: tunneling through the polymer (eq. 1-9), Holm contact resistance
(eq. 10-13), standard-linear-solid creep (eq. 14-17), read out through a divider (eq. 18);
plus the further effects named in ``docs/record-format.md``.

* ``params``: the parameters (``docs/parameters.md`` defaults) and their allowed ranges;
* ``physics``: the paper's equations as vectorized functions;
* ``submodels/``: one module per effect, each with its null variant; ``effects``: their table;
* ``evaluator``: the one evaluator of R(F), its slope, and every term (``ResistanceBreakdown``);
* ``state``: the per-channel state the state-carrying effects own;
* ``inversion``: force from resistance (statuses, Newton solvers);
* ``model``: ``SensorModel``, which puts them together;
* ``series``: ``ForceSeries``, a force history the model is driven with, which keeps what a
  fit's many parameter sets do not change (the state effects' series, the force-only terms);
* ``frontend``: the read-out front ends (``Divider``, the high-side divider of eq. 18;
  ``LowSideDivider``; ``Transimpedance``; ``RatioFrontEnd``, a divider of unknown values read
  in units of its reference resistor) with their ADC, both ways, and the factory by kind;
  ``frontend_base``: what they share (``FrontEnd``, ``DividerStatus``, the ADC);
  ``frontend_dividers``: the two dividers; ``frontend_transimpedance``: the amplifier;
  ``frontend_ratio``: the ratio read-out;
* ``divider``: the paper's conductance line (and ``Divider`` re-exported).
"""

from .effects import (
    EFFECT_DESCRIPTIONS,
    EFFECT_NAMES,
    EFFECT_PARAMETERS,
    EFFECTS,
    PAPER_EFFECTS,
    UnknownEffectError,
    parse_effects,
)
from .evaluator import ResistanceBreakdown
from .frontend import (
    FRONT_END_KINDS,
    Divider,
    DividerStatus,
    FrontEnd,
    LowSideDivider,
    RatioFrontEnd,
    Transimpedance,
    front_end_from_kind,
)
from .inversion import ForceStatus, Inversion
from .model import SensorModel
from .params import ChannelParams, ParameterError, SensorParams, parameter_names
from .state import ModelState

__all__ = [
    "EFFECTS",
    "EFFECT_DESCRIPTIONS",
    "EFFECT_NAMES",
    "EFFECT_PARAMETERS",
    "FRONT_END_KINDS",
    "PAPER_EFFECTS",
    "ChannelParams",
    "Divider",
    "DividerStatus",
    "ForceStatus",
    "FrontEnd",
    "Inversion",
    "LowSideDivider",
    "ModelState",
    "ParameterError",
    "RatioFrontEnd",
    "ResistanceBreakdown",
    "SensorModel",
    "SensorParams",
    "Transimpedance",
    "UnknownEffectError",
    "front_end_from_kind",
    "parameter_names",
    "parse_effects",
]
