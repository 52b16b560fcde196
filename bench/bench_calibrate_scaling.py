"""``calibrate`` from one core to a cluster (issue 36): a 64-channel simulated array (sim_device,
the ``ramps`` scenario, one row per second per channel) calibrated with one worker, the
baseline, and with every core (the ratio, and the efficiency per core = ratio / cores); then a
batch of simulated arrays on the local pool of every core against a 2-worker Dask
``LocalCluster`` (one thread each) on this machine; and from these the projected time for
1,000 arrays, on this machine and per machine of a cluster.

Each channel is a task of its own (``gateway.cli.calibrate_pool``), as the command runs it, with
the full fit (``--model auto``: the physical model with both objectives, hysteresis and the
zero offset tried, and every curve x drift candidate). Sizes: ``BENCH_SCALING_CHANNELS``
(default 64), ``BENCH_SCALING_RECORDS`` (default 20) arrays of ``BENCH_SCALING_BATCH_CHANNELS``
(default 4) channels in the batch (smaller than 64 so that the bench takes minutes, not an
hour; the projection is per channel, then per 64-channel array)."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from gateway.analysis.channel_work import FitSettings
from gateway.analysis.parallel import default_jobs
from gateway.analysis.records import read_record
from gateway.cli.calibrate_pool import open_pool, submit_channels
from gateway.cli.calibrate_progress import Quiet
from gateway.model import SensorParams, parse_effects
from sim_device import ArrayConfig, record_offline

CHANNELS = int(os.environ.get("BENCH_SCALING_CHANNELS", "64"))
RECORDS = int(os.environ.get("BENCH_SCALING_RECORDS", "20"))
BATCH_CHANNELS = int(os.environ.get("BENCH_SCALING_BATCH_CHANNELS", "4"))
SETTINGS = FitSettings(parse_effects("tunneling,contact,creep"), SensorParams(), "auto", "auto")


def array_record(path: Path, channels: int, seed: int) -> Path:
    """A simulated array under load ramps (190 s, 0-5 N at three rates), channels taxel0..."""
    config = ArrayConfig(
        channels=channels, columns=min(channels, 8), seed=seed, scenario="ramps", sensor_noise_rel=0.01
    )
    record = record_offline(config, record_period_s=1.0)
    record.channel = [f"taxel{c}" for c in record.channel]
    record.write_csv(path)
    return path


def calibrate_all(paths: list[Path], jobs: int | None, scheduler: str | None = None) -> float:
    """Seconds to calibrate every channel of every record (read here, one task per channel)."""
    t0 = time.perf_counter()
    with open_pool(jobs, scheduler) as pool:
        futures = []
        for path in paths:
            record = read_record(path, require_force=True)
            channels = [record.channel(n) for n in record.channels]
            futures += submit_channels(pool, SETTINGS, channels, str(path), record.metadata, Quiet())
        for f in futures:
            f.result()
    return time.perf_counter() - t0


def main() -> None:
    from distributed import LocalCluster

    cores = default_jobs()
    with tempfile.TemporaryDirectory() as tmp:
        one = [array_record(Path(tmp) / "array.csv", CHANNELS, seed=3)]
        cpu0_s = time.process_time()
        serial_s = calibrate_all(one, jobs=1)  # inline: this process's CPU time is the run's
        serial_cpu_s = time.process_time() - cpu0_s
        every_s = calibrate_all(one, jobs=cores)
        ratio = serial_s / every_s
        print(f"a {CHANNELS}-channel array, 190 rows a channel, calibrate --model auto:")
        print(
            f"  1 worker: {serial_s:.1f} s (baseline, {serial_s / CHANNELS:.2f} s a channel; "
            f"{serial_cpu_s:.1f} s of CPU)"
        )
        print(
            f"  {cores} workers (every core): {every_s:.1f} s: {ratio:.2f} x the baseline, "
            f"efficiency {ratio / cores:.0%} per core; {serial_cpu_s / every_s:.2f} x the baseline's CPU "
            "time (its wall time on an idle core: the ratio a machine busy with other work hides)"
        )
        batch = [
            array_record(Path(tmp) / f"array{k:02d}.csv", BATCH_CHANNELS, seed=10 + k) for k in range(RECORDS)
        ]
        n = RECORDS * BATCH_CHANNELS
        pool_s = calibrate_all(batch, jobs=cores)
        with LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, host="127.0.0.1"
        ) as cluster:
            cluster_s = calibrate_all(batch, jobs=None, scheduler=cluster.scheduler_address)
        print(f"{RECORDS} arrays of {BATCH_CHANNELS} channels ({n} channels):")
        print(f"  local pool, {cores} workers: {pool_s:.1f} s (baseline, {pool_s / n:.2f} s a channel)")
        print(
            f"  Dask LocalCluster, 2 workers x 1 thread: {cluster_s:.1f} s: {cluster_s / pool_s:.2f} x the "
            f"baseline ({cluster_s / n:.2f} s a channel)"
        )
        array_h = every_s * 64 / CHANNELS / 3600  # one 64-channel array on every core here
        overhead = cluster_s / pool_s
        print("projected for 1,000 arrays of 64 channels (from the figures above):")
        print(
            f"  one core: {1000 * serial_s * 64 / CHANNELS / 3600:.1f} h; this machine ({cores} cores): "
            f"{1000 * array_h:.1f} h"
        )
        print(
            f"  10 such machines on a Dask cluster: {1000 * array_h * overhead / 10:.1f} h (this machine's "
            f"time x the cluster's {overhead:.2f} / 10, if the scheduler keeps every worker busy)"
        )
