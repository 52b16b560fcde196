"""The time step of a poll: the device clock while it behaves, else the host clock.

Pure: ``time_step`` takes the device's clock settings, what was seen of its clock
(``ClockHealth``) and the two clocks' readings, and returns the step and the new health. A
device time that no counter holds (not finite, negative, 2^64 ticks or more: a record's
``time_s`` of 1e300) is no clock reading: that sample takes the host clock's step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Final

from ..modbus.register_map import DeviceClock

__all__ = [
    "CLOCK_JUMP_FACTOR",
    "CLOCK_MAX_BACKWARD_JUMPS",
    "CLOCK_STUCK_AFTER_S",
    "MAX_COUNTER_TICKS",
    "NO_CLOCK_HISTORY",
    "ClockHealth",
    "counter_ticks",
    "time_step",
]

#: A device clock that has not advanced for this long (host seconds, at least three of
#: its ticks) while polls succeed is stuck: the host clock takes over.
CLOCK_STUCK_AFTER_S = 2.0
#: A wrapping (16/32-bit) clock that steps more than this many times the host's step
#: (plus one second) has jumped, not wrapped.
CLOCK_JUMP_FACTOR = 10.0
#: After this many backward jumps the device clock is not trusted any more.
CLOCK_MAX_BACKWARD_JUMPS = 3


@dataclass(frozen=True)
class ClockHealth:
    """What the conversion has seen of a device clock: the last counter value, the host
    time at which it last advanced, faults by kind, and whether the host clock took over
    for good (``fallback``)."""

    last_ticks: int | None = None
    advanced_host_time_s: float | None = None
    stuck: int = 0
    backwards: int = 0
    fallback: str | None = None  # why the host clock took over: "stuck", "backwards"


#: No device counter holds this many ticks (the widest is 64 bit).
MAX_COUNTER_TICKS: Final = 2**64

#: A device whose clock has not been read yet.
NO_CLOCK_HISTORY: Final = ClockHealth()


def counter_ticks(clock: DeviceClock, device_time_s: float) -> int | None:
    """``device_time_s`` in ticks of ``clock``, or None for a time no counter of it holds: not
    finite, negative, or at least ``2^64`` ticks (``2^64 x tick_s``: 584 years at 1 ns)."""
    if not math.isfinite(device_time_s) or device_time_s < 0.0:
        return None
    ticks_f = device_time_s / clock.tick_s
    if not ticks_f < MAX_COUNTER_TICKS:  # also inf, from a huge time over a tiny tick
        return None
    return round(ticks_f)


def time_step(
    clock: DeviceClock | None,
    health_in: ClockHealth,
    device_time_s: float | None,
    device_ticks: int | None,
    last_time_s: float | None,
    last_host_time_s: float | None,
    time_from_device: bool,
    host_time_s: float,
) -> tuple[float, float, bool, ClockHealth]:
    """Seconds since the previous sample, the time to remember, whether it came from the
    device clock, and the clock's health.

    The device clock is used while it behaves. A counter that does not advance for
    ``CLOCK_STUCK_AFTER_S`` while polls succeed is stuck (a register that is not a clock, a
    frozen firmware): the host clock takes over for good, and the step covers the host time
    since the counter last advanced, so the creep lost meanwhile is made up. A counter that
    goes back (a restart) or, for a 16/32-bit counter, steps implausibly far, costs that one
    step the host clock; after ``CLOCK_MAX_BACKWARD_JUMPS`` of them the host clock takes over
    for good.
    """
    health = health_in
    host_dt = host_time_s - last_host_time_s if last_host_time_s is not None else 0.0
    host_dt = max(0.0, host_dt)
    if device_time_s is None or clock is None or health.fallback is not None:
        return (host_dt if last_time_s is not None else 0.0), host_time_s, False, health
    ticks = device_ticks if device_ticks is not None else counter_ticks(clock, device_time_s)
    if ticks is None:  # no counter holds it (a record's time_s of 1e300): the host step, flagged
        return (host_dt if last_time_s is not None else 0.0), host_time_s, False, health
    if health.last_ticks is None or not time_from_device or last_time_s is None:
        first = ClockHealth(ticks, host_time_s, health.stuck, health.backwards)
        return (host_dt if last_time_s is not None else 0.0), device_time_s, True, first
    delta = ticks - health.last_ticks
    if clock.registers < 4:
        delta %= clock.modulus
    step_s = delta * clock.tick_s
    backwards = delta < 0 or (
        clock.registers < 4 and step_s > CLOCK_JUMP_FACTOR * host_dt + 1.0 and step_s > 2 * clock.tick_s
    )
    if backwards:
        n = health.backwards + 1
        fallback = "backwards" if n >= CLOCK_MAX_BACKWARD_JUMPS else None
        new = ClockHealth(ticks, host_time_s, health.stuck, n, fallback)
        return host_dt, (host_time_s if fallback else device_time_s), fallback is None, new
    if delta == 0:
        advanced = health.advanced_host_time_s
        since = host_time_s - (advanced if advanced is not None else host_time_s)
        if since > max(CLOCK_STUCK_AFTER_S, 3.0 * clock.tick_s):
            new = ClockHealth(ticks, advanced, health.stuck + 1, health.backwards, "stuck")
            return max(0.0, since), host_time_s, False, new
        return 0.0, device_time_s, True, replace(health, last_ticks=ticks)
    new = ClockHealth(ticks, host_time_s, health.stuck, health.backwards)
    return step_s, device_time_s, True, new
