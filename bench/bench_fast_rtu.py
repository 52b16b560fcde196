"""Fast RTU: a 60-point skin read through vendor function 0x42 at 4,000,000 baud.

The simulated skin (``tactile-sim run --map skin60 --rtu B --baud 4000000 --scenario sine``,
with the simulator's line timing) runs in its own process on one end of a socat pty pair;
on the other end, taking turns on the port in ``ROUNDS`` rounds (a serial port has one user
at a time):

1. **bare loop**: a plain pyserial loop as a vendor SDK's: set the output mode (function 6),
   then write the 8-byte request (device 1, 0x42, start 0, 60 points, CRC16/Modbus), read the
   5 + 120 byte answer, check address, function, byte count and CRC, unpack the 60 values;
   frames per second. The device in mN mode for the skin60-mn line, in counts for the other.
2. **gateway, skin60-mn**: the real gateway (``Poller`` with the transport of a ``kind = "rtu"``
   bus at 4,000,000 baud with ``serial_client = "direct"``: the gateway's own RTU framing,
   ``gateway.modbus.rtu_line``; ``poll_interval_s = 0``: polls back to back), the shipped
   profile ``skin60-mn`` (force in mN passed through) with drift correction on
   (``drift = { creep_fraction = 0.05, creep_tau_s = 20.0 }`` in the device's frame table),
   every frame published to the web stream (a ``FrameHub`` attached to a loop in its own
   thread, as the HTTP server's, with one open stream queue whose frames are taken as they
   come) and to MQTT (a local ``mosquitto`` on an ephemeral loopback port, JSON, QoS 1, the
   default queue and batching), if ``mosquitto`` is installed; frames per second counted
   from the published snapshots (new, ``up`` device snapshots). Both publishers subscribe as
   ``run`` does: what they derive from a snapshot is computed by the poll loop while it
   waits, and their threads yield the CPU to it (a fast bus: ``gateway.runtime.priority``).
   For MQTT, over whole rounds (warm-up included, the publisher's flush at its stop
   included): frames polled, handed to the MQTT client, acknowledged by the broker and
   dropped, and frames per message (goal: every polled frame acknowledged, none dropped).
3. **gateway, skin60-counts**: the same with the raw-counts profile (our physical model of
   each sensor with creep, through the profile's assumed divider), against a bare loop with
   the device in counts mode.
4. **MQTT at 2,000 frames/s**: a real snapshot of the 60-point skin (``skin60-mn``, from
   line 2) published ``PACED_FPS`` times a second for ``BENCH_SECONDS`` (each a new
   snapshot object whose published ``Frame`` and JSON body the feeding thread derives first,
   as the poll loop does: about 0.4 ms of CPU a frame, so the publisher gets what a poll loop
   at that rate leaves of the core), to the
   same broker with the default batching and with ``max_batch_frames = 1`` (one message per
   frame, as before batching): frames fed, handed to the client, acknowledged and dropped
   (goal: every frame acknowledged at 2,000 frames/s). The device rate above depends on the
   machine; this tells whether publishing keeps up with a device read at 2,000 frames/s.
5. (diagnostic) the gateway's transport alone reading 0x42 back to back (no conversion, no
   publishing), with either client (``serial_client`` "direct" and "pymodbus"), to tell the
   cost of the Modbus layer from that of conversion and publishing; and line 2 with
   pymodbus' client.

Goals: the gateway at >= 1,000 frames/s of 60 points and >= 0.9 of the bare loop.

What limits the rate: a pty has no baud rate. The simulator models the wire by holding each
answer until ``(8 + 125 + 2 x 3.5) x 11 bits / 4,000,000 baud`` = 385 us after the request
arrived (about 2,600 transactions/s); beyond that every byte goes through the kernel's pty
and socat's relay, and every side spends CPU per frame: the device process (pymodbus server,
the simulated array), socat, and the reader. On a 2-core machine they share the cores, so
the rates below are CPU-bound, not wire-bound. The device process and socat (the wire) are
pinned to the last core, the reader (bare loop or gateway, and the broker it starts) to the
others: on real hardware neither the device nor the wire uses the host's CPU, and socat on
the reader's core would wait for the reader's time slice before relaying an answer, which
no UART or USB interrupt does. ``BENCH_WIRE_UNPINNED=1`` leaves socat to the scheduler.

Each line runs for ``BENCH_SECONDS`` (default 5) seconds in all.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import serial

from gateway.config import GatewayConfig
from gateway.config.mqtt import MqttConfig
from gateway.config.parser import parse_config
from gateway.modbus.backends import open_transport
from gateway.modbus.rtu_line import crc16_modbus
from gateway.modbus.vendor_fc import VendorRead
from gateway.mqtt.publisher import MqttPublisher
from gateway.runtime.poller import Poller
from gateway.runtime.priority import yield_to_poll_loop
from gateway.runtime.snapshot import DeviceSnapshot, GatewaySnapshot
from gateway.web import FrameHub

from .bench_mqtt import _start_mosquitto

MEASURE_S = float(os.environ.get("BENCH_SECONDS", "5"))
ROUNDS = 5
BAUD = 4_000_000
POINTS = 60
DEVICE_ID = 1
FC = 0x42
OUTPUT_MODE_REGISTER = 2
MODES = {"skin60-mn": 1, "skin60-counts": 0}  # the output mode each profile sets at connect
CLIENTS = ("direct", "pymodbus")  # who frames RTU on the gateway's side (serial_client)
#: BENCH_WIRE_UNPINNED=1: socat runs where the scheduler puts it (it then competes with the
#: reader for the reader's core: a pty relay is an ordinary process, a UART is not)
WIRE_UNPINNED = os.environ.get("BENCH_WIRE_UNPINNED", "") == "1"
ANSWER_BYTES = 5 + 2 * POINTS
BITS_PER_CHAR = 11
GAP_CHARS = 3.5
GOAL_FPS = 1000.0
#: the rate at which MQTT alone is fed a 60-point frame (line 4)
PACED_FPS = 2000.0
GOAL_RATIO = 0.9
WARM_UP_S = 0.5
DRIFT = "{ creep_fraction = 0.05, creep_tau_s = 20.0 }"


# ---------------------------------------------------------------------------- the bare loop
def request_frame(device_id: int = DEVICE_ID, start: int = 0, count: int = POINTS) -> bytes:
    """The RTU request of function 0x42: address, code, start, count (u16 BE), CRC (LE)."""
    body = struct.pack(">BBHH", device_id, FC, start, count)
    return body + struct.pack("<H", crc16_modbus(body))


def write_frame(register: int, value: int, device_id: int = DEVICE_ID) -> bytes:
    """The RTU request of function 6 (write one holding register)."""
    body = struct.pack(">BBHH", device_id, 6, register, value)
    return body + struct.pack("<H", crc16_modbus(body))


def bare_loop(port: str, seconds: float, output_mode: int) -> tuple[float, int]:
    """A vendor-SDK-style pyserial loop for ``seconds`` after a warm-up: (frames/s, frames).

    It first sets the device's output mode (holding register 2: 0 counts, 1 force in mN) as
    the gateway's profile does, so that both read the frame the device computes alike."""
    request = request_frame()
    unpack = struct.Struct(f">{POINTS}H").unpack_from
    with serial.Serial(port, BAUD, timeout=1.0) as ser:
        time.sleep(0.05)  # an answer of the previous user of the line still on its way
        ser.reset_input_buffer()
        mode = write_frame(OUTPUT_MODE_REGISTER, output_mode)
        ser.write(mode)
        if ser.read(len(mode)) != mode:  # function 6 answers with an echo of the request
            raise RuntimeError("bare loop: the device did not confirm the output mode")

        def one() -> tuple[int, ...]:
            ser.write(request)
            answer = ser.read(ANSWER_BYTES)
            if len(answer) != ANSWER_BYTES:
                raise RuntimeError(f"bare loop: {len(answer)} of {ANSWER_BYTES} bytes")
            if answer[0] != DEVICE_ID or answer[1] != FC or answer[2] != 2 * POINTS:
                raise RuntimeError(f"bare loop: unexpected answer {answer[:3].hex()}")
            if crc16_modbus(answer[:-2]) != answer[-2] | answer[-1] << 8:
                raise RuntimeError("bare loop: CRC mismatch")
            return unpack(answer, 3)

        t_end = time.perf_counter() + WARM_UP_S
        while time.perf_counter() < t_end:
            one()
        n, t0 = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - t0) < seconds:
            values = one()
            n += 1
        assert len(values) == POINTS
    return n / elapsed, n


