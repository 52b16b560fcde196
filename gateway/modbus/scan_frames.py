"""ADC frame candidates of the scan (pure): a live run of consecutive registers, its score, the
ADC width that holds its codes, and whether it rather reads as float32 pairs.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence

from .scan_types import ADC_BITS, FLOAT_EXPONENTS, MIN_FRAME_REGISTERS, FrameCandidate


def adc_bits_for(maximum: int) -> int:
    """The smallest ADC width in ``ADC_BITS`` whose codes reach ``maximum``."""
    return next((b for b in ADC_BITS if maximum <= (1 << b) - 1), ADC_BITS[-1])


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
