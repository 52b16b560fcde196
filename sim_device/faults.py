"""Fault injection for one simulated device: settable now, or scheduled over device time.

Fields (persist until changed or ``clear()``):

- ``delay_s``: hold every response back by this many seconds (wall clock).
- ``no_response``: answer nothing; the client times out.
- ``exception_code``: answer every request with this Modbus exception (e.g. 6 DEVICE_BUSY).
- ``garble``: corrupt the response frame (RTU: bad CRC; Modbus/TCP: bad MBAP protocol id),
  so the client discards it and times out.
- ``drop_connection``: close the TCP connection instead of answering (on a serial line,
  where there is no connection, the device stays silent instead).
- ``probability``: each request is hit by the active faults with this probability (seeded).

Channel faults (a channel going open or short) are scheduled with ``schedule(at_s,
channel=i, channel_mode="open")`` and applied by the array at the exact sample times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .scenarios import VALID_EXCEPTION_CODES, FaultEvent

FAULT_FIELDS: tuple[str, ...] = ("delay_s", "no_response", "exception_code", "garble", "drop_connection")
CHANNEL_MODES: dict[str, int] = {"normal": 0, "open": 1, "short": 2}
_OFF: dict[str, Any] = {
    "delay_s": 0.0,
    "no_response": False,
    "exception_code": None,
    "garble": False,
    "drop_connection": False,
}


class FaultError(ValueError):
    """An invalid fault setting."""


@dataclass(frozen=True)
class FaultDecision:
    """What happens to one request."""

    delay_s: float = 0.0
    no_response: bool = False
    exception_code: int | None = None
    garble: bool = False
    drop_connection: bool = False


#: The decision of a request that no fault hits.
NO_FAULT = FaultDecision()


def _check(name: str, value: Any) -> Any:
    if name == "delay_s":
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not (math.isfinite(value) and value >= 0)
        ):
            raise FaultError(f"delay_s must be a finite number >= 0 s, got {value!r}")
        return float(value)
    if name == "exception_code":
        if value is None:
            return None
        if isinstance(value, bool) or int(value) != value or int(value) not in VALID_EXCEPTION_CODES:
            raise FaultError(f"exception_code must be None or one of {VALID_EXCEPTION_CODES}, got {value!r}")
        return int(value)
    if name in ("no_response", "garble", "drop_connection"):
        if not isinstance(value, bool):
            raise FaultError(f"{name} must be True or False, got {value!r}")
        return value
    if name == "probability":
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
            raise FaultError(f"probability must be within 0..1, got {value!r}")
        return float(value)
    raise FaultError(f"unknown fault field {name!r} (valid: {', '.join(FAULT_FIELDS)}, probability)")


class FaultInjector:
    """Faults of one device (see the module docstring). All times are device times in s."""

    delay_s: float
    no_response: bool
    exception_code: int | None
    garble: bool
    drop_connection: bool
    probability: float
    _events: list[tuple[float, dict[str, Any]]]
    _channel_events: list[tuple[float, int, int]]
    _rng: np.random.Generator
    _active: bool

    def __init__(self, seed: int = 0) -> None:
        object.__setattr__(self, "_events", [])
        object.__setattr__(self, "_channel_events", [])
        object.__setattr__(self, "_rng", np.random.default_rng([seed, 0xFA]))
        object.__setattr__(self, "_active", False)
        self.clear()

    def __setattr__(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, _check(name, value))
        if name in _OFF:
            on = any(getattr(self, n, off) != off for n, off in _OFF.items())
            object.__setattr__(self, "_active", on)

    def clear(self) -> None:
        """Switch every fault off and forget the schedule."""
        for name, value in _OFF.items():
            setattr(self, name, value)
        self.probability = 1.0
        self._events.clear()
        self._channel_events.clear()

    @property
    def active(self) -> bool:
        """Whether any fault field is switched on now."""
        return self._active

    def schedule(
        self,
        at_s: float,
        *,
        until_s: float | None = None,
        channel: int | None = None,
        channel_mode: str | None = None,
        **fields: Any,
    ) -> None:
        """At device time ``at_s`` set the given fields (and/or a channel's mode).

        With ``until_s`` they switch back off (channel back to "normal") at that time.
        """
        if not math.isfinite(at_s):
            raise FaultError(f"at_s must be finite, got {at_s!r}")
        if until_s is not None and not until_s > at_s:
            raise FaultError(f"until_s ({until_s!r}) must be after at_s ({at_s!r})")
        for name, value in fields.items():
            if name not in FAULT_FIELDS:
                raise FaultError(f"unknown fault field {name!r} (valid: {', '.join(FAULT_FIELDS)})")
            fields[name] = _check(name, value)
        if channel_mode is not None:
            if channel_mode not in CHANNEL_MODES:
                raise FaultError(
                    f"channel_mode must be one of {', '.join(CHANNEL_MODES)}, got {channel_mode!r}"
                )
            if channel is None or isinstance(channel, bool) or not isinstance(channel, int) or channel < 0:
                raise FaultError(f"channel_mode needs a channel index, got {channel!r}")
            self._channel_events.append((float(at_s), channel, CHANNEL_MODES[channel_mode]))
            if until_s is not None:
                self._channel_events.append((float(until_s), channel, 0))
            self._channel_events.sort(key=lambda e: e[0])
        elif not fields:
            raise FaultError("schedule() needs fault fields or a channel_mode")
        if fields:
            self._events.append((float(at_s), dict(fields)))
            if until_s is not None:
                self._events.append((float(until_s), {name: _OFF[name] for name in fields}))
            self._events.sort(key=lambda e: e[0])

    def schedule_event(self, event: FaultEvent) -> None:
        """Schedule a ``FaultEvent`` (as read from a scenario file)."""
        changes = dict(event.changes)
        mode = changes.pop("channel_mode", None)
        self.schedule(event.at_s, until_s=event.until_s, channel=event.channel, channel_mode=mode, **changes)

    def apply_due(self, device_time_s: float) -> None:
        """Apply the scheduled field changes due at or before ``device_time_s``."""
        events = self._events
        while events and events[0][0] <= device_time_s:
            _at, changes = events.pop(0)
            for name, value in changes.items():
                setattr(self, name, value)

    def pop_channel_events(self, until_s: float) -> list[tuple[float, int, int]]:
        """Remove and return the channel-mode events due at or before ``until_s``.

        Each is (device time s, channel, mode code: 0 normal, 1 open, 2 short).
        """
        due = [e for e in self._channel_events if e[0] <= until_s]
        del self._channel_events[: len(due)]
        return due

    def decide(self, device_time_s: float) -> FaultDecision:
        """The faults that hit the next request (applies the schedule first)."""
        if self._events:
            self.apply_due(device_time_s)
        if not self._active:
            return NO_FAULT
        if self.probability < 1.0 and self._rng.random() >= self.probability:
            return NO_FAULT
        return FaultDecision(
            delay_s=self.delay_s,
            no_response=self.no_response,
            exception_code=self.exception_code,
            garble=self.garble,
            drop_connection=self.drop_connection,
        )

    def __repr__(self) -> str:
        state = ", ".join(f"{n}={getattr(self, n)!r}" for n in (*FAULT_FIELDS, "probability"))
        return f"FaultInjector({state}, scheduled={len(self._events) + len(self._channel_events)})"