# ---------------------------------------------------------------------------- the gateway
def gateway_config(port: str, profile: str, mqtt_port: int | None, client: str = "direct") -> GatewayConfig:
    """One RTU bus at 4,000,000 baud polled back to back; the skin with drift correction."""
    drift = f"drift = {DRIFT}" if profile == "skin60-mn" else ""
    text = f"""
[[bus]]
name = "skin"
kind = "rtu"
serial_port = "{port}"
serial_client = "{client}"
baudrate = {BAUD}
parity = "N"
stopbits = 1
poll_interval_s = 0
timeout_s = 1.0

[[bus.device]]
name = "palm"
device_id = {DEVICE_ID}
profile = "{profile}"

[bus.device.frame]
{drift}
"""
    config = parse_config(text)
    if mqtt_port is not None:
        mqtt = MqttConfig(
            "127.0.0.1", mqtt_port, None, None, None, f"bench-fast-rtu-{profile}", "bench", "gw",
        )  # fmt: skip
        config = dataclasses.replace(config, mqtt=mqtt)
    return config


class _StreamThread:
    """The web server's side of a ``FrameHub``: a loop in its own thread that drains the hub
    (encoding each frame once) and one stream client that takes every frame as it comes."""

    def __init__(self, hub: FrameHub, device: str) -> None:
        self.hub = hub
        self.device = device
        self.frames = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._serve, name="bench-web", daemon=True)

    def _serve(self) -> None:
        yield_to_poll_loop()  # as the web server's thread does beside a fast bus
        self._loop.run_forever()

    def __enter__(self) -> _StreamThread:
        self._thread.start()
        queue = None

        def wakeup() -> None:
            if queue is not None:
                self.frames += len(queue.take())

        def attach() -> None:
            nonlocal queue
            queue = self.hub.open_stream(self.device, wakeup)
            self.hub.attach(self._loop.call_soon_threadsafe)

        asyncio.run_coroutine_threadsafe(_call(attach), self._loop).result(timeout=5)
        self.queue = queue
        return self

    def __exit__(self, *exc: object) -> None:
        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(_call(self.hub.detach), self._loop).result(timeout=5)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)
        self._loop.close()


