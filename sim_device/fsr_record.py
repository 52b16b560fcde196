"""Emulated FSR runs (``EmulatedRecord``) and their record file (``docs/record-format.md``)."""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .fsr_params import FloatArray, FsrParams, RunConditions, require, require_finite


@dataclass(frozen=True, eq=False)
class EmulatedRecord:
    """One emulated run; arrays are per sample, times from the run's start."""

    time_s: FloatArray
    force_n: FloatArray  # the load cell's reading
    true_force_n: FloatArray  # the applied force, noise-free
    resistance_ohm: FloatArray  # the ohmmeter's reading (inf: open / over range)
    sensor_resistance_ohm: FloatArray  # the sensor's true resistance, without lead and meter
    static_resistance_ohm: FloatArray  # the run's static curve at the true force
    effective_force_n: FloatArray  # F_eff = F + x1 + x2 + phi + the creep chain's states
    run: int
    conditions: RunConditions
    cycles: int  # loading cycles in this run
    protocol_name: str
    seed: int
    params: FsrParams
    sample_interval_s: float

    @property
    def n_samples(self) -> int:
        return int(self.time_s.size)

    def static_force_n(self, resistance_ohm: FloatArray | None = None) -> FloatArray:
        """The force (N) the run's static curve reads from a resistance (default: the ohmmeter's).

        Inverts ``R = R_lead + 1 / (g_run k F^n_run + 1/R_leak)``: ``F = (G / (g_run k))^(1/n_run)``
        with ``G = 1 / (R - R_lead) - 1/R_leak``; 0 where G <= 0 (open, or at the leakage).
        This is a static lookup: what a reader without a creep model makes of the reading.
        """
        p, c = self.params, self.conditions
        r = self.resistance_ohm if resistance_ohm is None else np.asarray(resistance_ohm, dtype=np.float64)
        leak = 0.0 if math.isinf(p.leakage_ohm) else 1.0 / p.leakage_ohm
        with np.errstate(divide="ignore", invalid="ignore"):
            g = 1.0 / (r - p.lead_ohm) - leak
        g = np.where(np.isfinite(g) & (g > 0.0), g, 0.0)
        return np.asarray(np.power(g / (c.gain * p.k_s), 1.0 / c.exponent))


def _describe(p: FsrParams, sample_interval_s: float) -> dict[str, str]:
    effects = p.out_of_catalogue()
    parts = [f"{k}={v:g}" for k, v in effects.items()]
    if "humidity" in effects:
        parts[-1] += f" (period {p.humidity_period_s:g} s)"
    counts = f"{p.ohmmeter_counts} counts per range" if p.ohmmeter_counts else "ideal (no quantisation)"
    absolute = f" (+ {p.ohmmeter_noise_ohm:g} ohm rms)" if p.ohmmeter_noise_ohm > 0.0 else ""
    lag = f", lag {p.load_cell_lag_s:g} s behind the sensor" if p.load_cell_lag_s > 0.0 else ""
    bursts = ""
    if p.burst_size > 0:
        bursts = f", in bursts of {p.burst_size} samples, {p.burst_gap_s:g} s between bursts"
    described = {
        "force_reference": (
            f"emulated load cell, noise {p.load_cell_noise_n:g} N rms, zero offset per run "
            f"(sigma {p.load_cell_offset_sigma_n:g} N), resolution {p.load_cell_resolution_n:g} N, "
            f"no negative readings{lag}"
        ),
        "ohmmeter": (
            f"2-wire, leads {p.lead_ohm:g} ohm included, "
            f"{100 * p.ohmmeter_noise_rel:g} % rms noise{absolute}, "
            f"{counts}, auto-ranging {p.ohmmeter_min_range_ohm:g} .. {p.ohmmeter_max_range_ohm:g} ohm, "
            "open and over range as inf"
        ),
        "sample_interval_s": f"{sample_interval_s:g} (jitter +-{100 * p.jitter_fraction:g} %){bursts}",
        "out_of_catalogue": ", ".join(parts) if parts else "none",
    }
    if p.creep_chain:
        described["creep_chain"] = "; ".join(
            f"a={e.amplitude:+g} tau_load={e.tau_load_s:g} s tau_recovery={e.tau_recovery_s:g} s"
            for e in p.creep_chain
        )
    return described


def _joined(values: Sequence[object]) -> str:
    distinct = list(dict.fromkeys(str(v) for v in values))
    return distinct[0] if len(distinct) == 1 else ", ".join(str(v) for v in values)


def _fmt(values: FloatArray, spec: str) -> list[str]:
    return [spec % v if math.isfinite(v) else "inf" for v in values.tolist()]


def write_record(
    path: str | os.PathLike[str],
    records: Sequence[EmulatedRecord],
    channel: str = "0",
    *,
    gap_s: float = 60.0,
    metadata: Mapping[str, object] | None = None,
) -> Path:
    """Write ``records`` as one record file (``docs/record-format.md``), atomically.

    Columns ``time_s,channel,resistance_ohm,force_n`` (the ohmmeter's and the load cell's
    readings). Time continues across runs: each run starts ``gap_s`` after the previous
    run's last sample; ``# runs:`` lists the start times (s, comma separated). ``metadata``
    adds or overrides ``# key: value`` lines. Returns the path written.
    """
    require(len(records) > 0, "write_record needs at least one record")
    require_finite(gap_s, "gap_s", low=0.0, strict=True)
    require(
        bool(channel.strip()) and "," not in channel and "\n" not in channel, f"bad channel name {channel!r}"
    )
    first = records[0]
    require(
        all(r.params == first.params for r in records),
        "records written together must come from the same FsrParams",
    )
    starts: list[float] = []
    start = 0.0
    for rec in records:
        starts.append(start)
        last = float(rec.time_s[-1]) if rec.n_samples else 0.0
        start = start + last + gap_s
    meta: dict[str, object] = {
        "source": "sim_device.fsr_emulator",
        "sensor": "emulated FSR (sim_device.fsr_emulator)",
        "time": "real",
        "runs": ", ".join(f"{s:.6f}" for s in starts),
        "seed": _joined([r.seed for r in records]),
        "protocol": _joined([r.protocol_name for r in records]),
        **_describe(first.params, first.sample_interval_s),
    }
    meta.update(metadata or {})
    lines = [f"# {k}: {str(v).replace(chr(10), ' ')}\n" for k, v in meta.items()]
    lines.append("time_s,channel,resistance_ohm,force_n\n")
    for rec, s0 in zip(records, starts, strict=True):
        cols = (
            _fmt(rec.time_s + s0, "%.6f"),
            _fmt(rec.resistance_ohm, "%.10g"),
            _fmt(rec.force_n, "%.10g"),
        )
        lines.extend(f"{a},{channel},{b},{c}\n" for a, b, c in zip(*cols, strict=True))
    target = Path(path)
    if not target.parent.is_dir():
        raise FileNotFoundError(f"cannot write {target}: no directory {target.parent}")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.writelines(lines)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return target
