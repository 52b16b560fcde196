"""Ground-truth measurement records (``shared/spec/measurement-records.md``).

A record is CSV, UTF-8, with ``# key: value`` metadata lines, one header row and one row
per sample per channel (long format)::

    # source: sim_device
    # scenario: holds
    ...
    time_s,channel,resistance_ohm,force_n,temperature_c
    0.000000,0,inf,0,25

- ``time_s``: device time since the start of the record (s), non-decreasing per channel;
- ``channel``: channel index (``<device id>.<index>`` when several arrays share a record);
- ``resistance_ohm``: the *measured* resistance, from the noisy ADC counts by eq. 18
  (``inf`` for an open circuit, as the spec allows);
- ``force_n``: the true force of the scenario; ``temperature_c``: the true temperature.

Samples of a shorted channel (measured resistance 0, which the spec does not allow) are
left out and counted in the ``omitted_short_rows`` metadata of offline records.

Live recordings (``Recorder``) are written row block by row block and flushed after each
block, so an interrupted recording leaves a valid file; offline records (``record_offline``)
are written to a temporary file and renamed into place (atomic).
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np
from numpy.typing import NDArray

from .array import Listener, SampleBatch, SimArray
from .config import ArrayConfig
from .scenarios import Scenario

FloatArray = NDArray[np.float64]
COLUMNS = ("time_s", "channel", "resistance_ohm", "force_n", "temperature_c")


def _fmt(values: FloatArray, spec: str) -> list[str]:
    return [spec % v if math.isfinite(v) else ("inf" if v > 0 else "nan") for v in values.tolist()]


def format_rows(
    time_s: FloatArray,
    channel: Sequence[str],
    resistance_ohm: FloatArray,
    force_n: FloatArray,
    temperature_c: FloatArray,
) -> str:
    """CSV text of rows in the column order of ``COLUMNS`` (no header)."""
    cols = (
        _fmt(time_s, "%.6f"),
        channel,
        _fmt(resistance_ohm, "%.9g"),
        _fmt(force_n, "%.6g"),
        _fmt(temperature_c, "%.4f"),
    )
    return "".join(f"{a},{b},{c},{d},{e}\n" for a, b, c, d, e in zip(*cols, strict=True))


def header_text(metadata: Mapping[str, object]) -> str:
    """Metadata lines ``# key: value`` and the header row."""
    lines = []
    for key, value in metadata.items():
        text = str(value).replace("\n", " ")
        lines.append(f"# {key}: {text}\n")
    return "".join(lines) + ",".join(COLUMNS) + "\n"


def array_metadata(array: SimArray, record_period_s: float) -> dict[str, object]:
    """Metadata describing how a record of ``array`` was produced."""
    cfg = array.config
    e = array.electronics
    return {
        "source": "sim_device",
        "device_id": array.device_id,
        "scenario": array.scenario.name,
        "seed": cfg.seed,
        "channels": array.n_channels,
        "grid": f"{array.layout.rows}x{array.layout.columns}, pitch {array.layout.pitch_mm:g} mm",
        "world_effects": ",".join(("tunneling", "contact", "creep", *cfg.world_effects)),
        "param_spread": "yes" if cfg.param_spread and cfg.channel_params is None else "no",
        "sample_period_s": f"{e.sample_period_s:g}",
        "record_period_s": f"{record_period_s:g}",
        "adc_bits": e.adc_bits,
        "noise_lsb_rms": f"{e.noise_lsb_rms:g}",
        "supply_v": f"{e.supply_v:g}",
        "reference_ohm": f"{e.reference_ohm:g}",
        **_map_metadata(cfg),
    }


def _map_metadata(cfg: ArrayConfig) -> dict[str, object]:
    """The register map and read-out, named only when not the default (whose records stay as they were)."""
    if cfg.register_map == "tactile-sim":
        return {}
    return {
        "register_map": cfg.register_map,
        "readout": "low-side divider, pull-up reference_ohm from supply_v",
        "board_leakage_ohm": f"{cfg.board_leakage_ohm:g}",
    }


@dataclass
class _Picker:
    """Selects one sample per record period (the first sample at or after each period start)."""

    record_period_s: float
    start_s: float
    last_bucket: int = -1

    def pick(self, time_s: FloatArray) -> NDArray[np.intp]:
        buckets = np.floor((time_s - self.start_s) / self.record_period_s + 1e-9).astype(np.int64)
        first = np.ones(buckets.shape[0], dtype=bool)
        first[1:] = buckets[1:] != buckets[:-1]
        chosen = np.nonzero(first & (buckets > self.last_bucket))[0]
        if chosen.size:
            self.last_bucket = int(buckets[chosen[-1]])
        return chosen


def _long_rows(
    batch: SampleBatch, rows: NDArray[np.intp], start_s: float, labels: Sequence[str]
) -> tuple[FloatArray, list[str], FloatArray, FloatArray, FloatArray, int]:
    n = batch.force_n.shape[1]
    t = np.repeat(batch.time_s[rows] - start_s, n)
    r = batch.resistance_ohm[rows].reshape(-1)
    f = batch.force_n[rows].reshape(-1)
    temp = batch.temperature_c[rows].reshape(-1)
    ch = np.tile(np.arange(n), rows.shape[0])
    keep = r > 0.0
    omitted = int((~keep).sum())
    if omitted:
        t, r, f, temp, ch = t[keep], r[keep], f[keep], temp[keep], ch[keep]
    return t, [labels[i] for i in ch.tolist()], r, f, temp, omitted


