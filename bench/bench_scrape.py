"""A scrape that scales: the exposition of 32 arrays of 64 channels (about 25,500 series),
written directly (``gateway.metrics.exposition``) against the client library's
``generate_latest`` over the same collector, in the same run: median time per scrape and per
series, and the ratio. Goal: a median below 0.1 s for the set-up."""

from __future__ import annotations

import statistics
import time

import numpy as np
from prometheus_client import CollectorRegistry, generate_latest

from gateway.config import device_config_for
from gateway.metrics.collector import make_registry
from gateway.metrics.exposition import render
from gateway.modbus.image import RawSample
from gateway.model import SensorParams
from gateway.runtime.counters import Tally
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot

DEVICES = 32
CHANNELS = 64
REPEATS = 15


def _snapshot(seed: int) -> GatewaySnapshot:
    rng = np.random.default_rng(seed)
    devices, counters = {}, {}
    for d in range(DEVICES):
        dev = device_config_for(f"arr{d:02d}", 1, [SensorParams()] * CHANNELS, 8, 2.5)
        proc = DeviceProcessor(dev, "bus", 0.05)
        counts = rng.integers(3000, 30000, CHANNELS).astype(np.uint16)
        snap, _ = proc.process(proc.initial_state(), RawSample(counts=counts, device_time_s=1.0), 1.7e9, 1.0)
        devices[dev.name] = snap
        tally = Tally()
        tally.read()
        tally.poll(0.004)
        counters[dev.name] = tally.freeze()
    return GatewaySnapshot.build(devices, counters, seed)


def main() -> None:
    snaps = [_snapshot(s) for s in range(REPEATS)]  # a new snapshot per scrape: no cache hits
    current: list[GatewaySnapshot] = [snaps[0]]
    registry = make_registry(lambda: current[0], CollectorRegistry(auto_describe=False))
    library, direct = [], []
    series = 0
    for snap in snaps:
        current[0] = snap
        t0 = time.perf_counter()
        body = generate_latest(registry)
        library.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        text = render(snap)
        direct.append(time.perf_counter() - t0)
        assert text.encode() == body
        series = sum(1 for line in text.splitlines() if not line.startswith("#"))
    lib, new = statistics.median(library), statistics.median(direct)
    print(f"{DEVICES} arrays x {CHANNELS} channels: {series} series, {len(body) / 1e6:.2f} MB per scrape")
    print(
        f"  client library generate_latest: median {lib * 1e3:6.1f} ms ({lib / series * 1e6:.2f} us/series)"
    )
    print(
        f"  direct exposition:              median {new * 1e3:6.1f} ms ({new / series * 1e6:.2f} us/series)"
    )
    print(
        f"  ratio library / direct: {lib / new:.1f}x "
        f"(goal: median below 100 ms: {'met' if new < 0.1 else 'missed'})"
    )
