"""Read-out front ends: the circuit between the sensor and the ADC, both ways (numpy only).

The paper reads its sensor through a voltage divider (Fig. 4b, eq. 18)::

    V_o = R_ref / (R_ref + r) * V+      =>      r = R_ref (V+ / V_o - 1)

with the sensor r from the supply V+ to the output node and R_ref from the output to ground
(``Divider``, kind ``"high_side"``). Two other common read-outs are modelled the same way:

* ``LowSideDivider`` (``"low_side"``): R_ref is a pull-up from the supply to the output node,
  the sensor goes from the output to ground: ``V_o = V+ r / (R_ref + r)``, ``r = R_ref V_o /
  (V+ - V_o)``.
* ``RatioFrontEnd`` (``"ratio"``): a ratiometric divider of unknown values, read as the
  sensor resistance in units of its reference resistor, ``r / R_ref`` (the high-side or the
  low-side divider with ``V+ = 1`` and ``R_ref = 1``, by whether the counts rise with load):
  no circuit value is assumed, and forces need a calibration in those units.
* ``Transimpedance`` (``"transimpedance"``): the sensor, driven by a bias voltage V_b, feeds
  the virtual ground of an op-amp with feedback resistor R_f: ``V_o = V_os + V_b R_f / r``
  (the magnitude of the inverting output, plus the amplifier's output offset V_os), ``r = V_b
  R_f / (V_o - V_os)``.

Every front end ends in the same ideal ADC: ``code = offset + V_o / V_ref * FS`` rounded half
to even and clipped to ``[0, FS]``, ``FS = 2^bits - 1``, where ``offset`` is a constant code
the converter or amplifier adds. Reading a code back:

* not a number, negative or above FS: NaN, ``INVALID``;
* at or beyond the code an open sensor gives (``rint`` of its exact code): +inf, ``OPEN``;
* at or beyond the code a shorted sensor gives: 0, ``SHORT``;
* at an ADC rail (0 or FS) that is neither: the resistance at that rail, ``SATURATED`` (the
  true voltage is beyond the converter's range, so the resistance is only known to be beyond
  the measurable range, of which this is the bound);
* otherwise the exact algebraic inverse, ``OK``.

``docs/front-ends.md`` works each topology through with numbers.

The shared part (``FrontEnd``, ``DividerStatus``, the ADC) is in ``frontend_base``, the two
dividers in ``frontend_dividers``, the ratio read-out in ``frontend_ratio``, the
transimpedance stage in ``frontend_transimpedance``;
this module re-exports them and builds a front end from its configuration ``kind``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from .frontend_base import DividerStatus, FloatArray, FrontEnd, StatusArray
from .frontend_dividers import Divider, LowSideDivider
from .frontend_ratio import RatioFrontEnd
from .frontend_transimpedance import Transimpedance

__all__ = [
    "FRONT_END_KINDS",
    "Divider",
    "DividerStatus",
    "FloatArray",
    "FrontEnd",
    "LowSideDivider",
    "RatioFrontEnd",
    "StatusArray",
    "Transimpedance",
    "front_end_from_kind",
]

_FRONT_ENDS: dict[str, type[FrontEnd]] = {
    cls.kind: cls for cls in (Divider, LowSideDivider, Transimpedance, RatioFrontEnd)
}

#: The ``kind`` names of the front ends, as written in configuration files.
FRONT_END_KINDS: tuple[str, ...] = tuple(_FRONT_ENDS)


def front_end_from_kind(kind: str, **params: Any) -> FrontEnd:
    """The front end of a ``kind`` built from keyword parameters; ``ValueError`` naming an
    unknown kind, unknown or missing parameters (with the allowed ones), or a bad value."""
    cls = _FRONT_ENDS.get(kind)
    if cls is None:
        raise ValueError(f"unknown front end kind {kind!r}; allowed kinds: {', '.join(FRONT_END_KINDS)}")
    allowed = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    unknown = [k for k in params if k not in allowed]
    if unknown:
        raise ValueError(
            f"unknown parameter{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} for front "
            f"end kind {kind!r}; allowed parameters: {', '.join(allowed)}"
        )
    required = [
        f.name
        for f in dataclasses.fields(cls)  # type: ignore[arg-type]
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    missing = [k for k in required if k not in params]
    if missing:
        raise ValueError(
            f"missing parameter{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))} for front "
            f"end kind {kind!r}; required: {', '.join(required)}"
        )
    return cls(**params)
