"""What ``scan`` finds on an unknown device (pure): the snapshots it reads, the thresholds of its
suggestions, and the per-register statistics and candidates it returns (``ScanResult``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

#: One read of every range: host time (s) and, per table, address -> value (None: unreadable).
Snapshot = tuple[float, Mapping[str, Mapping[int, int | None]]]

#: ADC widths a frame may have; the estimate is the smallest that holds every value seen.
ADC_BITS: tuple[int, ...] = (10, 12, 14, 16)
#: Shortest run of registers that is suggested as an ADC frame.
MIN_FRAME_REGISTERS = 4
#: Biased float32 exponents of plausible measured values (2^-31 .. 2^33).
FLOAT_EXPONENTS: tuple[int, int] = (96, 160)
#: Counts per second of the clock units a device may use.
CLOCK_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e3, "us": 1e6}
#: Registers a clock may span (16, 32 or 64 bits), widest tried first.
CLOCK_WIDTHS: tuple[int, ...] = (4, 2, 1)
#: Fastest plausible device clock (a nanosecond counter): faster "clocks" are a counter
#: glued to whatever follows it.
MAX_CLOCK_RATE_PER_S = 2e9
#: A clock must have moved in at least this many intervals.
MIN_CLOCK_STEPS = 2
#: How far one interval's increment may stray from the clock's mean rate (relative), on top
#: of two counts for the quantisation of both readings.
CLOCK_STEADINESS = 0.35


@dataclass(frozen=True)
class RegisterStats:
    """What the snapshots saw of one register."""

    table: str
    address: int
    #: snapshots in which it was read, and in which it was refused
    samples: int
    unreadable: int
    minimum: int | None
    maximum: int | None
    distinct: int
    last: int | None

    @property
    def readable(self) -> bool:
        return self.samples > 0

    @property
    def changed(self) -> bool:
        return self.distinct > 1


@dataclass(frozen=True)
class FrameCandidate:
    """A run of registers that looks like an ADC frame; ``score`` 0..100, higher is likelier."""

    table: str
    address: int
    count: int
    #: the smallest ADC width in ``ADC_BITS`` that holds every value seen
    bits: int
    #: how many of its registers changed between snapshots
    changed: int
    maximum: int
    score: float
    #: every other register a plausible float32 high word: float32 pairs, not ADC counts
    float_like: bool

    @property
    def end(self) -> int:
        return self.address + self.count - 1


@dataclass(frozen=True)
class ClockCandidate:
    """A counter that rises with host time: ``registers`` big-endian registers from ``address``."""

    table: str
    address: int
    registers: int
    #: counts per second of host time
    rate_per_s: float
    #: "s", "ms" or "us" when the rate matches one, else None (a tick counter)
    unit: str | None

    @property
    def end(self) -> int:
        return self.address + self.registers - 1

    @property
    def type_name(self) -> str:
        return f"uint{16 * self.registers}"

    @property
    def tick_s(self) -> float:
        """Seconds per count: the unit's, or the measured one for a tick counter."""
        if self.unit is not None:
            return 1.0 / CLOCK_UNITS[self.unit]
        return 1.0 / self.rate_per_s

    @property
    def description(self) -> str:
        """The unit ("ms") or "ticks at 100 Hz"."""
        return self.unit if self.unit is not None else f"ticks at {_hertz(self.rate_per_s)}"


@dataclass(frozen=True)
class ConstantRegister:
    """A register that held one value over every snapshot that read it (at least two)."""

    table: str
    address: int
    value: int


@dataclass(frozen=True)
class ScanResult:
    """Per-register statistics and the suggestions, best first."""

    snapshots: int
    tables: tuple[str, ...]
    registers: tuple[RegisterStats, ...]
    frames: tuple[FrameCandidate, ...]
    clocks: tuple[ClockCandidate, ...]
    constants: tuple[ConstantRegister, ...]

    def stats(self, table: str, address: int) -> RegisterStats | None:
        for s in self.registers:
            if s.table == table and s.address == address:
                return s
        return None

    @property
    def best_frame(self) -> FrameCandidate | None:
        return self.frames[0] if self.frames else None

    @property
    def best_clock(self) -> ClockCandidate | None:
        """The clock for the configuration: one with a named unit first (ms, us, s), then ticks."""
        preference = {"ms": 0, "us": 1, "s": 2, None: 3}
        ranked = sorted(self.clocks, key=lambda c: preference[c.unit])
        return ranked[0] if ranked else None


def _hertz(rate: float) -> str:
    for scale, prefix in ((1e6, "MHz"), (1e3, "kHz")):
        if rate >= scale:
            return f"{rate / scale:.3g} {prefix}"
    return f"{rate:.3g} Hz"
