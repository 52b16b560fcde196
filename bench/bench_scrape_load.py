"""Poll schedule under scrapes: 32 simulated arrays of 64 channels (a simulator process, one
TCP server, device ids 1-32) polled by one gateway on 4 buses of 8 devices every 0.25 s, with
the real HTTP server, while a client scrapes ``/metrics`` 10 times a second. Reported: the
lateness of poll-cycle starts (p50, p99) without scrapes, with scrapes of the directly
written exposition, and with scrapes through the client library's ``generate_latest`` (the
previous collector), in the same run. Goal: p99 below 5 ms with 10 scrapes/s."""

from __future__ import annotations

import asyncio
import itertools
import socket
import statistics
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

from prometheus_client import CollectorRegistry

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.metrics.collector import make_registry
from gateway.metrics.exposition import SnapshotRegistry
from gateway.metrics.server import MetricsServer
from gateway.model import SensorParams
from gateway.runtime.bus import BusWorker
from gateway.runtime.poller import Poller, SnapshotHolder

DEVICES, CHANNELS, BUSES, INTERVAL_S, PHASE_S, SCRAPES_PER_S = 32, 64, 4, 0.25, 12.0, 10.0
BIN = Path(sys.executable).parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _instrument(worker: BusWorker, cycles: list[tuple[float, float]]) -> None:
    original = worker.poll_cycle

    async def timed(*, settle: bool = True) -> None:
        t0 = time.monotonic()
        await original(settle=settle)
        cycles.append((t0, time.monotonic()))

    worker.poll_cycle = timed  # type: ignore[method-assign]


def _lateness_ms(cycles: list[tuple[float, float]]) -> list[float]:
    """Start of each cycle minus when the bus task meant to start it: the previous schedule
    plus the interval, or the previous cycle's end when that cycle overran."""
    out: list[float] = []
    scheduled = cycles[0][0]
    for (_, prev_end), (start, _) in itertools.pairwise(cycles):
        scheduled = max(scheduled + INTERVAL_S, prev_end)
        out.append(max(0.0, start - scheduled) * 1e3)
    return out


def _scraper(url: str, stop: threading.Event, durations: list[float]) -> None:
    period = 1.0 / SCRAPES_PER_S
    next_t = time.monotonic()
    while not stop.is_set():
        t0 = time.monotonic()
        with urllib.request.urlopen(url, timeout=10) as response:
            response.read()
        durations.append(time.monotonic() - t0)
        next_t += period
        stop.wait(max(0.0, next_t - time.monotonic()))


async def _phase(mode: str, sim_port: int) -> tuple[list[float], list[float]]:
    devices = [
        device_config_for(f"arr{d:02d}", d + 1, [SensorParams()] * CHANNELS, 8, 2.5) for d in range(DEVICES)
    ]
    per_bus = DEVICES // BUSES
    buses = [
        bus_config_for(
            f"bus{b}", "tcp", devices[b * per_bus : (b + 1) * per_bus], host="127.0.0.1", port=sim_port,
            poll_interval_s=INTERVAL_S, timeout_s=1.0,
        )
        for b in range(BUSES)
    ]  # fmt: skip
    holder = SnapshotHolder()
    registry = (
        SnapshotRegistry(holder.get)
        if mode == "direct"
        else make_registry(holder.get, CollectorRegistry(auto_describe=False))
    )
    server = MetricsServer(registry, "127.0.0.1", 0).start()
    poller = Poller(gateway_config_for(buses), holder)
    starts: dict[str, list[tuple[float, float]]] = {w.name: [] for w in poller.workers}
    for worker in poller.workers:
        _instrument(worker, starts[worker.name])
    stop = threading.Event()
    durations: list[float] = []
    scraper = threading.Thread(target=_scraper, args=(server.url, stop, durations), daemon=True)
    try:
        async with poller:
            await asyncio.sleep(2.0)  # connect and warm up
            for s in starts.values():
                s.clear()
            if mode != "none":
                scraper.start()
            await asyncio.sleep(PHASE_S)
    finally:
        stop.set()
        if scraper.is_alive():
            scraper.join(timeout=20)
        server.stop()
    late = [x for s in starts.values() if len(s) > 2 for x in _lateness_ms(s)]
    overran = sum(1 for s in starts.values() for a, b in s if b - a > INTERVAL_S)
    late.append(-float(overran))  # carried to the report: cycles longer than the interval
    return late, durations


def _p(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100)[int(q) - 1] if len(values) >= 2 else float("nan")


def _start_sim(port: int) -> subprocess.Popen[bytes]:
    ids = ",".join(str(i + 1) for i in range(DEVICES))
    return subprocess.Popen(
        [str(BIN / "tactile-sim"), "run", "--tcp", f"127.0.0.1:{port}", "--channels", str(CHANNELS),
         "--device-ids", ids, "--scenario", "sine"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


async def bench() -> None:
    port = _free_port()
    sim = _start_sim(port)
    try:
        await asyncio.sleep(3.0)
        print(
            f"{DEVICES} arrays x {CHANNELS} channels on {BUSES} buses, every {INTERVAL_S} s; "
            f"{SCRAPES_PER_S:g} scrapes/s"
        )
        for mode, label in (
            ("none", "no scrapes"),
            ("direct", "direct exposition"),
            ("library", "generate_latest"),
        ):
            late, durations = await _phase(mode, port)
            overran = int(-late.pop())
            scrape = f", scrape median {statistics.median(durations) * 1e3:.1f} ms" if durations else ""
            print(
                f"  {label:18s}: poll-start lateness p50 {_p(late, 50):6.2f} ms, p99 {_p(late, 99):6.2f} ms "
                f"({len(late)} cycles, {overran} longer than the interval){scrape} (goal p99 < 5 ms)"
            )
    finally:
        sim.terminate()
        sim.wait(timeout=20)


def main() -> None:
    asyncio.run(bench())
