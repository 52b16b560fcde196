"""Static curves with drift correction on top, by their owners (the names callers import).

* ``static_curves``: the static forms (power law, conductance line, monotone lookup), with
  their fits, evaluation both ways and tables;
* ``drift``: the dynamic elements (Kelvin chain with recovery, hysteresis);
* ``calibrated``: ``CurveChannel``, one calibrated channel, and its tables;
* ``tracker``: force and status from resistance, sample by sample (``CurveSet``,
  ``track_series``).
"""

from __future__ import annotations

from .calibrated import CurveChannel, curve_from_table
from .drift import DRIFT_FORMS, DRIFT_KEYS, PLAY_SHARES, Drift, kelvin_unit_series, play_direction_series
from .static_curves import (
    CURVE_KINDS,
    CurveError,
    KnotTable,
    LineCurve,
    LookupCurve,
    PowerLawCurve,
    StaticCurve,
    finite_value,
)
from .tracker import CurveSet, CurveState, track_series

__all__ = [
    "CURVE_KINDS",
    "DRIFT_FORMS",
    "DRIFT_KEYS",
    "PLAY_SHARES",
    "CurveChannel",
    "CurveError",
    "CurveSet",
    "CurveState",
    "Drift",
    "KnotTable",
    "LineCurve",
    "LookupCurve",
    "PowerLawCurve",
    "StaticCurve",
    "curve_from_table",
    "finite_value",
    "kelvin_unit_series",
    "play_direction_series",
    "track_series",
]
