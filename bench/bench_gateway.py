"""Gateway throughput: polls per second against baselines measured in the same run.

1. Modbus TCP over loopback, a simulated 64-channel array in its own process (a device has
   its own CPU) under the "sine" load (every channel loaded, the force always changing):
   the gateway's full poll (reads of the read plan, decoding, drift-corrected conversion,
   snapshot publication) back to back, as a ratio to a bare pymodbus client reading the
   same registers; the two take turns in 5 rounds (goal >= 0.8). The gateway runs each
   poll's conversion in steps while the next poll's requests are answered; the bench
   checks that every poll was converted and published.
2. The conversion alone (decode + pipeline) per poll, in microseconds.
3. Modbus RTU at 115200 baud on a socat pty pair, the simulator emulating line timing:
   polls per second as a fraction of the line's limit for that read plan. Each request
   and its answer occupy the line for (request bytes + response bytes + 2 x 3.5 gap
   characters) x 11 bits / baud; a read of n registers is an 8-byte request and a
   5 + 2n byte response.

Each measurement runs for ``BENCH_SECONDS`` (default 5) seconds.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import signal
import statistics
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

from pymodbus.client import AsyncModbusTcpClient

from gateway.cli.simulated import gateway_params
from gateway.config import BusConfig, DeviceConfig, bus_config_for, device_config_for, gateway_config_for
from gateway.modbus.image import RegisterImage, RegisterKind, decode_sample
from gateway.modbus.plan import ReadRequest
from gateway.model import Divider
from gateway.runtime.bus import DeviceRunner
from gateway.runtime.poller import Poller
from sim_device import ArrayConfig, SimArray

MEASURE_S = float(os.environ.get("BENCH_SECONDS", "5"))
ROUNDS = 5
CHANNELS = 64
COLUMNS = 8
BAUD = 115200
BITS_PER_CHAR = 11
GAP_CHARS = 3.5


def _array(channels: int = CHANNELS, columns: int = COLUMNS) -> SimArray:
    cfg = ArrayConfig(channels=channels, columns=columns, pitch_mm=2.5, seed=1, scenario="sine", speed=1.0)
    return SimArray(cfg, device_id=1)


def _device_of(array: SimArray, name: str = "bench") -> DeviceConfig:
    cfg = array.config
    return device_config_for(
        name,
        1,
        gateway_params(array.channel_params),
        cfg.columns,
        cfg.pitch_mm,
        front_end=Divider(cfg.supply_v, cfg.reference_ohm, cfg.adc_bits),
    )


async def _rate(step: Callable[[], Awaitable[object]], seconds: float) -> float:
    """Calls per second of ``step`` run back to back for ``seconds`` (after a warm-up)."""
    for _ in range(5):
        await step()
    n, t0 = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - t0) < seconds:
        await step()
        n += 1
    return n / elapsed


def _gateway(bus: BusConfig) -> tuple[Poller, DeviceRunner]:
    poller = Poller(gateway_config_for([bus]))
    worker = poller.workers[0]
    return poller, worker.runners[0]


_SIM_SCRIPT = """
import asyncio, sys
from sim_device import ArrayConfig, SimArray, serve_tcp

async def main():
    cfg = ArrayConfig(channels=int(sys.argv[1]), columns=int(sys.argv[2]), pitch_mm=2.5, seed=1,
                      scenario="sine", speed=1.0)
    async with serve_tcp([SimArray(cfg, device_id=1)], host="127.0.0.1", port=0) as sim:
        print(sim.port, flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)

asyncio.run(main())
"""


def _split_cores(device_pid: int) -> str:
    """Give the device process its own core and keep this process (gateway or bare client,
    and every thread it starts later) on the others, as with a real device's own CPU.
    Returns a note for the report."""
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        return "one core: device and gateway share it"
    os.sched_setaffinity(device_pid, {cores[-1]})
    os.sched_setaffinity(0, set(cores[:-1]))
    return f"device pinned to core {cores[-1]}, gateway and bare client to {cores[:-1]}"


async def _sim_process() -> tuple[asyncio.subprocess.Process, int]:
    """The simulated device in its own process (a device has its own CPU); its port."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", _SIM_SCRIPT, str(CHANNELS), str(COLUMNS),
        stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None
    line = await asyncio.wait_for(proc.stdout.readline(), timeout=30)
    return proc, int(line)


