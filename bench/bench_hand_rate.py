"""The 1,062-taxel hand (profile ``dexhand-1062``) polled by ``tactile-gateway run`` with every
output on: frame rate against a bare client, and the hand's 30 Hz kept.

The gateway is ``run``'s own ``serve`` (``gateway.cli.run_cmd``) in this process, on a
configuration file with the profile read through the simulator's circuit (a transimpedance
front end: 1 V bias, 1 kohm feedback, 16-bit converter at 1 V), so every taxel's force is
drift corrected (the paper's model with creep). Every output ``run`` has is on:

* MQTT to a local ``mosquitto`` (Debian's, ephemeral loopback port, no persistence), JSON at
  the defaults, with ``tactile-gateway subscribe --out rec.mcap`` recording every frame from
  the broker (``run`` itself writes no record: a record beside a running gateway is written by a
  subscriber);
* Foxglove's WebSocket server with one protocol client subscribed to every topic (17 grids,
  the layout, the summary);
* the page's hub with one page client (``/api/live``) and one stream client
  (``/api/devices/hand/stream``, every poll);
* ``/metrics`` scraped once a second.

Each device runs in its own process, pinned to a core of its own (a device has its own CPU):
first the simulated hand (``sim_device.hand``, scenario "grasp": every region moving), then a
light device (the same registers in a plain pymodbus block, a new frame every 1/30 s, answered
by the same pymodbus server code), which shows the gateway's own limits where the simulator's
physics (some 8 ms of CPU per 30 Hz frame) and a busy machine would hide them. The broker, the
clients and the recorder run on the gateway's core(s) at nice ``CONSUMER_NICE``: they stand
for other machines, and take the CPU the gateway leaves. The CPU each thread of the gateway
and each process spends per poll is printed: where the time goes.

1. Back to back (``poll_interval_s = 0``): the gateway's polls per second (the profile's read
   plan of 9 requests of at most 125 holding registers, decoding, drift-corrected
   conversion, every output) as a ratio to a bare pymodbus client reading the same 9 blocks
   from the same device process; the two take turns in ``ROUNDS`` rounds (the gateway's bus
   task stopped while the bare client reads), so that a change in the machine's load hits
   both; the ratio is of the mean rates (goal >= 0.95).
2. At the hand's 30 Hz (``poll_interval_s = 1/30``): polls per second over
   ``3 x BENCH_SECONDS`` (goal >= 29.7), the conversion's time per poll in the poll loop
   (decode, drift-corrected forces, statuses and snapshot; then what the page and MQTT derive
   from each snapshot: p50, p99), and the poll loop's lateness: how much later than asked the
   loop wakes for a cycle, and the cycles that started late because the previous one overran.
   Then a bare client paced the same way, for what the device itself allows.

Each measurement of part 1 runs for ``BENCH_SECONDS`` (default 5) seconds in all.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import os
import signal
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar

from pymodbus.client import AsyncModbusTcpClient

import gateway.cli.run_cmd as run_cmd
import gateway.runtime.bus as bus_module
from gateway.config import load_config, parse_config
from gateway.modbus.plan import MERGE_GAP, device_plan
from gateway.runtime.conversion import Conversion
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import GatewaySnapshot

from .bench_gateway import _end, _split_cores
from .bench_mqtt import _cpu_s, _free_port, _start_mosquitto
from .hand_rate_setup import CLIENTS_SCRIPT, LIGHT_SCRIPT, SIM_SCRIPT, config_text

MEASURE_S = float(os.environ.get("BENCH_SECONDS", "5"))
ROUNDS = 5
HAND_HZ = 30.0
GOAL_RATIO = 0.95
GOAL_HZ = 29.7
TOPICS = 19  # 17 region grids, the layout, the summary
#: The consumers (broker, clients, recorder) stand for other machines: on this one they take
#: the CPU the gateway leaves, as the gateway's own publishing threads do on a fast bus
#: (``gateway.runtime.priority.BACKGROUND_NICE``).
CONSUMER_NICE = 10


class _Timing:
    """What the instrumented poll loop saw: each conversion's step times (s) with the monotonic
    time it ended, and the loop's sleeps (asked end, woke)."""

    def __init__(self) -> None:
        self.conversions: list[tuple[float, list[float]]] = []
        self.reads: list[tuple[float, float]] = []  # (when the reads ended, how long they took)
        self.sleeps: list[tuple[float, float]] = []


