"""Whether a record starts with its sensor loaded, and at what load.

A piezoresistive sensor's reading depends on its load history (creep, slow recovery): a record
that starts at rest starts from a known state, one that starts under load does not. The
sensor may have held that load (or a higher one) for seconds or hours before the first row,
so its creep elements are in a state the record does not show, and a residual that changes
with the time since the record's start may be that history settling.

``start_load`` says which, from the first ``START_ROWS`` rows:

- with a reference force: the record starts loaded when their median reference force lies
  above the start threshold, the larger of the record's hold tolerance
  (``holds.hold_tolerance_n``, 2 % of the largest reference force) and its load-cell
  zero-noise tolerance (``records.zero_noise_tolerance_n``, at least 0.05 N): clearly above 0 N,
  never the load cell's noise at rest;
- without one: the record starts loaded when their median resistance lies more than
  ``UNLOADED_FACTOR`` below the record's unloaded level, its highest resistance (the 99th
  percentile; an open circuit is +inf). The load is then known only through a calibration
  (``force_of``, resistance in ohm to force in N); without one it is NaN. A record that never
  shows its sensor unloaded cannot be told apart from one that starts at rest this way: the
  sentence says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .holds import hold_tolerance_n
from .records import ChannelRecord, zero_noise_tolerance_n

FloatArray = NDArray[np.float64]

#: The rows that say how a record starts.
START_ROWS = 5
#: Without a reference: a start this factor below the record's unloaded resistance is loaded.
UNLOADED_FACTOR = 10.0
#: The share of the rows whose resistance sets the unloaded level (its highest, robustly).
UNLOADED_QUANTILE = 0.99


@dataclass(frozen=True)
class StartLoad:
    """How a record starts: ``loaded`` and at what ``force_n`` (N; NaN when not known), on
    which evidence (``source``: ``"reference"`` or ``"resistance"``)."""

    loaded: bool
    force_n: float
    source: str
    n_rows: int
    #: the start threshold (N) a reference force must exceed (NaN without a reference)
    threshold_n: float = math.nan
    #: the first rows' median resistance and the record's unloaded level (ohm; inf: open)
    resistance_ohm: float = math.nan
    unloaded_ohm: float = math.nan
    #: how long the starting load lasts before the reference first leaves it (s; NaN unknown)
    held_s: float = math.nan

    def sentence(self) -> str:
        """The start in words."""
        if self.source == "reference":
            if not self.loaded:
                return (
                    f"the record starts at rest (reference {self.force_n:.4g} N over its first "
                    f"{self.n_rows} rows, within the start threshold of {self.threshold_n:.4g} N)"
                )
            held = f", held for {self.held_s:.4g} s" if math.isfinite(self.held_s) else ""
            return (
                f"the record starts loaded at {self.force_n:.4g} N (reference over its first "
                f"{self.n_rows} rows, above the start threshold of {self.threshold_n:.4g} N{held}): "
                "the sensor's load history before the record is unknown"
            )
        ratio = f"{_ohm(self.resistance_ohm)} against an unloaded level of {_ohm(self.unloaded_ohm)}"
        if not self.loaded:
            return (
                f"the record starts with its resistance near its unloaded level ({ratio}; no reference "
                "force): at rest, or loaded throughout if the record never shows the sensor unloaded"
            )
        load = f" at about {self.force_n:.4g} N" if math.isfinite(self.force_n) else " (load unknown)"
        return (
            f"the record starts loaded{load}: its first {self.n_rows} rows read {ratio}, more than "
            f"{UNLOADED_FACTOR:g} x below it (no reference force); the sensor's load history before the "
            "record is unknown"
        )

    def as_json(self) -> dict[str, object]:
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "loaded": self.loaded,
            "force_n": num(self.force_n),
            "source": self.source,
            "rows": self.n_rows,
            "threshold_n": num(self.threshold_n),
            "resistance_ohm": num(self.resistance_ohm),
            "unloaded_resistance_ohm": num(self.unloaded_ohm),
            "held_s": num(self.held_s),
            "sentence": self.sentence(),
        }


def _ohm(r: float) -> str:
    if math.isinf(r):
        return "open circuit"
    return f"{r / 1e3:.4g} kohm" if r >= 1e3 else f"{r:.4g} ohm"


def start_threshold_n(force_n: ArrayLike) -> float:
    """The reference force (N) above which a record starts loaded (module docstring)."""
    f = np.asarray(force_n, dtype=np.float64)
    finite = f[np.isfinite(f)]
    full_scale = float(finite.max()) if finite.size else 0.0
    return max(hold_tolerance_n(f), zero_noise_tolerance_n(full_scale))


def start_load(
    time_s: ArrayLike,
    resistance_ohm: ArrayLike,
    force_n: ArrayLike | None = None,
    force_of: Callable[[float], float] | None = None,
    rows: int = START_ROWS,
) -> StartLoad:
    """Whether the series starts loaded (module docstring): times in s, resistances in ohm
    (+inf open), the reference force in N when there is one; ``force_of`` reads a resistance
    as a force (a calibration) where there is not."""
    t = np.asarray(time_s, dtype=np.float64)
    r = np.asarray(resistance_ohm, dtype=np.float64)
    n = min(rows, r.size)
    if n == 0:
        raise ValueError("an empty record has no start")
    r_start = float(np.median(r[:n]))
    if force_n is not None:
        f = np.asarray(force_n, dtype=np.float64)
        threshold = start_threshold_n(f)
        f_start = float(np.median(f[:n]))
        loaded = f_start > threshold
        held = math.nan
        if loaded:
            left = np.flatnonzero(np.abs(f - f_start) > threshold)
            held = float(t[left[0]] - t[0]) if left.size else float(t[-1] - t[0])
        return StartLoad(loaded, f_start, "reference", n, threshold, r_start, math.nan, held)
    unloaded = float(np.quantile(r[~np.isnan(r)], UNLOADED_QUANTILE, method="higher"))
    loaded = bool(r_start * UNLOADED_FACTOR < unloaded)
    force = math.nan
    if loaded and force_of is not None:
        force = float(force_of(r_start))
    elif not loaded:
        force = 0.0 if math.isinf(r_start) else math.nan
    return StartLoad(loaded, force, "resistance", n, math.nan, r_start, unloaded)


def channel_start_load(channel: ChannelRecord, force_of: Callable[[float], float] | None = None) -> StartLoad:
    """``start_load`` of one channel of a record (its reference force when it has one)."""
    return start_load(channel.time_s, channel.resistance_ohm, channel.force_n, force_of)
