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

The work is split by job: ``scan_types`` (snapshots, thresholds, the result types),
``scan_stats`` (per-register statistics), ``scan_frames`` (ADC frame candidates),
``scan_clocks`` (clock candidates) and ``scan_snippet`` (constant runs, text and the TOML
snippet); ``analyse`` puts them together here, and every public name is re-exported.
"""

from __future__ import annotations

from collections.abc import Sequence

from .scan_clocks import _adc_channels, _clocks
from .scan_frames import _frame, frame_runs
from .scan_frames import adc_bits_for as adc_bits_for
from .scan_snippet import config_snippet, constant_runs, printable_text
from .scan_stats import _present, _runs, _stats, _value
from .scan_types import (
    ADC_BITS,
    MIN_FRAME_REGISTERS,
    ClockCandidate,
    ConstantRegister,
    FrameCandidate,
    RegisterStats,
    ScanResult,
    Snapshot,
)
from .scan_types import CLOCK_STEADINESS as CLOCK_STEADINESS
from .scan_types import CLOCK_UNITS as CLOCK_UNITS
from .scan_types import CLOCK_WIDTHS as CLOCK_WIDTHS
from .scan_types import FLOAT_EXPONENTS as FLOAT_EXPONENTS
from .scan_types import MAX_CLOCK_RATE_PER_S as MAX_CLOCK_RATE_PER_S
from .scan_types import MIN_CLOCK_STEPS as MIN_CLOCK_STEPS

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
            for part in frame_runs(run, series[name]):
                frame = _frame(name, part, series[name], len(ordered))
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
