"""Record benchmark (issue 34 §6): size and write cost of a record of a 1,062-taxel hand at
30 Hz, CSV against MCAP (zstd, lz4, uncompressed), measured in the same run.

Each frame is one poll: 1,062 rows (``time_s``, ``channel``, ``resistance_ohm``; the hand has
no load cell or temperature), resistances as the gateway reads them through a 12-bit divider
(a few counts of noise around each taxel's level, a third of the taxels pressed and drifting).
Write cost is the writer's CPU time per frame (``time.process_time``: rows, flush, and for
MCAP the chunk compression and the closing index, spread over the frames), against the 33 ms
a frame lasts at 30 Hz; size is extrapolated to an hour from the file written. The read-back
time of the whole file by ``read_record`` is shown too.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gateway.analysis.mcap_records import COMPRESSIONS, Compression, McapRecordWriter
from gateway.analysis.records import RecordWriter, read_record
from gateway.atomic import AtomicFile

CHANNELS = 1062
RATE_HZ = 30.0
FRAMES = 300  # 10 s of recording
REFERENCE_OHM = 10_000.0
ADC_COUNTS = 4096


def _frames(seed: int = 0) -> tuple[list[str], np.ndarray]:
    """Channel names (the hand's 17 regions) and the resistances (ohm) of every frame."""
    regions = [f"finger{f}_{part}" for f in range(1, 5) for part in ("tip", "nail", "pad")]
    regions += ["thumb_tip", "thumb_nail", "thumb_middle", "thumb_pad", "palm"]
    names = [f"{regions[k % len(regions)]}/t{k:04d}" for k in range(CHANNELS)]
    rng = np.random.default_rng(seed)
    level = rng.integers(200, 3800, CHANNELS).astype(float)
    pressed = rng.random(CHANNELS) < 0.33
    t = np.arange(FRAMES) / RATE_HZ
    drift = 300.0 * np.sin(2 * np.pi * t[:, None] / 4.0) * pressed
    counts = np.clip(np.rint(level + drift + rng.normal(0.0, 2.0, (FRAMES, CHANNELS))), 1, ADC_COUNTS - 1)
    return names, REFERENCE_OHM * counts / (ADC_COUNTS - counts)


def _write(
    path: Path, make: Callable[[AtomicFile], RecordWriter | McapRecordWriter], names: list[str], r: np.ndarray
) -> float:
    """CPU seconds per frame to write every frame to ``path`` (committed)."""
    rows = r.tolist()
    with AtomicFile(path) as out:
        t0 = time.process_time()
        writer = make(out)
        for i, values in enumerate(rows):
            t_s = round(i / RATE_HZ, 6)
            for name, value in zip(names, values, strict=True):
                writer.row(t_s, name, value)
            writer.flush()
        writer.close()
        cpu_s = time.process_time() - t0
        out.commit()
    return cpu_s / len(rows)


def _maker(
    compression: Compression | None, meta: dict[str, str]
) -> Callable[[AtomicFile], RecordWriter | McapRecordWriter]:
    """A writer of CSV (``compression`` None) or of MCAP with ``compression``."""

    def make(out: AtomicFile) -> RecordWriter | McapRecordWriter:
        if compression is None:
            return RecordWriter(out.text, meta)
        return McapRecordWriter(out, meta, compression=compression)

    return make


def main() -> None:
    names, r = _frames()
    meta = {"source": "bench_record"}
    forms: list[tuple[str, str, Compression | None]] = [("csv", "csv", None)]
    forms += [(f"mcap {c}", "mcap", c) for c in COMPRESSIONS]
    frame_budget_s = 1.0 / RATE_HZ
    print(
        f"{CHANNELS} channels at {RATE_HZ:g} Hz, {FRAMES} frames ({FRAMES / RATE_HZ:g} s); "
        f"a frame lasts {1e3 * frame_budget_s:.1f} ms"
    )
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, ext, compression in forms:
            path = Path(tmp) / f"rec.{ext}"
            cpu_s = min(_write(path, _maker(compression, meta), names, r) for _ in range(2))
            size = path.stat().st_size
            t0 = time.perf_counter()
            record = read_record(path)
            read_s = time.perf_counter() - t0
            assert len(record.channels) == CHANNELS and record.channel(names[0]).n_samples == FRAMES
            results.append((label, size, cpu_s, read_s))
    csv_size, csv_cpu = results[0][1], results[0][2]
    heads = ("bytes/frame", "GB/hour", "vs CSV", "CPU/frame", "of frame", "vs CSV", "read/frame")
    widths = (12, 8, 7, 11, 9, 7, 11)
    print(f"{'format':<12}" + "".join(f" {h:>{w}}" for h, w in zip(heads, widths, strict=True)))
    for label, size, cpu_s, read_s in results:
        per_frame = size / FRAMES
        per_hour_gb = per_frame * RATE_HZ * 3600 / 1e9
        print(
            f"{label:<12} {per_frame:>12,.0f} {per_hour_gb:>8.2f} {size / csv_size:>7.3f} "
            f"{1e3 * cpu_s:>8.2f} ms {100 * cpu_s / frame_budget_s:>8.1f}% {cpu_s / csv_cpu:>7.2f} "
            f"{1e3 * read_s / FRAMES:>8.2f} ms"
        )


if __name__ == "__main__":
    main()