_TIMING = _Timing()


class _TimedConversion(Conversion):
    """``Conversion`` timing each of its steps (decode; drift-corrected forces; statuses and
    snapshot; the subscribers' derivations)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.steps_s: list[float] = []
        _TIMING.reads.append((time.monotonic(), self.duration_s))  # the reads' time, so far

    def step(self) -> bool:
        t0 = time.perf_counter()
        done = super().step()
        self.steps_s.append(time.perf_counter() - t0)
        if done:
            _TIMING.conversions.append((time.monotonic(), self.steps_s))
        return done


class _Captured(Poller):
    """``run``'s poller, kept where the bench can reach it."""

    made: ClassVar[list[Poller]] = []

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        _Captured.made.append(self)


@contextmanager
def _instrumented() -> Iterator[None]:
    """``run``'s own wiring, with its poller reachable and its conversions timed."""
    saved = run_cmd.Poller, bus_module.Conversion
    run_cmd.Poller, bus_module.Conversion = _Captured, _TimedConversion  # type: ignore[misc]
    try:
        yield
    finally:
        run_cmd.Poller, bus_module.Conversion = saved  # type: ignore[misc]
        _Captured.made.clear()


async def _timed_sleep(delay_s: float) -> None:
    asked = time.monotonic() + delay_s
    await asyncio.sleep(delay_s)
    _TIMING.sleeps.append((asked, time.monotonic()))


