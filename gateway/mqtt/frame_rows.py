"""What a received frame's fields give a subscriber (pure): its channels in contact, its
clock for a record, and its record rows (``docs/record-format.md``; the CLI owns the writer).
"""

from __future__ import annotations

import math
from typing import Any, Final

from ..runtime.snapshot import CONTACT_STATUSES, READING_STATUSES

#: ok, no_contact, saturated, extrapolated, no_zero, uncalibrated
_WITH_VALUE: Final = frozenset(s.label for s in READING_STATUSES)
_CONTACT: Final = frozenset(s.label for s in CONTACT_STATUSES)  # ok, saturated, extrapolated


def in_contact(fields: dict[str, Any]) -> list[str]:
    """Channel names in contact: status ok, saturated or extrapolated with a force above 0 (as the gateway
    counts ``channels_in_contact``)."""
    out = []
    for name, status, force in zip(fields["channels"], fields["status"], fields["force_n"], strict=False):
        if status in _CONTACT and force is not None and force > 0.0:
            out.append(str(name))
    return out


def frame_clock_s(fields: dict[str, Any]) -> float:
    """The frame's time for a record: the device clock when the frame has one, else the host's."""
    device_time = fields.get("device_time_s")
    return float(device_time) if device_time is not None else float(fields["host_time_s"])


def recordable(fields: dict[str, Any]) -> tuple[list[tuple[str, float]], int]:
    """A frame's record rows (channel, resistance in ohm) and how many channels have none.

    As ``tactile-gateway record``: an open channel is ``inf``; a channel whose status carries
    a reading (ok, no_contact, saturated, extrapolated, no_zero, uncalibrated) records its resistance, ``inf``
    when not finite; a short, stale or error channel has no row (counted). A frame of a device that was not
    polled successfully (``up`` false) has no rows at all.
    """
    if not fields.get("up", True):
        return [], len(fields["channels"])
    rows: list[tuple[str, float]] = []
    skipped = 0
    for name, status, r in zip(fields["channels"], fields["status"], fields["resistance_ohm"], strict=True):
        value = math.inf if r is None else float(r)
        if status == "open" or (status in _WITH_VALUE and not math.isfinite(value)):
            rows.append((str(name), math.inf))
        elif status in _WITH_VALUE and value > 0.0:
            rows.append((str(name), value))
        else:
            skipped += 1
    return rows, skipped
