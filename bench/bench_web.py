"""The live page and frame stream under load: frame latency, and the poll rate they cost.

A simulated 64-channel array ("sine" load) in its own process, polled back to back over
loopback Modbus TCP by the gateway's bus worker; every poll is published to the hub and the
HTTP server (aiohttp in its own thread) serves the page stream and the frame stream.

1. Frame latency: from the gateway publishing a poll to a full-rate stream client (another
   process) receiving it, median and p99 (goal p99 < 50 ms on loopback); the same monotonic
   clock on both sides.
2. Poll rate with 5 page clients (``/api/live``, <= 30 frames/s each) and 2 full-rate stream
   clients (``/api/devices/NAME/stream``) connected, as a ratio to no clients; the two take
   turns in ``ROUNDS`` rounds in the same run (goal >= 0.95). The clients run in one other
   process, pinned with the device to the device's core where there are two or more.

Each measurement runs for ``BENCH_SECONDS`` (default 5) seconds in all.
"""

from __future__ import annotations

import asyncio
import json
import os
import statistics
import sys
import time

from prometheus_client import CollectorRegistry

from gateway.config import bus_config_for
from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.web import FrameHub, WebPage

from .bench_gateway import MEASURE_S, _array, _device_of, _end, _gateway, _sim_process, _split_cores

ROUNDS = 3
PAGE_CLIENTS = 5
STREAM_CLIENTS = 2

_CLIENT_SCRIPT = r"""
import asyncio, json, sys, time
import aiohttp

async def follow(session, url, record, counts, k):
    async with session.get(url) as resp:
        async for line in resp.content:
            if line.startswith(b"data: "):
                frame = json.loads(line[6:])
                counts[k] += 1
                if record is not None:
                    record.append((frame["seq"], time.monotonic(), frame.get("dropped", 0)))

async def main():
    base, device, pages, streams = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    record, counts = [], [0] * (pages + streams)
    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=None)) as session:
        live = base + "/api/live"
        tasks = [asyncio.create_task(follow(session, live, None, counts, k)) for k in range(pages)]
        tasks += [asyncio.create_task(follow(session, f"{base}/api/devices/{device}/stream",
                                             record if k == 0 else None, counts, pages + k))
                  for k in range(streams)]
        print("ready", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    print(json.dumps({"record": record, "counts": counts}), flush=True)

asyncio.run(main())
"""


async def _clients(base: str, device: str, core: int | None) -> asyncio.subprocess.Process:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", _CLIENT_SCRIPT, base, device, str(PAGE_CLIENTS), str(STREAM_CLIENTS),
        stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
    )  # fmt: skip
    if core is not None:
        os.sched_setaffinity(proc.pid, {core})
    assert proc.stdout is not None
    line = await asyncio.wait_for(proc.stdout.readline(), timeout=30)
    if line.strip() != b"ready":
        raise RuntimeError(f"the client process did not start: {line!r}")
    return proc


async def _finish_clients(proc: asyncio.subprocess.Process) -> dict[str, list[object]]:
    out, _ = await asyncio.wait_for(proc.communicate(b""), timeout=30)
    return dict(json.loads(out.decode().strip().splitlines()[-1]))


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


async def bench_web() -> None:
    array = _array()
    proc, port = await _sim_process()
    all_cores = os.sched_getaffinity(0)
    cores = _split_cores(proc.pid)
    device_core = sorted(all_cores)[-1] if len(all_cores) > 1 else None
    slot = MEASURE_S / ROUNDS
    try:
        bus = bus_config_for("bench", "tcp", [_device_of(array)], host="127.0.0.1", port=port)
        poller, runner = _gateway(bus)
        worker = poller.workers[0]
        await worker.transport.connect()
        hub = FrameHub(poller.holder)
        published: dict[int, float] = {}

        def note(_: object) -> None:  # after the hub's own callback: the seq it gave this poll
            latest = hub.latest(runner.config.name)
            if latest is not None:
                published.setdefault(latest.seq, time.monotonic())

        poller.holder.subscribe(note)
        registry = make_registry(poller.holder.get, CollectorRegistry())
        server = MetricsServer(registry, "127.0.0.1", 0, install=WebPage(hub).install).start()

        async def polls_for(seconds: float) -> float:
            n = 0
            t0 = time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                if not await worker.poll_device(runner):
                    raise RuntimeError(f"poll failed: {runner.last_error}")
                n += 1
            return n / (time.perf_counter() - t0)

        alone, loaded, latencies_s = [], [], []
        dropped = 0
        counts: list[int] = [0] * (PAGE_CLIENTS + STREAM_CLIENTS)
        try:
            await polls_for(0.5)  # warm up
            for _ in range(ROUNDS):
                alone.append(await polls_for(slot))
                clients = await _clients(server.base_url, runner.config.name, device_core)
                try:
                    await polls_for(0.3)  # every client connected and following
                    loaded.append(await polls_for(slot))
                finally:
                    result = await _finish_clients(clients)
                for seq, t_recv, lost in result["record"]:  # type: ignore[misc]
                    if seq in published:
                        latencies_s.append(t_recv - published[seq])
                    dropped = max(dropped, int(lost))
                counts = [a + int(b) for a, b in zip(counts, result["counts"], strict=True)]  # type: ignore[call-overload]
        finally:
            server.stop()
            await worker.close()
    finally:
        await _end(proc)
        os.sched_setaffinity(0, all_cores)
    ms = [1000.0 * x for x in latencies_s]
    seconds = slot * ROUNDS
    print(f"web: {cores}; clients on core {device_core}; {ROUNDS} rounds of {slot:.2f} s each")
    print(f"  poll rate, no clients       {statistics.mean(alone):8.1f} polls/s")
    with_clients = f"{PAGE_CLIENTS} page + {STREAM_CLIENTS} stream"
    print(f"  poll rate, {with_clients} {statistics.mean(loaded):8.1f} polls/s  "
          f"ratio {sum(loaded) / sum(alone):.3f} (goal >= 0.95)")  # fmt: skip
    if ms:
        print(f"  frame latency poll->stream client: median {statistics.median(ms):.2f} ms, "
              f"p99 {_pct(ms, 0.99):.2f} ms, max {max(ms):.2f} ms over {len(ms)} frames "
              "(goal p99 < 50 ms)")  # fmt: skip
    page_fps = sum(counts[:PAGE_CLIENTS]) / PAGE_CLIENTS / (seconds + 0.3 * ROUNDS)
    print(f"  page client frames/s {page_fps:.1f} (cap 30); stream frames dropped for the slowest: {dropped}")


def main() -> None:
    asyncio.run(bench_web())