class Recorder:
    """Writes the samples of live arrays to a record, one row block per batch, flushed.

    ``attach`` it to one or more arrays; ``close`` detaches and closes the file.
    """

    def __init__(self, path: str | Path, record_period_s: float, metadata: Mapping[str, object]) -> None:
        if not (math.isfinite(record_period_s) and record_period_s > 0):
            raise ValueError(f"record_period_s must be > 0, got {record_period_s!r}")
        self.path = Path(path)
        self.record_period_s = record_period_s
        self._file: TextIO = self.path.open("w", encoding="utf-8", newline="")
        self._file.write(header_text(metadata))
        self._file.flush()
        self._arrays: list[tuple[SimArray, Listener]] = []
        self.rows_written = 0

    def attach(self, array: SimArray, labels: Sequence[str] | None = None) -> None:
        """Record ``array`` from its latest sample on; ``labels`` name its channels."""
        names = list(labels) if labels is not None else [str(i) for i in range(array.n_channels)]
        picker = _Picker(self.record_period_s, array.last_sample_time_s)

        def listener(batch: SampleBatch) -> None:
            self._write(batch, picker, names)

        self._arrays.append((array, listener))
        self._write(array.latest(), picker, names)
        array.add_listener(listener)

    def _write(self, batch: SampleBatch, picker: _Picker, labels: Sequence[str]) -> None:
        if self._file.closed:
            return
        rows = picker.pick(batch.time_s)
        if rows.size == 0:
            return
        t, ch, r, f, temp, _omitted = _long_rows(batch, rows, picker.start_s, labels)
        self._file.write(format_rows(t, ch, r, f, temp))
        self._file.flush()
        self.rows_written += len(ch)

    def close(self) -> None:
        for array, listener in self._arrays:
            array.remove_listener(listener)
        self._arrays.clear()
        if not self._file.closed:
            self._file.close()


@dataclass
class Record:
    """A measurement record in memory (long format arrays, one entry per row)."""

    metadata: dict[str, object]
    time_s: FloatArray
    channel: list[str]
    resistance_ohm: FloatArray
    force_n: FloatArray
    temperature_c: FloatArray
    omitted_short_rows: int = 0

    @property
    def n_rows(self) -> int:
        return int(self.time_s.shape[0])

    def to_csv_text(self) -> str:
        return header_text(self.metadata) + format_rows(
            self.time_s, self.channel, self.resistance_ohm, self.force_n, self.temperature_c
        )

    def write_csv(self, path: str | Path) -> Path:
        """Write atomically: a temporary file in the same directory, renamed into place."""
        target = Path(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
                fh.write(self.to_csv_text())
            os.replace(tmp, target)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        return target


def record_offline(
    config: ArrayConfig,
    scenario: str | Scenario | None = None,
    duration_s: float | None = None,
    path: str | Path | None = None,
    *,
    record_period_s: float | None = None,
    device_id: int = 1,
    metadata: Mapping[str, object] | None = None,
) -> Record:
    """Simulate ``config`` (with ``scenario`` if given) for ``duration_s`` of device time, no server.

    Deterministic for a given config (seeded parameters and noise). Every sample is
    simulated exactly; one row per channel is kept every ``record_period_s`` (default
    0.1 s, at least one sample period). ``duration_s`` defaults to the scenario's duration
    (60 s for a scenario without one). Writes ``path`` atomically if given.
    """
    cfg = config if scenario is None else config.with_changes(scenario=scenario)
    array = SimArray(cfg, device_id, clock=lambda: 0.0)
    total = float(duration_s) if duration_s is not None else (array.scenario.duration_s or 60.0)
    if not (math.isfinite(total) and total >= 0.0):
        raise ValueError(f"duration_s must be a finite number >= 0, got {duration_s!r}")
    period = record_period_s if record_period_s is not None else max(0.1, cfg.sample_period_s)
    if not (math.isfinite(period) and period > 0):
        raise ValueError(f"record_period_s must be > 0, got {record_period_s!r}")
    picker = _Picker(period, 0.0)
    labels = [str(i) for i in range(array.n_channels)]
    parts: list[tuple[FloatArray, list[str], FloatArray, FloatArray, FloatArray]] = []
    omitted = 0

    def collect(batch: SampleBatch) -> None:
        nonlocal omitted
        rows = picker.pick(batch.time_s)
        if rows.size:
            t, ch, r, f, temp, om = _long_rows(batch, rows, 0.0, labels)
            parts.append((t, ch, r, f, temp))
            omitted += om

    collect(array.latest())
    array.add_listener(collect)
    array.advance(total, exact=True)
    array.remove_listener(collect)
    meta: dict[str, object] = array_metadata(array, period)
    meta["duration_s"] = f"{total:g}"
    if omitted:
        meta["omitted_short_rows"] = omitted
    meta.update(metadata or {})
    record = Record(
        metadata=meta,
        time_s=np.concatenate([p[0] for p in parts]) if parts else np.zeros(0),
        channel=[c for p in parts for c in p[1]],
        resistance_ohm=np.concatenate([p[2] for p in parts]) if parts else np.zeros(0),
        force_n=np.concatenate([p[3] for p in parts]) if parts else np.zeros(0),
        temperature_c=np.concatenate([p[4] for p in parts]) if parts else np.zeros(0),
        omitted_short_rows=omitted,
    )
    if path is not None:
        record.write_csv(path)
    return record
