"""The live page and frame stream under load: frame latency, and the poll rate they cost.

A simulated 64-channel array ("sine" load) in its own process, polled back to back over
loopback Modbus TCP by the gateway's bus worker; every poll is published to the hub and the
HTTP server (aiohttp in its own thread) serves the page stream and the frame stream.

1. Frame latency: from the gateway publishing a poll to a full-rate stream client (another
   process) receiving it, median and p99 (goal p99 < 50 ms on loopback); the same monotonic
   clock on both sides.
2. Poll rate with 5 page clients (``/api/live``, <= 30 frames/s each) and 2 full-rate stream
   clients (``/api/devices/NAME/stream``) connected, as a ratio to no clients; the two take
   turns in ``ROUNDS`` short rounds in the same run (goal >= 0.95). The clients run in one
   other process for the whole run, standing for browsers and programs on other machines:
   pinned with the device to the device's core where there are two or more, at the lowest
   priority, and only the timed stream client decodes its frames (see ``_Clients``). The
   server is started as ``run`` starts it for a bus polled back to back: its thread lowered
   (``runtime.priority``). Besides the ratio of the summed rates, the quartiles of the
   rounds' own ratios show how much the machine itself moved.

Each phase runs for ``BENCH_SECONDS`` seconds in all, 20 s at least (see ``ROUNDS``).
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
from gateway.runtime.priority import polls_fast
from gateway.web import FrameHub, WebPage

from .bench_gateway import MEASURE_S, _array, _device_of, _end, _gateway, _sim_process, _split_cores

#: each phase's share of a round (s): the phases alternate every half second, so that the
#: machine's own changes of pace (a second or more on a shared host) hit both alike
SLOT_S = 0.5
#: at least 40 rounds (20 s a phase) whatever ``BENCH_SECONDS``: a round's own ratio moves by
#: tens of per cent with the machine, so fewer rounds leave the summed ratio a few per cent off
ROUNDS = max(40, round(MEASURE_S / SLOT_S))
#: the longest line the client process may report (a round's frames: about 40 bytes each)
REPORT_LIMIT_BYTES = 1 << 26
#: after the clients connect, polls before the loaded phase is measured (s)
SETTLE_S = 0.1
PAGE_CLIENTS = 5
STREAM_CLIENTS = 2

_CLIENT_SCRIPT = r"""
import asyncio, json, sys, time
import aiohttp

async def follow(session, url, record, counts, k, connected):
    async with session.get(url) as resp:
        connected.set_result(None) if not connected.done() else None
        async for line in resp.content:
            if line.startswith(b"data: "):
                counts[k] += 1
                if record is not None:  # only the timed client decodes: the others count
                    frame = json.loads(line[6:])
                    record.append((frame["seq"], time.monotonic(), frame.get("dropped", 0)))

async def main():
    base, device, pages, streams = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    loop = asyncio.get_running_loop()
    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=None)) as session:
        print("started", flush=True)
        while (command := (await loop.run_in_executor(None, sys.stdin.readline)).strip()) == "connect":
            record, counts = [], [0] * (pages + streams)
            urls = [base + "/api/live"] * pages + [f"{base}/api/devices/{device}/stream"] * streams
            connected = [loop.create_future() for _ in urls]
            tasks = [asyncio.create_task(follow(session, url, record if k == pages else None, counts, k, c))
                     for k, (url, c) in enumerate(zip(urls, connected))]
            await asyncio.gather(*connected)
            print("ready", flush=True)
            await loop.run_in_executor(None, sys.stdin.readline)  # "disconnect"
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            print(json.dumps({"record": record, "counts": counts}), flush=True)

