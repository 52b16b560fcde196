"""``tactile-gateway view``'s load and ``apply``: a record whose rows each have their own time
against the same rows with shared times (issue 33 §8).

For each case, two records of the same rows (the same channels, resistances in the same
order, a reference force) are written: "shared", where the k-th row of every channel is at
one time (a device sample of all channels), and "distinct", where every row has its own time
(the channels' rows interleaved, 1/n of a step apart: a device sample per row). Each is loaded
as ``view`` loads it before serving (``load_playback``: read, replay, frames, and the page's
JSON body, ``PlaybackPage``), with the fallback layout; the time of the distinct record over
the shared one's, in the same run, is the ratio (goal: a small factor; before the fix each row
of its own cost one conversion of the whole device, about 3 ms). ``apply_calibration`` (a
calibration of every channel with r0 = 150 kohm, the record read beforehand) is timed the same
way.

Cases: 16 and 64 channels at 1,000, 2,000 and 4,000 distinct times (rows), and the two record
sizes of the issue (82 KB and 0.87 MB, 16 channels). ``BENCH_VIEW_CASES`` limits the cases to
those whose label contains one of its comma-separated words (e.g. ``16ch``, ``KB``).
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

from gateway.analysis.apply import apply_calibration
from gateway.analysis.records import RecordWriter, read_record
from gateway.cli.view_cmd import load_playback
from gateway.web.playback import PlaybackPage

#: (label, channels, rows); the record sizes' rows are found by writing (``_rows_for_bytes``)
CASES: tuple[tuple[str, int, int | str], ...] = (
    ("16ch 1000 rows", 16, 1000),
    ("16ch 2000 rows", 16, 2000),
    ("16ch 4000 rows", 16, 4000),
    ("64ch 1000 rows", 64, 1000),
    ("64ch 2000 rows", 64, 2000),
    ("64ch 4000 rows", 64, 4000),
    ("16ch 82 KB", 16, "82000"),
    ("16ch 0.87 MB", 16, "870000"),
)
STEP_S = 0.01


def _resistance_ohm(row: int, channel: int) -> float:
    """A press that moves over the array: about 15-60 kohm, open (inf) a third of the time."""
    if (row // 40 + channel) % 3 == 0:
        return math.inf
    return 15e3 * (2.5 + 1.5 * math.sin(row / 25.0 + channel))


def write_record(path: Path, channels: int, rows: int, distinct: bool) -> int:
    """``rows`` rows over ``channels`` channels in turn; returns the file's size in bytes."""
    with path.open("w", encoding="utf-8") as out:
        writer = RecordWriter(out, {"source": "bench_view"}, has_force=True)
        for i in range(rows):
            k, sample = i % channels, i // channels
            t = (i if distinct else sample * channels) * STEP_S / channels
            writer.row(round(t, 9), f"ch{k:02d}", _resistance_ohm(sample, k), 1.0, None)
    return path.stat().st_size


def _rows_for_bytes(target: int, channels: int, where: Path) -> int:
    """The rows of a distinct-time record of about ``target`` bytes."""
    probe = 2000
    size = write_record(where / "probe.csv", channels, probe, True)
    return max(channels, round(probe * target / size))


def _apply_s(path: Path, calibration: Path) -> float:
    """Seconds for ``apply_calibration`` over ``path`` (the record read beforehand)."""
    record = read_record(path)
    start = time.perf_counter()
    apply_calibration(calibration, record)
    return time.perf_counter() - start


def _load_s(path: Path) -> tuple[float, int, int]:
    """Seconds to load ``path`` as ``view`` does, its frames and its device samples."""
    start = time.perf_counter()
    playback = load_playback(path, None, None)
    PlaybackPage(playback)
    return time.perf_counter() - start, len(playback.frames), playback.samples_total


def main() -> None:
    wanted = [w for w in os.environ.get("BENCH_VIEW_CASES", "").split(",") if w]
    print("view's load (read, replay, frames, page body): every row its own time / shared times")
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(tmp)
        for label, channels, rows_or_bytes in CASES:
            if wanted and not any(w in label for w in wanted):
                continue
            if isinstance(rows_or_bytes, str):
                rows = _rows_for_bytes(int(rows_or_bytes), channels, where)
            else:
                rows = rows_or_bytes
            shared_path, distinct_path = where / "shared.csv", where / "distinct.csv"
            write_record(shared_path, channels, rows, False)
            size = write_record(distinct_path, channels, rows, True)
            shared_s, _, shared_n = _load_s(shared_path)
            distinct_s, frames, distinct_n = _load_s(distinct_path)
            print(
                f"  {label:15s} {rows:6d} rows, {size / 1e3:7.1f} KB: shared {shared_s:6.2f} s "
                f"({shared_n} samples), distinct {distinct_s:6.2f} s ({distinct_n} samples, "
                f"{frames} frames), ratio {distinct_s / shared_s:5.2f}",
                flush=True,
            )
            calibration = where / "cal.toml"
            calibration.write_text(
                "".join(f'[channel."ch{k:02d}"]\nr0_ohm = 150e3\n' for k in range(channels))
            )
            shared_s, distinct_s = _apply_s(shared_path, calibration), _apply_s(distinct_path, calibration)
            print(
                f"  {'':15s} apply: shared {shared_s:6.2f} s, distinct {distinct_s:6.2f} s, "
                f"ratio {distinct_s / shared_s:5.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