async def _device_process(script: str) -> tuple[asyncio.subprocess.Process, int]:
    """The device (``script`` prints its port) in its own process; its port."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", script, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE
    )
    assert proc.stdout is not None
    return proc, int(await asyncio.wait_for(proc.stdout.readline(), timeout=60))


class _Gateway:
    """``run_cmd.serve`` on a configuration file, as a task of this event loop; its consumers
    (the clients' process and the MQTT recorder) in processes of their own, on the gateway's
    cores (started after ``_split_cores``, they inherit this process's)."""

    def __init__(self, folder: Path, text: str, others: dict[str, int]) -> None:
        self.folder = folder
        self.others = dict(others)  # name -> pid of the processes beside the gateway
        self.path = folder / "gateway.toml"
        self.path.write_text(text)
        self.config = load_config(self.path)
        self.task: asyncio.Task[int] | None = None
        self.poller: Poller | None = None
        self.clients: asyncio.subprocess.Process | None = None
        self.recorder: asyncio.subprocess.Process | None = None
        self.record = folder / f"rec-{self.config.buses[0].poll_interval_s:g}.mcap"

    async def start(self, broker_port: int) -> Poller:
        self.task = asyncio.create_task(run_cmd.serve(self.path, self.config, None, True))
        try:
            deadline = time.monotonic() + 60.0
            while not _Captured.made or not _snapshot_up(_Captured.made[-1].holder.get()):
                if self.task.done() or time.monotonic() > deadline:
                    raise RuntimeError(f"the gateway did not poll the hand: {self.task}")
                await asyncio.sleep(0.05)
            self.poller = _Captured.made[-1]
            self.poller.workers[0].sleep = _timed_sleep
            metrics = self.config.metrics
            self.recorder = await asyncio.create_subprocess_exec(
                str(Path(sys.executable).parent / "tactile-gateway"), "subscribe",
                "--broker", f"127.0.0.1:{broker_port}", "--out", str(self.record), "--quiet",
                "--session-expiry", "0",
                stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            fox = self.config.foxglove
            assert fox is not None
            self.clients = await asyncio.create_subprocess_exec(
                sys.executable, "-c", CLIENTS_SCRIPT, f"http://{metrics.host}:{metrics.port}", str(fox.port),
                str(TOPICS), stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
            )  # fmt: skip
            self.others.update(recorder=self.recorder.pid, clients=self.clients.pid)
            for pid in (self.recorder.pid, self.clients.pid):
                os.setpriority(os.PRIO_PROCESS, pid, CONSUMER_NICE)
            assert self.clients.stdout is not None
            line = await asyncio.wait_for(self.clients.stdout.readline(), timeout=60)
            if line.strip() != b"ready":
                raise RuntimeError(f"the clients did not connect: {line!r}")
            return self.poller
        except BaseException:
            await self._abort()
            raise

    async def _abort(self) -> None:
        """After a failed start: end whatever was started (``run`` by cancelling it: its signal
        handlers may not be in place yet)."""
        for proc in (self.clients, self.recorder):
            if proc is not None and proc.returncode is None:
                proc.kill()
                await proc.wait()
        if self.task is not None and not self.task.done():
            self.task.cancel()
            await asyncio.gather(self.task, return_exceptions=True)

    async def stop(self) -> tuple[dict[str, int], int, str]:
        """Stop everything; what the clients received, the frames recorded, the recorder's notes."""
        counts: dict[str, int] = {}
        if self.clients is not None:
            out, _ = await asyncio.wait_for(self.clients.communicate(b""), timeout=30)
            counts = dict(json.loads(out.decode().strip().splitlines()[-1]))
        notes = ""
        if self.recorder is not None:
            self.recorder.send_signal(signal.SIGTERM)
            _, err = await asyncio.wait_for(self.recorder.communicate(), timeout=60)
            notes = err.decode(errors="replace")
        if self.task is not None:
            if not self.task.done():
                os.kill(os.getpid(), signal.SIGTERM)  # `run` stops on SIGTERM
            if await asyncio.wait_for(self.task, timeout=30) != 0:
                raise RuntimeError("the gateway did not stop cleanly")
        return counts, _recorded_messages(self.record), notes


def _snapshot_up(snap: GatewaySnapshot) -> bool:
    dev = snap.devices.get("hand")
    return dev is not None and dev.up and dev.polled


def _recorded_messages(path: Path) -> int:
    from mcap.reader import make_reader

    if not path.exists():
        return 0
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    return 0 if summary is None or summary.statistics is None else summary.statistics.message_count


def _cpu(others: dict[str, int]) -> dict[str, float]:
    """CPU seconds so far of each thread of this process (by its Python name; threads Python
    does not know, such as the Foxglove SDK's, as "native") and of the processes ``others``
    (name -> pid)."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        name = names.get(int(task.name), "native")
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    for name, pid in others.items():
        out[name] = _cpu_s(pid)
    return out


def _cpu_text(before: dict[str, float], after: dict[str, float], polls: int) -> str:
    """CPU ms per poll of each thread or process between two ``_cpu`` readings, largest first."""
    spent = {k: after[k] - before.get(k, 0.0) for k in after}
    parts = [f"{k} {1e3 * v / max(1, polls):.1f}" for k, v in sorted(spent.items(), key=lambda kv: -kv[1])]
    return ", ".join(p for p in parts if not p.endswith(" 0.0"))


def _polls(poller: Poller) -> int:
    return sum(r.counters.polls_total for r in poller.runners())


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


async def _polled(poller: Poller, polls: int) -> None:
    """Wait (60 s at most) until ``poller`` has made ``polls`` more polls."""
    target, deadline = _polls(poller) + polls, time.monotonic() + 60.0
    while _polls(poller) < target:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the gateway stopped polling: {next(iter(poller.runners())).last_error}")
        await asyncio.sleep(0.01)


def _errors(poller: Poller) -> str:
    """The gateway's read errors so far, by reason (each retried: a late answer on a busy
    machine is a timeout, and the poll goes on)."""
    runner = next(iter(poller.runners()))
    errors = {k: v for k, v in runner.counters.read_errors_total.items() if v}
    reads = runner.counters.reads_total
    return f"{sum(errors.values())} read errors in {reads} reads" + (f" {errors}" if errors else "")


async def bench_back_to_back(folder: Path, sim_port: int, broker_port: int, others: dict[str, int]) -> None:
    text = config_text(sim_port, broker_port, _free_port(), _free_port(), 0.0)
    slot = MEASURE_S / ROUNDS
    gateway = _Gateway(folder, text, others)
    gateway_rates: list[float] = []
    bare_rates: list[float] = []
    cpu_on: dict[str, float] = {}
    cpu_bare: dict[str, float] = {}
    polls_on = polls_bare = 0
    converted = len(_TIMING.conversions)
    with _instrumented():
        poller = await gateway.start(broker_port)
        try:
            plan = next(iter(poller.runners())).plan
            client = AsyncModbusTcpClient("127.0.0.1", port=sim_port, retries=0, reconnect_delay=0)
            for _ in range(ROUNDS):
                if not poller.running:
                    await poller.start()
                await _polled(poller, 5)  # connected again, every output busy
                n0, t0, c0 = _polls(poller), time.perf_counter(), _cpu(gateway.others)
                await asyncio.sleep(slot)
                n = _polls(poller) - n0
                gateway_rates.append(n / (time.perf_counter() - t0))
                _add(cpu_on, c0, _cpu(gateway.others))
                polls_on += n
                await poller.stop()
                await client.connect()
                try:
                    c0 = _cpu(gateway.others)
                    n, elapsed = await _bare_polls(client, plan, slot)
                    _add(cpu_bare, c0, _cpu(gateway.others))
                    bare_rates.append(n / elapsed)
                    polls_bare += n
                finally:
                    client.close()
            errors = _errors(poller)
        finally:
            if not poller.running:
                await poller.start()  # `run` stops its own poller
            counts, recorded, notes = await gateway.stop()
    gateway_rate, bare_rate = statistics.mean(gateway_rates), statistics.mean(bare_rates)
    requests = ", ".join(f"{r.address}+{r.count}" for r in plan)
    print(f"back to back, {len(plan)} reads/poll of holding registers ({requests})")
    print(f"  gateway (`run`, every output on, drift-corrected): {gateway_rate:8.1f} polls/s")
    print(f"  bare pymodbus client, same reads:                  {bare_rate:8.1f} polls/s")
    verdict = "ok" if gateway_rate / bare_rate >= GOAL_RATIO else "BELOW the goal"
    print(f"  ratio gateway / bare: {gateway_rate / bare_rate:.3f} (goal >= {GOAL_RATIO}: {verdict})")
    print(f"  rounds, gateway: {' '.join(f'{r:.1f}' for r in gateway_rates)}")
    print(f"  rounds, bare:    {' '.join(f'{r:.1f}' for r in bare_rates)}")
    print(f"  CPU ms per poll, gateway rounds: {_cpu_text({}, cpu_on, polls_on)}")
    print(f"  CPU ms per poll, bare rounds:    {_cpu_text({}, cpu_bare, polls_bare)}")
    steps = _step_text(_TIMING.conversions[converted:])
    print(
        f"  conversion steps (one per request while the device answers), p50: {steps}; "
        f"a bare request's round trip: {1e3 / bare_rate / len(plan):.2f} ms"
    )
    _print_outputs(counts, recorded, notes, errors)


STEP_NAMES = ("decode", "forces", "statuses+snapshot", "derivations")


def _step_text(conversions: list[tuple[float, list[float]]]) -> str:
    """The median time (ms) of each step of the conversions (``Conversion``'s steps in order)."""
    by_step: list[list[float]] = [[] for _ in STEP_NAMES]
    for _, steps in conversions:
        for k, step_s in enumerate(steps[: len(STEP_NAMES)]):
            by_step[k].append(1e3 * step_s)
    return ", ".join(
        f"{n} {statistics.median(v):.2f} ms" for n, v in zip(STEP_NAMES, by_step, strict=True) if v
    )


def _add(total: dict[str, float], before: dict[str, float], after: dict[str, float]) -> None:
    for k, v in after.items():
        total[k] = total.get(k, 0.0) + v - before.get(k, 0.0)


async def _bare_polls(client: AsyncModbusTcpClient, plan: Any, seconds: float) -> tuple[int, float]:
    """Polls of the bare client (the plan's reads, one after the other) in about ``seconds``
    after a warm-up, and the seconds they took."""

    async def poll() -> None:
        for req in plan:
            rr = await client.read_holding_registers(req.address, count=req.count, device_id=1)
            if rr.isError():
                raise RuntimeError(f"bare client: {rr}")

    for _ in range(5):
        await poll()
    n, t0 = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - t0) < seconds:
        await poll()
        n += 1
    return n, elapsed


def _print_outputs(counts: dict[str, int], recorded: int, notes: str, errors: str) -> None:
    gaps = notes.count("gap:")
    print(f"  gateway: {errors}")
    print(
        f"  outputs: Foxglove client {counts.get('foxglove', 0)} messages, page client "
        f"{counts.get('page', 0)} frames, stream client {counts.get('stream', 0)} frames, "
        f"{counts.get('scrapes', 0)} scrapes of /metrics, MQTT recorder {recorded} frames in its MCAP "
        f"({gaps} gap notices)"
    )


async def bench_30hz(folder: Path, sim_port: int, broker_port: int, others: dict[str, int]) -> float:
    """Part 2 (module doc); the gateway's polls per second."""
    interval_s = 1.0 / HAND_HZ
    seconds = 3 * MEASURE_S
    text = config_text(sim_port, broker_port, _free_port(), _free_port(), interval_s)
    gateway = _Gateway(folder, text, others)
    polled: list[float] = []
    with _instrumented():
        poller = await gateway.start(broker_port)
        try:
            last: list[object] = [None]

            def note(snap: GatewaySnapshot) -> None:
                dev = snap.devices.get("hand")
                if dev is not None and dev is not last[0] and dev.polled and dev.up:
                    last[0] = dev
                    polled.append(time.monotonic())

            poller.holder.subscribe(note)
            await asyncio.sleep(1.0)  # every output busy
            t0, c0 = time.monotonic(), _cpu(gateway.others)
            await asyncio.sleep(seconds)
            t1, c1 = time.monotonic(), _cpu(gateway.others)
            errors = _errors(poller)
        finally:
            counts, recorded, notes = await gateway.stop()
    inside = [t for t in polled if t0 <= t <= t1]
    rate = (len(inside) - 1) / (inside[-1] - inside[0])
    conversions = [steps for t, steps in _TIMING.conversions if t0 <= t <= t1]
    convert_ms = [1e3 * sum(s[:3]) for s in conversions]
    derive_ms = [1e3 * sum(s[3:]) for s in conversions]
    late_ms = [1e3 * (woke - asked) for asked, woke in _TIMING.sleeps if t0 <= woke <= t1]
    reads_ms = [1e3 * took for t, took in _TIMING.reads if t0 <= t <= t1]
    periods_ms = [1e3 * (b - a) for a, b in itertools.pairwise(inside)]
    overran = len(inside) - len(late_ms)  # cycles that began with no wait: the last one overran
    verdict = "ok" if rate >= GOAL_HZ else "BELOW the goal"
    print(f"at {HAND_HZ:g} Hz (poll_interval_s = 1/30), every output on, over {t1 - t0:.1f} s")
    print(f"  polls/s: {rate:.2f} (goal >= {GOAL_HZ}: {verdict}); {len(inside)} polls")
    print(
        f"  conversion per poll (decode, drift-corrected forces, statuses, snapshot): "
        f"p50 {statistics.median(convert_ms):.2f} ms, p99 {_pct(convert_ms, 0.99):.2f} ms"
    )
    print(
        f"  the 9 reads of a poll: p50 {statistics.median(reads_ms):.2f} ms, "
        f"p99 {_pct(reads_ms, 0.99):.2f} ms, max {max(reads_ms):.2f} ms"
    )
    print(
        f"  then what the page and MQTT derive from it (frame, JSON): "
        f"p50 {statistics.median(derive_ms):.2f} ms, p99 {_pct(derive_ms, 0.99):.2f} ms"
    )
    print(
        f"  poll loop lateness (woke after the time it asked for): p50 {statistics.median(late_ms):.2f} ms, "
        f"p99 {_pct(late_ms, 0.99):.2f} ms, max {max(late_ms):.2f} ms over {len(late_ms)} waits; "
        f"{max(0, overran)} cycles began late (the previous one overran its 33.3 ms)"
    )
    print(
        f"  time between polls: p50 {statistics.median(periods_ms):.2f} ms, "
        f"p99 {_pct(periods_ms, 0.99):.2f} ms, max {max(periods_ms):.2f} ms"
    )
    print(f"  CPU ms per poll: {_cpu_text(c0, c1, len(inside))}")
    _print_outputs(counts, recorded, notes, errors)
    return rate


async def bench_bare_30hz(sim_port: int, gateway_rate: float) -> None:
    """The device's side of part 2: a bare client reading the same 9 blocks paced at 30 Hz as
    the poll loop paces itself (the next poll 1/30 s after the last began; none made up)."""
    client = AsyncModbusTcpClient("127.0.0.1", port=sim_port, retries=0, reconnect_delay=0)
    await client.connect()
    interval_s, n = 1.0 / HAND_HZ, 0
    try:
        bus = parse_config(config_text(sim_port, 1, 2, 3, interval_s)).buses[0]
        reads = device_plan(bus.devices[0], bus.max_read_registers, MERGE_GAP, True)
        await _bare_polls(client, reads, 0.5)
        t0 = next_s = time.monotonic()
        reads_ms: list[float] = []
        while time.monotonic() - t0 < MEASURE_S:
            r0 = time.monotonic()
            for req in reads:
                rr = await client.read_holding_registers(req.address, count=req.count, device_id=1)
                if rr.isError():
                    raise RuntimeError(f"bare client: {rr}")
            reads_ms.append(1e3 * (time.monotonic() - r0))
            n += 1
            next_s = max(next_s + interval_s, time.monotonic())
            await asyncio.sleep(next_s - time.monotonic())
        elapsed = time.monotonic() - t0
    finally:
        client.close()
    print(
        f"  the device's side: a bare client paced at 30 Hz makes {n / elapsed:.2f} polls/s "
        f"(the gateway {gateway_rate:.2f}); its 9 reads: p50 {statistics.median(reads_ms):.2f} ms, "
        f"p99 {_pct(reads_ms, 0.99):.2f} ms"
    )


DEVICES = (
    ("the simulated hand (sim_device.hand, scenario grasp: every region moving)", SIM_SCRIPT),
    (
        "a light device (the same registers in a plain pymodbus block, a new frame every 1/30 s)",
        LIGHT_SCRIPT,
    ),
)


async def _main() -> None:
    print("hand: profile dexhand-1062, 1,062 taxels in 17 regions, read in ohm with drift correction")
    for what, script in DEVICES:
        sim, sim_port = await _device_process(script)
        all_cores = os.sched_getaffinity(0)
        cores = _split_cores(sim.pid)
        try:
            with tempfile.TemporaryDirectory() as tmp:
                broker, broker_port = _start_mosquitto(Path(tmp))
                os.setpriority(os.PRIO_PROCESS, broker.pid, CONSUMER_NICE)
                try:
                    print(f"device: {what}, in its own process; {cores}")
                    print(
                        f"  the broker, the clients and the MQTT recorder on the gateway's cores at nice "
                        f"{CONSUMER_NICE}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
                    )
                    others = {"device": sim.pid, "mosquitto": broker.pid}
                    await bench_back_to_back(Path(tmp), sim_port, broker_port, others)
                    rate = await bench_30hz(Path(tmp), sim_port, broker_port, others)
                    await bench_bare_30hz(sim_port, rate)
                finally:
                    broker.terminate()
                    broker.wait(timeout=10)
        finally:
            os.sched_setaffinity(0, all_cores)
            await _end(sim)


def main() -> None:
    import logging

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    asyncio.run(_main())


if __name__ == "__main__":
    main()
