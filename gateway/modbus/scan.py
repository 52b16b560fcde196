"""What repeated reads of an unknown device's registers suggest about its map (pure, no I/O).

``tactile-gateway scan`` reads register ranges of an undocumented board several times and
hands the snapshots here: a sequence of ``(host_time_s, {table: {address: value}})`` with
``None`` for a register the device refused. ``analyse`` summarises every register (min,
max, distinct values, whether it changed) and makes three kinds of suggestion:

* **clocks**: one register, or 2 or 4 consecutive ones read as a big-endian uint32/uint64,
  whose value rises steadily with host time; the rate against host time names the unit
  (s, ms, us) or gives "ticks at X Hz". Looked for first, so that a clock never counts as
  part of an ADC frame.
* **ADC frames**: maximal runs of at least 4 consecutive readable registers of one table
  (clocks excluded) that are live: most registers change between snapshots (noise alone is
  enough, so an idle frame is found), or some change and the registers differ from one
  another. A run that never changes (identification, version, configuration) is never a
  frame, and it takes two snapshots to tell. The estimated ADC width is the smallest of
  10, 12, 14, 16 bits that holds every value seen: only a lower bound, since an idle frame
  uses a small part of its range.
* **constants**: registers read at least twice with one value: identification and version
  candidates.

``config_snippet`` turns the best suggestions into TOML text for a ``[[bus.device]]``
table. This module knows nothing of the configuration: the text is for a person to check.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

__all__ = [
    "ADC_BITS",
    "MIN_FRAME_REGISTERS",
    "ClockCandidate",
    "ConstantRegister",
    "FrameCandidate",
    "RegisterStats",
    "ScanResult",
    "Snapshot",
    "analyse",
    "config_snippet",
    "constant_runs",
    "printable_text",
]

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


# --------------------------------------------------------------------------- analysis
def analyse(snapshots: Sequence[Snapshot]) -> ScanResult:
    """Statistics and suggestions from snapshots (see the module docstring).

    Snapshots are put in host-time order; a register missing from a snapshot counts as
    unreadable there. Values must be 0..65535.
    """
    ordered = sorted(snapshots, key=lambda s: s[0])
    times = [float(t) for t, _ in ordered]
    tables: list[str] = []
    for _, data in ordered:
        tables.extend(name for name in data if name not in tables)
    series: dict[str, dict[int, list[int | None]]] = {}
    for name in tables:
        addresses = sorted({a for _, data in ordered for a in data.get(name, {})})
        series[name] = {a: [_value(data.get(name, {}).get(a)) for _, data in ordered] for a in addresses}
    stats = tuple(_stats(name, a, values) for name in tables for a, values in series[name].items())
    clocks: list[ClockCandidate] = []
    for name in tables:
        found = _clocks(name, series[name], times)
        clocks.extend(c for c in found if not _adc_channels(c, series[name], len(ordered)))
    clocks.sort(key=lambda c: (tables.index(c.table), c.address))
    in_clock = {(c.table, a) for c in clocks for a in range(c.address, c.end + 1)}
    frames: list[FrameCandidate] = []
    for name in tables:
        readable = [a for a, v in series[name].items() if (name, a) not in in_clock and _present(v)]
        for run in _runs(readable):
            frame = _frame(name, run, series[name], len(ordered))
            if frame is not None:
                frames.append(frame)
    frames.sort(key=lambda f: (-f.score, tables.index(f.table), f.address))
    claimed = in_clock | {(f.table, a) for f in frames for a in range(f.address, f.end + 1)}
    constants = tuple(
        ConstantRegister(s.table, s.address, s.minimum)
        for s in stats
        if s.samples >= 2
        and s.distinct == 1
        and s.minimum is not None
        and (s.table, s.address) not in claimed
    )
    return ScanResult(len(ordered), tuple(tables), stats, tuple(frames), tuple(clocks), constants)


def _value(v: int | None) -> int | None:
    return None if v is None else int(v)


def _present(values: Sequence[int | None]) -> bool:
    return any(v is not None for v in values)


def _stats(table: str, address: int, values: Sequence[int | None]) -> RegisterStats:
    seen = [v for v in values if v is not None]
    return RegisterStats(
        table=table,
        address=address,
        samples=len(seen),
        unreadable=len(values) - len(seen),
        minimum=min(seen) if seen else None,
        maximum=max(seen) if seen else None,
        distinct=len(set(seen)),
        last=seen[-1] if seen else None,
    )


def _runs(addresses: Iterable[int]) -> list[list[int]]:
    """Maximal runs of consecutive addresses."""
    runs: list[list[int]] = []
    for a in sorted(addresses):
        if runs and runs[-1][-1] == a - 1:
            runs[-1].append(a)
        else:
            runs.append([a])
    return runs


def adc_bits_for(maximum: int) -> int:
    """The smallest ADC width in ``ADC_BITS`` whose codes reach ``maximum``."""
    return next((b for b in ADC_BITS if maximum <= (1 << b) - 1), ADC_BITS[-1])


# --------------------------------------------------------------------------- frames
def _frame(
    table: str, run: list[int], series: Mapping[int, list[int | None]], n_snapshots: int
) -> FrameCandidate | None:
    """The run as a frame candidate, or None when it is too short or not live."""
    n = len(run)
    if n < MIN_FRAME_REGISTERS:
        return None
    values = [[v for v in series[a] if v is not None] for a in run]
    distinct = [len(set(v)) for v in values]
    changed = sum(1 for d in distinct if d > 1)
    live = changed / n
    spread = len({statistics.median_low(v) for v in values}) / n
    if n_snapshots < 2 or not (live >= 0.5 or (changed >= 1 and spread >= 0.5)):
        return None
    maximum = max(max(v) for v in values)
    float_like = _float_like(values)
    score = 100.0 * (0.75 * live + 0.25 * spread) * n / (n + 4) * (0.4 if float_like else 1.0)
    return FrameCandidate(
        table=table,
        address=run[0],
        count=n,
        bits=adc_bits_for(maximum),
        changed=changed,
        maximum=maximum,
        score=round(score, 1),
        float_like=float_like,
    )


def _float_like(values: Sequence[Sequence[int]]) -> bool:
    """Whether the run reads as float32 pairs rather than ADC counts: in one phase every
    other register is a plausible float32 high word (sign, an exponent for about 5e-10 to
    9e9, or zero or infinity) in every snapshot, and in the other phase not. ADC counts
    fail both phases when small and pass both when all in that band; the low words of
    floats are too random to pass."""
    passing = []
    for phase in (0, 1):
        high = values[phase::2]
        pairs = min(len(high), len(values[phase + 1 :: 2]))
        passing.append(pairs >= 2 and all(_float_high_word(w) for v in high[:pairs] for w in v))
    return passing[0] != passing[1]


def _float_high_word(word: int) -> bool:
    magnitude = word & 0x7FFF
    return magnitude in (0, 0x7F80) or FLOAT_EXPONENTS[0] <= magnitude >> 7 <= FLOAT_EXPONENTS[1]


# --------------------------------------------------------------------------- clocks
@dataclass(frozen=True)
class _Group:
    address: int
    width: int
    rate: float
    total: int
    top_zero: bool
    top_changes: bool


def _clocks(
    table: str, series: Mapping[int, list[int | None]], times: Sequence[float]
) -> list[ClockCandidate]:
    """Clock candidates of one table: for each register that could be a counter's low word
    the best reading (the widest whose top register is zero or moving: a uint64 of small
    value reads as zeros above a uint16), then no two overlapping, wider ones first
    (``analyse`` then drops those inside an ADC frame)."""
    by_low: dict[int, list[_Group]] = {}
    for width in CLOCK_WIDTHS:
        for address in series:
            group = _group(series, address, width, times)
            if group is not None:
                by_low.setdefault(address + width - 1, []).append(group)
    chosen: list[_Group] = []
    for groups in by_low.values():
        fitting = [g for g in groups if g.width == 1 or g.top_zero or g.top_changes]
        chosen.append(fitting[0] if fitting else groups[-1])
    chosen.sort(key=lambda g: (-g.width, g.address))
    taken: set[int] = set()
    accepted: list[_Group] = []
    for g in chosen:
        span = set(range(g.address, g.address + g.width))
        if not span & taken:
            accepted.append(g)
            taken |= span
    return [ClockCandidate(table, g.address, g.width, g.rate, _unit(g.rate, g.total)) for g in accepted]


def _adc_channels(clock: ClockCandidate, series: Mapping[int, list[int | None]], n_snapshots: int) -> bool:
    """Whether a rising "clock" is rather ADC channels under a steady ramp (or whose noise
    happened to rise): it lies in a run of readable registers that is an ADC frame, and
    either the registers on both sides of it make a frame without it, or it is a wider
    group whose top word moves in several intervals (a counter's upper word moves only by
    a rare carry; a ramping channel's every interval) next to a moving register."""

    def side(start: int, step: int) -> list[int]:
        found: list[int] = []
        a = start
        while a in series and _present(series[a]):
            found.append(a)
            a += step
        return found

    left, right = side(clock.address - 1, -1), side(clock.end + 1, 1)
    if not (left or right):
        return False
    run = sorted([*left, *range(clock.address, clock.end + 1), *right])
    if _frame(clock.table, run, series, n_snapshots) is None:
        return False
    if left and right and _frame(clock.table, sorted(left + right), series, n_snapshots) is not None:
        return True
    top = [v for v in series[clock.address] if v is not None]
    top_moves = sum(1 for a, b in itertools.pairwise(top) if a != b)
    neighbours = (series.get(clock.address - 1), series.get(clock.end + 1))
    return clock.registers > 1 and top_moves >= 2 and any(_moving(v) for v in neighbours)


def _moving(values: Sequence[int | None] | None) -> bool:
    return values is not None and len({v for v in values if v is not None}) > 1


def _group(
    series: Mapping[int, list[int | None]], address: int, width: int, times: Sequence[float]
) -> _Group | None:
    """``width`` registers from ``address`` as a big-endian counter, if they rise steadily."""
    columns = [series.get(address + k) for k in range(width)]
    cols = [c for c in columns if c is not None]
    if len(cols) < width:
        return None
    rows: list[tuple[float, list[int]]] = []
    for i, t in enumerate(times):
        row = [c[i] for c in cols]
        if all(v is not None for v in row):
            rows.append((t, [int(v or 0) for v in row]))
    if len(rows) < 3:
        return None
    words = [w for _, w in rows]
    if len({w[-1] for w in words}) < 2:
        return None  # the low word must move
    modulus = 1 << (16 * width)
    values = [_combine(w) for w in words]
    steps: list[int] = []
    spans: list[float] = []
    for i in range(1, len(rows)):
        dt = rows[i][0] - rows[i - 1][0]
        if not (math.isfinite(dt) and dt > 0):
            return None
        step = values[i] - values[i - 1]
        if step < 0:
            if -step <= modulus // 2:
                return None  # a fall, not a wrap
            step += modulus
        steps.append(step)
        spans.append(dt)
    total = sum(steps)
    elapsed = sum(spans)
    if sum(1 for step in steps if step > 0) < MIN_CLOCK_STEPS or not elapsed > 0:
        return None
    rate = _slope([t for t, _ in rows], list(itertools.accumulate(steps, initial=0)))
    if not 0.0 < rate <= MAX_CLOCK_RATE_PER_S:
        return None
    for step, dt in zip(steps, spans, strict=True):
        if abs(step - rate * dt) > CLOCK_STEADINESS * rate * dt + 2:
            return None
    if width > 1 and not _carries_fit(words, rate * max(spans)):
        return None
    top = [w[0] for w in words]
    return _Group(address, width, rate, total, all(v == 0 for v in top), len(set(top)) > 1)


def _slope(x: Sequence[float], y: Sequence[int]) -> float:
    """Least-squares slope of y over x: a counter's rate, less sensitive than its end points
    to the counts it had not yet reached at the first or last reading."""
    mx, my = sum(x) / len(x), sum(y) / len(y)
    sxx = sum((a - mx) ** 2 for a in x)
    return sum((a - mx) * (b - my) for a, b in zip(x, y, strict=True)) / sxx if sxx > 0 else 0.0


def _combine(words: Sequence[int]) -> int:
    value = 0
    for w in words:
        value = (value << 16) | (w & 0xFFFF)
    return value


def _carries_fit(words: Sequence[Sequence[int]], max_step: float) -> bool:
    """Where the lower part of a reading moves less than half its range per interval, the
    part above may only change by a carry: +1 exactly when the lower part wrapped. Two
    unrelated slow counters side by side fail this."""
    width = len(words[0])
    for low_words in range(1, width):
        modulus = 1 << (16 * low_words)
        if max_step >= modulus / 2:
            continue
        for prev, cur in itertools.pairwise(words):
            low_prev, low_cur = _combine(prev[-low_words:]), _combine(cur[-low_words:])
            high_step = _combine(cur[:-low_words]) - _combine(prev[:-low_words])
            if high_step != (1 if low_cur < low_prev else 0):
                return False
    return True


def _unit(rate: float, total: int) -> str | None:
    """The unit whose counts per second match ``rate``, allowing for the quantisation of a
    counter that moved only ``total`` counts; None for anything else (a tick counter)."""
    tolerance = 0.15 + 2.0 / total
    matches = [
        (abs(math.log(rate / per_s)), name)
        for name, per_s in CLOCK_UNITS.items()
        if abs(rate / per_s - 1.0) <= tolerance
    ]
    return min(matches)[1] if matches else None


def _hertz(rate: float) -> str:
    for scale, prefix in ((1e6, "MHz"), (1e3, "kHz")):
        if rate >= scale:
            return f"{rate / scale:.3g} {prefix}"
    return f"{rate:.3g} Hz"


# --------------------------------------------------------------------------- presentation
def constant_runs(constants: Iterable[ConstantRegister]) -> list[tuple[str, int, list[int]]]:
    """Constants grouped into runs of consecutive addresses: (table, first address, values)."""
    runs: list[tuple[str, int, list[int]]] = []
    for c in constants:
        if runs and runs[-1][0] == c.table and runs[-1][1] + len(runs[-1][2]) == c.address:
            runs[-1][2].append(c.value)
        else:
            runs.append((c.table, c.address, [c.value]))
    return runs


def printable_text(values: Iterable[int]) -> list[str]:
    """Stretches of text in the registers' bytes (high byte first): at least two letters,
    digits or ``space . _ - /`` with a letter among them, as vendor or product codes are
    kept. Float32 and counter words rarely spell that much by chance."""
    found: list[str] = []
    current = ""
    for byte in (b for v in values for b in ((v >> 8) & 0xFF, v & 0xFF)):
        char = chr(byte)
        if char.isascii() and (char.isalnum() or char in " ._-/"):
            current += char
            continue
        found.append(current)
        current = ""
    found.append(current)
    return [t.strip() for t in found if len(t.strip()) >= 2 and any(c.isalpha() for c in t)]


def _toml_float(x: float) -> str:
    """Three significant digits, always a TOML float (``0.01``, ``2.0``, ``1e-05``)."""
    return repr(float(f"{x:.3g}"))


def config_snippet(result: ScanResult, device_id: int | None = None) -> str | None:
    """TOML text for the device's table from the best frame (and the best clock, if any);
    None without a frame candidate. A starting point to check, not a finished configuration."""
    frame = result.best_frame
    if frame is None:
        return None
    lines = ["[[bus.device]]"]
    if device_id is not None:
        lines.append(f"device_id = {device_id}")
    lines += [
        'encoding = "adc"',
        f"channels = {frame.count}",
        "",
        "[bus.device.registers]",
        f'table = "{frame.table}"',
        f"adc_address = {frame.address}",
        "",
        "# the read-out circuit does not show in the registers: check kind, supply and resistor",
        "# against the board (docs/front-ends.md)",
        "[bus.device.front_end]",
        'kind = "high_side"             # or "low_side" (pull-up), "transimpedance"',
        "supply_v = 3.3",
        "reference_ohm = 10000.0",
        f"adc_bits = {frame.bits}              # the smallest width that holds the codes seen",
    ]
    clock = result.best_clock
    if clock is not None:
        lines += [
            "",
            "[bus.device.clock]",
            f'table = "{clock.table}"',
            f"address = {clock.address}",
            f"registers = {clock.registers}",
            f'unit = "{clock.unit}"' if clock.unit is not None else f"tick_s = {_toml_float(clock.tick_s)}",
        ]
    return "\n".join(lines) + "\n"