async def _end(proc: asyncio.subprocess.Process) -> None:
    if proc.stdin is not None:
        proc.stdin.close()
    try:
        await asyncio.wait_for(proc.wait(), timeout=10)
    except TimeoutError:
        proc.kill()
        await proc.wait()


async def bench_tcp() -> None:
    """Gateway and bare client take turns (ROUNDS rounds each), so that a change in the
    machine's load hits both; the ratio is of the summed rates."""
    array = _array()  # same seed as the device process: the same channel parameters
    proc, port = await _sim_process()
    all_cores = os.sched_getaffinity(0)
    cores = _split_cores(proc.pid)
    slot = MEASURE_S / ROUNDS
    try:
        bus = bus_config_for("bench", "tcp", [_device_of(array)], host="127.0.0.1", port=port)
        poller, runner = _gateway(bus)
        worker = poller.workers[0]
        client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0, reconnect_delay=0)
        await client.connect()
        await worker.transport.connect()
        plan = runner.plan
        polls = 0
        publish_delays_s: list[float] = []

        def published(_: object) -> None:  # runs at publication, after the state update
            if runner.state.last_host_time_s is not None:
                publish_delays_s.append(time.monotonic() - runner.state.last_host_time_s)

        poller.holder.subscribe(published)

        async def gateway_poll() -> None:
            nonlocal polls
            if not await worker.poll_device(runner):
                raise RuntimeError(f"poll failed: {runner.last_error}")
            polls += 1

        async def bare_poll() -> None:
            for req in plan:
                rr = await client.read_input_registers(req.address, count=req.count, device_id=1)
                if rr.isError():
                    raise RuntimeError(f"bare client: {rr}")

        gateway_rates, bare_rates = [], []
        try:
            for _ in range(ROUNDS):
                gateway_rates.append(await _rate(gateway_poll, slot))
                worker.settle_now(runner)
                bare_rates.append(await _rate(bare_poll, slot))
        finally:
            client.close()
            await worker.close()
        if runner.last_error or sum(runner.counters.read_errors_total.values()):
            raise RuntimeError(f"gateway errors: {runner.last_error}")
        if runner.counters.polls_total != polls:  # every poll converted and published
            raise RuntimeError(f"{polls} polls but {runner.counters.polls_total} conversions")
    finally:
        os.sched_setaffinity(0, all_cores)
        await _end(proc)
    gateway_rate, bare_rate = sum(gateway_rates) / ROUNDS, sum(bare_rates) / ROUNDS
    requests = ", ".join(f"{r.address}+{r.count}" for r in plan)
    print(
        f"TCP loopback, {CHANNELS} channels, device in its own process, {len(plan)} reads/poll ({requests})"
    )
    print(f"  {cores}")
    print(f"  gateway poll (read + convert + publish): {gateway_rate:8.1f} polls/s")
    print(f"  bare pymodbus client, same reads:        {bare_rate:8.1f} polls/s")
    print(f"  ratio gateway / bare: {gateway_rate / bare_rate:.3f} (goal >= 0.8)")
    delay_us = 1e6 * statistics.median(publish_delays_s)
    print(f"  a poll is published {delay_us:.0f} us (median) after its reads end (steps ride the next poll)")
    bench_pipeline(poller)


def bench_pipeline(poller: Poller) -> None:
    """Decode + convert one recorded poll, repeated: the processing cost per poll."""
    runner = next(iter(poller.runners()))
    dev = runner.config
    image_reads: list[tuple[RegisterKind, int, list[int]]] = []
    for req in runner.plan:
        base = 30000 if req.address <= dev.registers.adc_address <= req.end else 0
        image_reads.append(("input", req.address, [base] * req.count))
    image = RegisterImage.from_reads(image_reads)
    proc, state = runner.processor, runner.processor.initial_state()
    n, t0 = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - t0) < min(MEASURE_S, 2.0):
        raw = decode_sample(dev, image)
        _, state = proc.process(state, raw, 0.0, float(n))
        n += 1
    print(f"  conversion only (decode + model, {dev.n_channels} channels): {1e6 * elapsed / n:8.1f} us/poll")


def line_limit_polls_per_s(plan: tuple[ReadRequest, ...], baud: int) -> float:
    """The most polls per second a serial line can carry for ``plan`` (see module doc)."""
    chars = sum(8 + (5 + 2 * r.count) + 2 * GAP_CHARS for r in plan)
    return baud / (chars * BITS_PER_CHAR)