async def _call(fn: object) -> None:
    assert callable(fn)
    fn()


@dataclasses.dataclass
class GatewayRun:
    frames: int = 0
    seconds: float = 0.0
    stream_frames: int = 0
    stream_dropped: int = 0
    mqtt_published: int = 0
    mqtt_dropped: int = 0
    errors: int = 0
    # over whole rounds: polls the publisher was given, frames handed to the MQTT client,
    # acknowledged by the broker, and the messages that carried them
    mqtt_polled: int = 0
    mqtt_sent: int = 0
    mqtt_acknowledged: int = 0
    mqtt_messages: int = 0
    sample: DeviceSnapshot | None = None  # the last polled snapshot (for line 4)


async def gateway_round(config: GatewayConfig, seconds: float, run: GatewayRun) -> None:
    """The gateway's own poll loop for ``seconds`` after a warm-up, every frame published."""
    poller = Poller(config)
    name = config.buses[0].devices[0].name
    hub = FrameHub(poller.holder)
    publisher = MqttPublisher(config) if config.mqtt is not None else None
    counting = False
    frames = 0
    polled = 0  # every poll the publisher is given a frame of (``polled``, up or not)
    last = None
    good: DeviceSnapshot | None = None  # the last polled snapshot of the device up

    def count(snap: GatewaySnapshot) -> None:
        nonlocal frames, last, polled, good
        dev = snap.devices.get(name)
        if dev is None or dev is last:
            return
        last = dev
        polled += dev.polled
        if dev.polled and dev.up:
            good = dev
        if counting and dev.polled and dev.up:
            frames += 1

    poller.holder.subscribe(count)
    if publisher is not None:
        poller.holder.subscribe(publisher.on_snapshot, derive=publisher.derivations)
        publisher.start()
    with _StreamThread(hub, name) as stream:
        try:
            await poller.start()
            await asyncio.sleep(WARM_UP_S)
            stream0 = stream.frames
            pub0 = publisher.stats().published.get(name, 0) if publisher else 0
            counting, t0 = True, time.perf_counter()
            await asyncio.sleep(seconds)
            counting, elapsed = False, time.perf_counter() - t0
            stream1 = stream.frames
            pub1 = publisher.stats().published.get(name, 0) if publisher else 0
        finally:
            await poller.stop()
            if publisher is not None:
                await asyncio.to_thread(publisher.stop)
    runner = next(iter(poller.runners()))
    run.frames += frames
    run.seconds += elapsed
    run.stream_frames += stream1 - stream0
    run.stream_dropped += hub.dropped_total.get(name, 0) + hub.inbox_dropped
    run.mqtt_published += pub1 - pub0
    if publisher is not None:
        stats = publisher.stats()
        run.mqtt_dropped += sum(stats.dropped.values())
        run.mqtt_polled += polled
        run.mqtt_sent += sum(stats.sent.values())
        run.mqtt_acknowledged += sum(stats.published.values())
        run.mqtt_messages += stats.messages
    run.errors += sum(runner.counters.read_errors_total.values())
    run.sample = good or run.sample
    if runner.last_error:
        raise RuntimeError(f"gateway: {runner.last_error}")


