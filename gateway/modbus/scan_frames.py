"""ADC frame candidates of the scan (pure): a live run of consecutive registers, its score, the
ADC width that holds its codes, and whether it rather reads as float32 pairs.

A run of readable registers is first cut down to the registers that may be ADC cells
(``frame_runs``): a frame is a stretch of registers that change between snapshots, with the
constant registers inside it kept as idle cells unless their value is out of the frame's
range (an identifier such as 0x3343 beside 12-bit codes splits the run there). Constant
registers at its ends are added one by one while they look like idle cells (a value among
the idle cells inside, or within the range the changing ones took) and not like a count (a
value the frame's length could be); a constant right next to the frame whose value is a
length between that of the changing stretch and that of the extended one is taken as the
channel count, and the frame is cut to that length on its other side (idle cells and a gap
of zeros before the frame read alike; the count tells where the frame starts).
Identity, version and count registers next to a frame thus stay constants.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence

from .scan_types import ADC_BITS, FLOAT_EXPONENTS, MIN_FRAME_REGISTERS, FrameCandidate


def adc_bits_for(maximum: int) -> int:
    """The smallest ADC width in ``ADC_BITS`` whose codes reach ``maximum``."""
    return next((b for b in ADC_BITS if maximum <= (1 << b) - 1), ADC_BITS[-1])


def frame_runs(run: Sequence[int], series: Mapping[int, list[int | None]]) -> list[list[int]]:
    """The parts of a run of consecutive readable registers that may be ADC frames (see the
    module docstring); each still has to pass ``_frame``."""
    values = {a: {v for v in series[a] if v is not None} for a in run}
    changing = [a for a in run if len(values[a]) > 1]
    if not changing:
        return []
    top = max(max(values[a]) for a in changing)
    full = (1 << adc_bits_for(top)) - 1
    pieces: list[list[int]] = [[]]
    for a in run:
        if len(values[a]) == 1 and min(values[a]) > full:
            pieces.append([])  # an identifier out of the codes' range: no cell
        else:
            pieces[-1].append(a)
    return [part for piece in pieces if (part := _extended_core(piece, values, len(run)))]


def _extended_core(piece: list[int], values: Mapping[int, set[int]], longest: int) -> list[int]:
    """The stretch of ``piece`` from its first to its last changing register, extended at both
    ends by constants that look like idle cells, cut to an adjacent channel count; ``longest``
    is the length of the whole run, the longest frame it may hold."""
    changing = [i for i, a in enumerate(piece) if len(values[a]) > 1]
    if not changing:
        return []
    first, last = changing[0], changing[-1]
    low = min(min(values[piece[i]]) for i in changing)
    high = max(max(values[piece[i]]) for i in changing)
    idle = {min(values[a]) for a in piece[first : last + 1] if len(values[a]) == 1}
    core = last - first + 1

    def cell_like(i: int) -> bool:
        """Whether constant ``piece[i]`` may be an idle cell at an end of the frame."""
        v = min(values[piece[i]])
        if core <= v <= longest:
            return False  # a length the frame may have: rather its channel count
        return v in idle or low <= v <= high

    start, end = first, last
    while start > 0 and cell_like(start - 1):
        start -= 1
    while end < len(piece) - 1 and cell_like(end + 1):
        end += 1
    after = min(values[piece[end + 1]]) if end + 1 < len(piece) else None
    before = min(values[piece[start - 1]]) if start > 0 else None
    if after is not None and core <= after < end - start + 1 and end - after + 1 <= first:
        start = end - after + 1  # a count right after the frame: the frame ends here
    elif before is not None and core <= before < end - start + 1 and start + before - 1 >= last:
        end = start + before - 1
    return piece[start : end + 1]


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