_SERIAL_SIM_SCRIPT = """
import asyncio, sys
from sim_device import ArrayConfig, SimArray, serve_serial

async def main():
    cfg = ArrayConfig(channels=int(sys.argv[1]), columns=int(sys.argv[2]), pitch_mm=2.5, seed=1,
                      scenario="sine", speed=1.0)
    async with serve_serial([SimArray(cfg, device_id=1)], port=sys.argv[3], baudrate=int(sys.argv[4]),
                            line_timing=True):
        print("ready", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)

asyncio.run(main())
"""


async def bench_rtu() -> None:
    """The device (with its line-timing emulation) in its own process on one end of a socat
    pty pair; the gateway and a bare pymodbus serial client take turns (ROUNDS rounds each)
    on the other end."""
    from pymodbus.client import AsyncModbusSerialClient

    socat = shutil.which("socat")
    if socat is None:
        print("RTU: not measured, socat is not installed (`make sysdeps` installs it)")
        return
    with tempfile.TemporaryDirectory() as tmp:
        a, b = Path(tmp) / "a", Path(tmp) / "b"
        proc = await asyncio.create_subprocess_exec(
            socat, f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}",
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL,
        )  # fmt: skip
        sim: asyncio.subprocess.Process | None = None
        try:
            for _ in range(500):
                if a.exists() and b.exists():
                    break
                await asyncio.sleep(0.02)
            sim = await asyncio.create_subprocess_exec(
                sys.executable, "-c", _SERIAL_SIM_SCRIPT, str(CHANNELS), str(COLUMNS), str(b), str(BAUD),
                stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
            )  # fmt: skip
            assert sim.stdout is not None
            await asyncio.wait_for(sim.stdout.readline(), timeout=30)
            array = _array()
            bus = bus_config_for(
                "line", "rtu", [_device_of(array)], serial_port=str(a), baudrate=BAUD, timeout_s=1.0
            )
            poller, runner = _gateway(bus)
            worker = poller.workers[0]
            plan = runner.plan

            async def gateway_poll() -> None:
                if not await worker.poll_device(runner):
                    raise RuntimeError(f"poll failed: {runner.last_error}")

            client = AsyncModbusSerialClient(str(a), baudrate=BAUD, timeout=1.0, retries=0, reconnect_delay=0)

            async def bare_poll() -> None:
                for req in plan:
                    rr = await client.read_input_registers(req.address, count=req.count, device_id=1)
                    if rr.isError():
                        raise RuntimeError(f"bare client: {rr}")

            # the two take turns on the one port (a serial port has one user at a time)
            gateway_rates, bare_rates = [], []
            slot = MEASURE_S / ROUNDS
            for _ in range(ROUNDS):
                await worker.transport.connect()
                try:
                    gateway_rates.append(await _rate(gateway_poll, slot))
                finally:
                    await worker.close()
                await client.connect()
                try:
                    bare_rates.append(await _rate(bare_poll, slot))
                finally:
                    client.close()
                    await asyncio.sleep(0)
            if runner.last_error or sum(runner.counters.read_errors_total.values()):
                raise RuntimeError(f"gateway errors: {runner.last_error}")
            rate, bare = sum(gateway_rates) / ROUNDS, sum(bare_rates) / ROUNDS
        finally:
            if sim is not None:
                await _end(sim)
            proc.send_signal(signal.SIGTERM)
            await asyncio.wait_for(proc.wait(), timeout=5)
    limit = line_limit_polls_per_s(plan, BAUD)
    requests = ", ".join(f"{r.address}+{r.count}" for r in plan)
    print(f"RTU {BAUD} baud (line timing emulated), {CHANNELS} channels, {len(plan)} reads/poll ({requests})")
    print(f"  gateway: {rate:6.2f} polls/s; bare pymodbus serial client: {bare:6.2f} polls/s")
    print(f"  line limit for this plan: {limit:6.2f} polls/s")
    print(
        f"  fraction of the line limit: gateway {rate / limit:.3f} (goal >= 0.9), "
        f"bare client {bare / limit:.3f}"
    )


async def _main() -> None:
    await bench_tcp()
    await bench_rtu()


def main() -> None:
    import logging

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    asyncio.run(_main())


if __name__ == "__main__":
    main()