@dataclasses.dataclass
class PacedRun:
    fed_fps: float
    fed: int
    sent: int
    acknowledged: int
    dropped: int
    messages: int


def paced_mqtt(config: GatewayConfig, snap: DeviceSnapshot, fps: float, seconds: float) -> PacedRun:
    """Line 4: ``snap`` published ``fps`` times a second for ``seconds`` (each a new copy whose
    derivations this thread computes first, as the poll loop does before it hands a snapshot
    over), then the publisher stopped (it flushes what waits); what became of the frames."""
    publisher = MqttPublisher(config)
    publisher.start()
    try:
        deadline = time.monotonic() + 10.0
        while not publisher.stats().connected:
            if time.monotonic() > deadline:
                raise RuntimeError("the publisher did not connect")
            time.sleep(0.01)
        fed, t0 = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - t0) < seconds:
            while fed < int(elapsed * fps):
                fed += 1
                dev = dataclasses.replace(snap, timestamp_s=snap.timestamp_s + fed)
                for fn in publisher.derivations:
                    dev.derived(fn)
                publisher.on_snapshot(GatewaySnapshot.build({dev.device: dev}, {}, fed))
            time.sleep(0.0005)
    finally:
        publisher.stop()
    stats = publisher.stats()
    return PacedRun(
        fed / elapsed,
        fed,
        sum(stats.sent.values()),
        sum(stats.published.values()),
        sum(stats.dropped.values()),
        stats.messages,
    )


async def transport_only(config: GatewayConfig, seconds: float) -> tuple[float, int]:
    """Diagnostic: the gateway's ``ModbusTransport`` alone (pymodbus' client and framing,
    our checks), the 0x42 read back to back: no conversion, no publishing."""
    read = VendorRead(FC)
    async with open_transport(config.buses[0]) as transport:
        t_end = time.perf_counter() + WARM_UP_S
        while time.perf_counter() < t_end:
            await transport.read_vendor(DEVICE_ID, read, 0, POINTS)
        n, t0 = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - t0) < seconds:
            await transport.read_vendor(DEVICE_ID, read, 0, POINTS)
            n += 1
    return n / elapsed, n


