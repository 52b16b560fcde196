"""Special codes of a frame: raw values that are codes, not readings (``SpecialCodes``).

A device may report a saturated taxel or a fault with reserved raw values (a hand's values
from 65280 up). The configuration lists them (``[bus.device.frame] special``); the decoder
marks each channel's code and the conversion turns it into a status, never a force.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

__all__ = ["SPECIAL_ERROR", "SPECIAL_NONE", "SPECIAL_SATURATED", "SpecialCodes"]

#: What a special code reads as: nothing special, the sensor's saturation, an error code.
SPECIAL_NONE: Final = 0
SPECIAL_SATURATED: Final = 1
SPECIAL_ERROR: Final = 2


@dataclass(frozen=True)
class SpecialCodes:
    """Raw values (the registers' integer, before scale and offset) that are codes, not
    readings: ``saturated`` values and those from ``saturated_from`` up read status
    saturated, ``error`` values and those from ``error_from`` up status error; a listed value
    wins over a range, saturation over error. Never a force."""

    saturated: tuple[int, ...] = ()
    error: tuple[int, ...] = ()
    saturated_from: int | None = None
    error_from: int | None = None

    def classify(self, raw: NDArray[np.integer[Any]]) -> NDArray[np.int8]:
        """``SPECIAL_NONE``, ``SPECIAL_SATURATED`` or ``SPECIAL_ERROR`` per raw value."""
        out = np.zeros(raw.shape, dtype=np.int8)
        if self.error_from is not None:
            out[raw >= self.error_from] = SPECIAL_ERROR
        if self.saturated_from is not None:
            out[raw >= self.saturated_from] = SPECIAL_SATURATED
        if self.error:
            out[np.isin(raw, self.error)] = SPECIAL_ERROR
        if self.saturated:
            out[np.isin(raw, self.saturated)] = SPECIAL_SATURATED
        return out

    def describe(self) -> str:
        parts = []
        if self.saturated:
            parts.append(f"{', '.join(map(str, self.saturated))} saturated")
        if self.saturated_from is not None:
            parts.append(f">= {self.saturated_from} saturated")
        if self.error:
            parts.append(f"{', '.join(map(str, self.error))} error")
        if self.error_from is not None:
            parts.append(f">= {self.error_from} error")
        return "; ".join(parts)
