"""A channel's conversion from a calibration table: every kind loads into one ``CurveChannel``.

``tactile-gateway calibrate --model line|lookup|curve|auto`` writes, for a channel whose
physical model loses on held-out force, a ``[line.<name>]``, ``[lookup.<name>]`` or
``[curve.<name>]`` table (``docs/calibration.md``). All three are read into the one calibration
form, ``calibrated.CurveChannel`` (a static line or lookup is a curve without dynamics), and
tracked by the one tracker (``tracker.CurveSet``): one set of force and status rules whatever
the table. ``line_conversion`` and ``lookup_conversion`` build the static ones from values.
"""

from __future__ import annotations

from collections.abc import Mapping

from .calibrated import CONVERSION_KINDS, ZERO_FORCE_N, CurveChannel, channel_from_table
from .frontend_base import FrontEnd
from .static_curves import CurveError

__all__ = [
    "CONVERSION_KINDS",
    "ZERO_FORCE_N",
    "Conversion",
    "ConversionError",
    "conversion_from_table",
    "line_conversion",
    "lookup_conversion",
]

#: A conversion's value outside its allowed range (``key`` names the field).
ConversionError = CurveError
#: What a calibrated channel is read with.
Conversion = CurveChannel


def conversion_from_table(
    kind: str,
    data: Mapping[str, object],
    force_min_n: float,
    force_max_n: float,
    front_end: FrontEnd | None = None,
) -> CurveChannel:
    """The channel of a calibration file's ``[line]``, ``[lookup]`` or ``[curve]`` table; a
    line without its own force range takes the channel's (``force_min_n``/``force_max_n``); a
    lookup is read in the domain it was given in (``resistance_ohm``: ln R; ``counts``: the
    code of ``front_end``, the device's ADC front end). ``ConversionError`` names the key."""
    return channel_from_table(kind, data, force_min_n, force_max_n, front_end)


def line_conversion(
    slope_s_per_n: float, intercept_s: float, force_min_n: float, force_max_n: float
) -> CurveChannel:
    """A ``[line]`` table's channel: F = (1/R - n) / m over [force_min_n, force_max_n]."""
    return channel_from_table(
        "line",
        {
            "slope_s_per_n": slope_s_per_n,
            "intercept_s": intercept_s,
            "force_min_n": force_min_n,
            "force_max_n": force_max_n,
        },
        force_min_n,
        force_max_n,
    )


def lookup_conversion(resistance_ohm: tuple[float, ...], force_n: tuple[float, ...]) -> CurveChannel:
    """A ``[lookup]`` table in ``resistance_ohm``: F against ln R through the knots."""
    return channel_from_table(
        "lookup", {"resistance_ohm": list(resistance_ohm), "force_n": list(force_n)}, 0.0, 0.0
    )