# ---------------------------------------------------------------------------- processes
@contextlib.contextmanager
def _pty_pair(folder: Path) -> Iterator[tuple[str, str, int]]:
    """A socat pty pair: the two ends' paths and socat's pid."""
    socat = shutil.which("socat")
    if socat is None:
        raise RuntimeError("socat is not installed (`make sysdeps` installs it)")
    a, b = folder / "A", folder / "B"
    proc = subprocess.Popen(
        [socat, "-d", "-d", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 10.0
        while not (a.exists() and b.exists()):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("socat did not make the pty pair")
            time.sleep(0.02)
        yield str(a), str(b), proc.pid
    finally:
        _stop(proc)


@contextlib.contextmanager
def _skin_device(port: str) -> Iterator[subprocess.Popen[bytes]]:
    """``tactile-sim run --map skin60 --rtu PORT --baud 4000000`` in its own process."""
    cmd = [
        sys.executable, "-m", "sim_device.cli", "run", "--map", "skin60", "--rtu", port,
        "--baud", str(BAUD), "--scenario", "sine",
    ]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline().decode(errors="replace")
        if "serving" not in line:
            raise RuntimeError(f"the simulator did not start: {line.strip()}")
        proc.stderr.close()
        yield proc
    finally:
        _stop(proc)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def _pinned(device_pid: int, wire_pid: int) -> Iterator[str]:
    """The device and the wire (socat) on the last core, this process (and what it starts:
    the broker) on the others, restored afterwards. On real hardware neither the device nor
    the wire runs on the host's CPU; here they share a core, so that the reader's work cannot
    hold up the relay of an answer (socat is an ordinary process: on the reader's core it
    would wait for the reader's time slice, which no UART or USB interrupt does)."""
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        yield "one core: device, socat and reader share it"
        return
    os.sched_setaffinity(device_pid, {cores[-1]})
    if not WIRE_UNPINNED:
        os.sched_setaffinity(wire_pid, {cores[-1]})
    os.sched_setaffinity(0, set(cores[:-1]))
    wire = "socat unpinned" if WIRE_UNPINNED else f"socat pinned to core {cores[-1]} with the device"
    try:
        yield f"device pinned to core {cores[-1]}, {wire}, reader (and broker) to {cores[:-1]}"
    finally:
        os.sched_setaffinity(0, set(cores))


def _have_mosquitto() -> bool:
    return bool(shutil.which("mosquitto")) or Path("/usr/sbin/mosquitto").exists()


def line_limit_fps(baud: int = BAUD) -> float:
    """Transactions per second the simulator's line timing allows for one 60-point read."""
    chars = 8 + ANSWER_BYTES + 2 * GAP_CHARS
    return baud / (chars * BITS_PER_CHAR)


async def _bench() -> None:
    slot = MEASURE_S / ROUNDS
    with contextlib.ExitStack() as stack:
        folder = Path(stack.enter_context(tempfile.TemporaryDirectory()))
        a, b, wire_pid = stack.enter_context(_pty_pair(folder))
        device = stack.enter_context(_skin_device(b))
        cores = stack.enter_context(_pinned(device.pid, wire_pid))
        mqtt_port: int | None = None
        if _have_mosquitto():
            broker, mqtt_port = _start_mosquitto(folder)
            stack.callback(_stop, broker)
        bare_fps: dict[str, list[float]] = {p: [] for p in MODES}
        transport_fps: dict[str, list[float]] = {c: [] for c in CLIENTS}
        runs = {p: GatewayRun() for p in MODES}
        pymodbus_run = GatewayRun()
        configs = {p: gateway_config(a, p, mqtt_port) for p in MODES}
        pymodbus_config = gateway_config(a, "skin60-mn", mqtt_port, client="pymodbus")
        for _ in range(ROUNDS):
            for profile, run in runs.items():
                fps, _n = await asyncio.to_thread(bare_loop, a, slot, MODES[profile])
                bare_fps[profile].append(fps)
                await gateway_round(configs[profile], slot, run)
                if profile == "skin60-mn":  # the device is in mN mode now
                    for client in CLIENTS:
                        await asyncio.sleep(0.05)  # the cancelled poll's answer, discarded at connect
                        config = configs[profile] if client == "direct" else pymodbus_config
                        transport_fps[client].append((await transport_only(config, slot))[0])
                    await asyncio.sleep(0.05)
                    await gateway_round(pymodbus_config, slot, pymodbus_run)
        paced: list[tuple[str, PacedRun]] = []
        sample = runs["skin60-mn"].sample
        if mqtt_port is not None and sample is not None:
            for batching in ("default", "off"):
                config = configs["skin60-mn"]
                mqtt = config.mqtt
                assert mqtt is not None
                if batching == "off":
                    mqtt = dataclasses.replace(mqtt, max_batch_frames=1)
                    config = dataclasses.replace(config, mqtt=mqtt)
                what = (
                    "max_batch_frames = 1 (no batching)"
                    if batching == "off"
                    else f"max_batch_frames = {mqtt.max_batch_frames}, "
                    f"batch_interval_s = {mqtt.batch_interval_s:g} (the default)"
                )
                paced.append(
                    (what, await asyncio.to_thread(paced_mqtt, config, sample, PACED_FPS, MEASURE_S))
                )
    mqtt_note = "MQTT (local mosquitto, JSON, QoS 1)" if mqtt_port else "NO MQTT (mosquitto not installed)"
    _print_rounds(cores, bare_fps, transport_fps, runs, pymodbus_run, mqtt_note, mqtt_port)
    for what, p in paced:
        every = "met" if p.acknowledged == p.fed and not p.dropped else "NOT met"
        print(
            f"  MQTT at {PACED_FPS:,.0f} frames/s: a {POINTS}-point frame, each derived as the poll loop "
            f"does, fed for {MEASURE_S:g} s "
            f"(JSON, QoS 1, {what}):"
        )
        print(
            f"    fed {p.fed_fps:7.1f} frames/s: {p.fed} fed, {p.sent} handed to the client, "
            f"{p.acknowledged} acknowledged, {p.dropped} dropped, "
            f"{p.acknowledged / max(1, p.messages):.1f} frames/message "
            f"(goal: every frame acknowledged: {every})"
        )


def _print_rounds(
    cores: str,
    bare_fps: dict[str, list[float]],
    transport_fps: dict[str, list[float]],
    runs: dict[str, GatewayRun],
    pymodbus_run: GatewayRun,
    mqtt_note: str,
    mqtt_port: int | None,
) -> None:
    print(f"RTU {BAUD:,} baud on a socat pty pair, skin60 (60 points, function 0x42), {ROUNDS} rounds")
    print(f"  {cores}; {os.cpu_count()} cores")
    print(
        f"  the simulator's line timing allows {line_limit_fps():,.0f} frames/s; a pty has no baud "
        "rate: beyond that the rate is CPU-bound (device, socat, reader), not wire-bound"
    )
    for profile, run in runs.items():
        bare = sum(bare_fps[profile]) / ROUNDS
        unit = "mN" if MODES[profile] else "counts"
        print(f"  bare pyserial loop, device in {unit} (request, read, CRC, unpack): {bare:8.1f} frames/s")
        if profile == "skin60-mn":
            for client in CLIENTS:
                transport = sum(transport_fps[client]) / ROUNDS
                print(
                    f"  (diagnostic) gateway transport alone, serial_client = {client!r}, 0x42 back to "
                    f"back, no conversion or publishing: {transport:8.1f} frames/s, "
                    f"{transport / bare:.3f} of bare"
                )
            fps = pymodbus_run.frames / pymodbus_run.seconds
            print(
                f"  (diagnostic) gateway {profile} as below but serial_client = 'pymodbus': "
                f"{fps:8.1f} frames/s, {fps / bare:.3f} of bare"
            )
        fps = run.frames / run.seconds
        ratio = fps / bare
        what = "force in mN + drift correction" if profile == "skin60-mn" else "counts + our model with creep"
        ok = "met" if fps >= GOAL_FPS and ratio >= GOAL_RATIO else "NOT met"
        print(f"  gateway {profile} ({what}), web stream + {mqtt_note}:")
        print(
            f"    {fps:8.1f} frames/s, ratio gateway / bare {ratio:.3f} "
            f"(goals >= {GOAL_FPS:,.0f} frames/s and >= {GOAL_RATIO}: {ok})"
        )
        stream_fps, mqtt_fps = run.stream_frames / run.seconds, run.mqtt_published / run.seconds
        print(
            f"    web stream took {stream_fps:8.1f} frames/s ({run.stream_dropped} dropped); "
            f"MQTT published {mqtt_fps:8.1f} frames/s ({run.mqtt_dropped} dropped); {run.errors} read errors"
        )
        if mqtt_port:
            every = "met" if run.mqtt_acknowledged == run.mqtt_polled and not run.mqtt_dropped else "NOT met"
            print(
                f"    MQTT over the rounds: {run.mqtt_polled} frames polled, {run.mqtt_sent} handed to the "
                f"client, {run.mqtt_acknowledged} acknowledged, {run.mqtt_dropped} dropped, "
                f"{run.mqtt_acknowledged / max(1, run.mqtt_messages):.1f} frames/message "
                f"(goal: every frame acknowledged: {every})"
            )


def main() -> None:
    import logging

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    asyncio.run(_bench())


if __name__ == "__main__":
    main()
