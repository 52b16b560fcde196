"""The physical model's fits (``fitting.fit_channel``) with a fit's force history kept across
its residuals (``model.series.ForceSeries``: the state effects' series and the force-only
terms reused while their parameters are unchanged) against the same fits solving everything
again for every residual (the history rebuilt per residual, as before issue 32): the ratio,
and whether the fitted parameters are the same to the bit (they must be).

The record is ``bench_calibrate``'s synthetic FSR with a creep of 100 s, 3000 rows (what
``calibrate`` fits at most), fitted with creep and hysteresis by the log-R and the force
objectives, the second with the reference zero offset too."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from gateway.analysis import objectives
from gateway.analysis.fitting import FitData, FitResult, fit_channel
from gateway.analysis.records import read_record
from gateway.model.series import ForceSeries

from .bench_calibrate import creep_record

ROWS = 3000
EFFECTS = ("tunneling", "contact", "creep", "hysteresis")


def _fits(data: FitData) -> list[FitResult]:
    return [
        fit_channel(data, EFFECTS, objective="log_r"),
        fit_channel(data, EFFECTS, objective="force", fit_force_offset=True),
    ]


def _rebuilt(self: objectives.Problem, offset: float, up: bool) -> ForceSeries:
    """The history made anew for every residual: nothing is reused."""
    force = self.data.force_n + offset + (self.step if up else 0.0)
    return ForceSeries.of(force[:, None], self.data.time_s, 1)


def _timed(run: Callable[[], list[FitResult]]) -> tuple[float, list[FitResult]]:
    start = time.perf_counter()
    out = run()
    return time.perf_counter() - start, out


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = creep_record(Path(folder) / "slow.csv", tau_s=100.0, rows=ROWS)
        channel = next(iter(read_record(path).channels.values()))
    data = FitData.from_channel(channel)
    kept_s, kept = _timed(lambda: _fits(data))
    original = objectives.Problem._history
    objectives.Problem._history = _rebuilt  # type: ignore[method-assign]
    try:
        rebuilt_s, rebuilt = _timed(lambda: _fits(data))
    finally:
        objectives.Problem._history = original  # type: ignore[method-assign]
    pairs = zip(kept, rebuilt, strict=True)
    same = all(a.params == b.params and a.force_offset_n == b.force_offset_n for a, b in pairs)
    print(f"fits of {ROWS} rows ({', '.join(EFFECTS)}; log-R, force with offset)")
    print(
        f"  history kept {kept_s:.2f} s, rebuilt per residual {rebuilt_s:.2f} s: {rebuilt_s / kept_s:.2f} x"
    )
    print(f"  the same parameters to the bit: {same}")


if __name__ == "__main__":
    main()