asyncio.run(main())
"""


class _Clients:
    """The page and stream clients, in one other process for the whole run: they connect at
    ``connect`` and all go at ``disconnect``, so the two phases can alternate many times.

    They stand for browsers and programs on other machines: pinned with the device to the
    device's core where there are two or more, and at the lowest priority, so that they take
    only what the device leaves of that core (a real device has its own CPU)."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc

    @classmethod
    async def start(cls, base: str, device: str, core: int | None) -> _Clients:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", _CLIENT_SCRIPT, base, device, str(PAGE_CLIENTS), str(STREAM_CLIENTS),
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, limit=REPORT_LIMIT_BYTES,
        )  # fmt: skip
        if core is not None:
            os.sched_setaffinity(proc.pid, {core})
        os.setpriority(os.PRIO_PROCESS, proc.pid, 19)
        self = cls(proc)
        await self._expect(b"started")
        return self

    async def _expect(self, word: bytes) -> bytes:
        assert self.proc.stdout is not None
        line = await asyncio.wait_for(self.proc.stdout.readline(), timeout=30)
        if word and line.strip() != word:
            raise RuntimeError(f"the client process said {line!r}, not {word!r}")
        return line

    async def _say(self, command: bytes) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + b"\n")
        await self.proc.stdin.drain()

    async def connect(self) -> None:
        """Every client connected (its response headers in)."""
        await self._say(b"connect")
        await self._expect(b"ready")

    async def disconnect(self) -> dict[str, list[object]]:
        """All clients gone; what they received: the first stream client's (seq, receive time,
        dropped) per frame, and each client's frame count."""
        await self._say(b"disconnect")
        return dict(json.loads(await self._expect(b"")))

    async def close(self) -> None:
        await self._say(b"quit")
        await asyncio.wait_for(self.proc.wait(), timeout=30)


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


async def bench_web() -> None:
    array = _array()
    proc, port = await _sim_process()
    all_cores = os.sched_getaffinity(0)
    cores = _split_cores(proc.pid)
    device_core = sorted(all_cores)[-1] if len(all_cores) > 1 else None
    slot = max(MEASURE_S / ROUNDS, SLOT_S)
    try:
        # polled back to back (as below): ``run`` would lower its server's priority for such
        # a bus (``runtime.priority``), and so does this bench
        bus = bus_config_for(
            "bench", "tcp", [_device_of(array)], host="127.0.0.1", port=port, poll_interval_s=0.0
        )
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
        fast = polls_fast(poller.config)
        server = MetricsServer(
            registry, "127.0.0.1", 0, install=WebPage(hub).install, yield_to_polling=fast
        ).start()

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
        clients = await _Clients.start(server.base_url, runner.config.name, device_core)
        try:
            await polls_for(0.5)  # warm up
            for _ in range(ROUNDS):
                alone.append(await polls_for(slot))
                await clients.connect()
                try:
                    await polls_for(SETTLE_S)  # every client following
                    loaded.append(await polls_for(slot))
                finally:
                    result = await clients.disconnect()
                for seq, t_recv, lost in result["record"]:  # type: ignore[misc]
                    if seq in published:
                        latencies_s.append(t_recv - published[seq])
                    dropped = max(dropped, int(lost))
                counts = [a + int(b) for a, b in zip(counts, result["counts"], strict=True)]  # type: ignore[call-overload]
        finally:
            await clients.close()
            server.stop()
            await worker.close()
    finally:
        await _end(proc)
        os.sched_setaffinity(0, all_cores)
    ms = [1000.0 * x for x in latencies_s]
    seconds = slot * ROUNDS
    print(f"web: {cores}; clients on core {device_core}; {ROUNDS} rounds of {slot:.2f} s each; "
          f"server thread {'lowered' if fast else 'not lowered'} (back-to-back bus)")  # fmt: skip
    print(f"  poll rate, no clients       {statistics.mean(alone):8.1f} polls/s")
    with_clients = f"{PAGE_CLIENTS} page + {STREAM_CLIENTS} stream"
    print(f"  poll rate, {with_clients} {statistics.mean(loaded):8.1f} polls/s  "
          f"ratio {sum(loaded) / sum(alone):.3f} (goal >= 0.95)")  # fmt: skip
    per_round = sorted(b / a for a, b in zip(alone, loaded, strict=True))
    q1, q2, q3 = statistics.quantiles(per_round, n=4) if len(per_round) > 1 else (per_round * 3)
    print(f"  per round ({len(per_round)}): quartiles {q1:.3f} {q2:.3f} {q3:.3f}, "
          f"range {per_round[0]:.2f}-{per_round[-1]:.2f} (the machine's own noise)")  # fmt: skip
    if ms:
        print(f"  frame latency poll->stream client: median {statistics.median(ms):.2f} ms, "
              f"p99 {_pct(ms, 0.99):.2f} ms, max {max(ms):.2f} ms over {len(ms)} frames "
              "(goal p99 < 50 ms)")  # fmt: skip
    page_fps = sum(counts[:PAGE_CLIENTS]) / PAGE_CLIENTS / (seconds + SETTLE_S * ROUNDS)
    print(f"  page client frames/s {page_fps:.1f} (cap 30); stream frames dropped for the slowest: {dropped}")


def main() -> None:
    asyncio.run(bench_web())
