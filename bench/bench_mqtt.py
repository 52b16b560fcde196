"""MQTT publishing: frames per second the publisher sustains, and what it costs polling.

Against a local ``mosquitto`` (Debian's, started here on an ephemeral loopback port, no
persistence), with a simulated 64-channel array in its own process (as ``bench_gateway``):

1. The publisher alone: snapshots of the 64-channel device, one new snapshot object per
   frame, fed as fast as the publisher takes them (at most 2,000 waiting), for JSON and
   binary at QoS 1 (acknowledged) and QoS 0, with the default batching (``max_batch_frames``,
   ``batch_interval_s``) and, for JSON at QoS 1, without (``max_batch_frames = 1``); frames
   per second published and frames per message, and the payload size. This includes building
   the frame (the static force estimate of every channel) and encoding it, which run in the
   publisher's thread.
2. The gateway's back-to-back poll rate with MQTT on (every poll published, JSON, QoS 1) as
   a ratio to MQTT off, in alternating rounds of the same run (goal >= 0.9), for the default
   batching and for each of ``BATCHINGS``; with the frames polled while publishing, handed to
   the client, acknowledged by the broker and dropped (goal: all acknowledged, none dropped).
   On a machine shared with other work the ratio varies from round to round with the others'
   load; the CPU time per poll (the gateway's process, all its threads, and the broker's,
   with MQTT off and on) does much less, and says what publishing costs a poll.

First, the CPU time of what MQTT derives from each poll (the frame with its static force
estimate, and the JSON body), process time per 64-channel poll over fresh copies of 200
polled snapshots: the part of publishing's cost that runs on the poll loop.

Each measurement runs for ``BENCH_SECONDS`` (default 5) seconds.
"""

from __future__ import annotations

import asyncio
import dataclasses
import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from bench.bench_gateway import CHANNELS, _array, _device_of, _end, _sim_process, _split_cores
from gateway.config import GatewayConfig, bus_config_for, gateway_config_for
from gateway.config.mqtt import MqttConfig
from gateway.mqtt.payload import encode_binary, encode_json, frame_dict, json_body
from gateway.mqtt.publisher import MqttPublisher
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import DeviceSnapshot, GatewaySnapshot

MEASURE_S = float(os.environ.get("BENCH_SECONDS", "5"))
ROUNDS = 5
MAX_WAITING = 2000
#: polls whose snapshots the derivation's CPU time is measured on
DERIVED_POLLS = 200
#: (max_batch_frames, batch_interval_s) compared in part 2 besides the default
BATCHINGS = ((1, 0.0), (50, 0.005), (50, 0.02))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start_mosquitto(folder: Path) -> tuple[subprocess.Popen[bytes], int]:
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    port = _free_port()
    lines = [f"listener {port} 127.0.0.1", "allow_anonymous true", "max_queued_messages 100000"]
    if os.geteuid() == 0:
        lines.append("user root")
    conf = folder / "mosquitto.conf"
    conf.write_text("\n".join(lines) + "\n")
    proc = subprocess.Popen([exe, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return proc, port
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    proc.kill()
    raise RuntimeError("mosquitto did not start (apt-get install mosquitto)")


def _with_mqtt(
    config: GatewayConfig, port: int, encoding: str, qos: int, batching: tuple[int, float] | None = None
) -> GatewayConfig:
    """``batching``: (max_batch_frames, batch_interval_s), None for the defaults."""
    mqtt = MqttConfig(
        "127.0.0.1", port, None, None, None, f"bench-{encoding}-{qos}", "bench", "gw",
        qos=qos, encoding=encoding, protocol="5", queue_frames=1_000_000,
    )  # fmt: skip
    if batching is not None:
        mqtt = dataclasses.replace(mqtt, max_batch_frames=batching[0], batch_interval_s=batching[1])
    return dataclasses.replace(config, mqtt=mqtt)


def _batching_text(config: GatewayConfig) -> str:
    assert config.mqtt is not None
    m = config.mqtt
    if m.max_batch_frames == 1:
        return "max_batch_frames = 1 (no batching)"
    return f"max_batch_frames = {m.max_batch_frames}, batch_interval_s = {m.batch_interval_s:g}"


@dataclasses.dataclass
class PollRun:
    off_polls_s: float
    on_polls_s: float
    polled: int  # frames handed to the publisher while it was on
    sent: int  # handed to the MQTT client
    acknowledged: int  # acknowledged by the broker (QoS 1)
    dropped: int
    messages: int  # acknowledged messages
    off_cpu_s: float  # the gateway process's CPU time per poll, MQTT off
    on_cpu_s: float  # and on
    broker_cpu_s: float  # the broker's CPU time per poll, MQTT on


def _derivation_text(polled: list[DeviceSnapshot]) -> str:
    """The CPU time the MQTT path adds to one poll, apart from publishing: the frame (its
    static force estimate and rounding) and the JSON body, derived anew from fresh copies of
    polled snapshots; process time, the least of several rounds (a busy machine only adds)."""
    per_poll_s = []
    for _ in range(5):
        copies = [dataclasses.replace(s) for s in polled]
        c0 = time.process_time()
        for copy in copies:
            json_body(copy)
        per_poll_s.append((time.process_time() - c0) / len(copies))
    per_poll_s.sort()
    return (
        f"MQTT derivation CPU per {CHANNELS}-channel poll (frame, static estimate, JSON body): "
        f"{1e6 * per_poll_s[0]:.0f} us (median of 5 rounds {1e6 * per_poll_s[2]:.0f} us)"
    )


def _cpu_s(pid: int) -> float:
    """CPU time (user + system) of process ``pid`` so far, in seconds (Linux ``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _publisher_rate(config: GatewayConfig, snap: DeviceSnapshot) -> tuple[float, float]:
    """Frames per second published (acknowledged at QoS 1) by a publisher fed without pause,
    and frames per message."""
    publisher = MqttPublisher(config)
    publisher.start()
    try:
        deadline = time.monotonic() + 10.0
        while not publisher.stats().connected:
            if time.monotonic() > deadline:
                raise RuntimeError("the publisher did not connect")
            time.sleep(0.01)
        i = 0

        def feed_until(t_end: float) -> None:
            nonlocal i
            while time.monotonic() < t_end:
                if publisher.stats().queued >= MAX_WAITING:
                    time.sleep(0.0005)
                    continue
                i += 1
                dev = dataclasses.replace(snap, timestamp_s=snap.timestamp_s + i)
                publisher.on_snapshot(GatewaySnapshot.build({snap.device: dev}, {}, i))

        feed_until(time.monotonic() + min(1.0, MEASURE_S / 5))  # warm-up
        s0, t0 = publisher.stats(), time.monotonic()
        feed_until(t0 + MEASURE_S)
        s1, t1 = publisher.stats(), time.monotonic()
        if s1.dropped.get(snap.device, 0):
            raise RuntimeError("frames were dropped")
        frames = s1.published.get(snap.device, 0) - s0.published.get(snap.device, 0)
        return frames / (t1 - t0), frames / max(1, s1.messages - s0.messages)
    finally:
        publisher.stop()


async def _poll_rates(config: GatewayConfig, broker_pid: int) -> PollRun:
    """Back-to-back polls per second without and with publishing, alternating rounds; what
    became of the frames polled while publishing."""
    poller = Poller(config)
    worker = poller.workers[0]
    runner = worker.runners[0]
    publisher = MqttPublisher(config)
    on = False
    polled = 0
    last: object = None

    def forward(snapshot: GatewaySnapshot) -> None:
        nonlocal polled, last
        if on:
            dev = snapshot.devices.get(runner.config.name)
            if dev is not None and dev is not last and dev.polled:
                last = dev
                polled += 1
            publisher.on_snapshot(snapshot)

    # as `run` subscribes it: the poll loop derives the JSON body while it waits (only while on)
    poller.holder.subscribe(forward, derive_now=lambda: publisher.derivations if on else ())
    publisher.start()
    await worker.transport.connect()
    slot = MEASURE_S / ROUNDS
    rates: dict[bool, list[float]] = {False: [], True: []}
    polls = {False: 0, True: 0}
    cpu = {False: 0.0, True: 0.0}
    broker_cpu = 0.0
    try:
        for _ in range(ROUNDS):
            for state in (False, True):
                on = state
                for _ in range(5):
                    await worker.poll_device(runner)
                n, t0 = 0, time.perf_counter()
                c0, b0 = time.process_time(), _cpu_s(broker_pid)
                while (elapsed := time.perf_counter() - t0) < slot:
                    if not await worker.poll_device(runner):
                        raise RuntimeError(f"poll failed: {runner.last_error}")
                    n += 1
                rates[state].append(n / elapsed)
                polls[state] += n
                cpu[state] += time.process_time() - c0
                if state:
                    broker_cpu += _cpu_s(broker_pid) - b0
                worker.settle_now(runner)
    finally:
        on = False
        await worker.close()
        await asyncio.to_thread(publisher.stop)
    stats = publisher.stats()
    return PollRun(
        sum(rates[False]) / ROUNDS,
        sum(rates[True]) / ROUNDS,
        polled,
        sum(stats.sent.values()),
        sum(stats.published.values()),
        sum(stats.dropped.values()),
        stats.messages,
        cpu[False] / polls[False],
        cpu[True] / polls[True],
        broker_cpu / polls[True],
    )


async def bench() -> None:
    array = _array()
    proc, port = await _sim_process()
    all_cores = os.sched_getaffinity(0)
    cores = _split_cores(proc.pid)
    with tempfile.TemporaryDirectory() as tmp:
        broker, broker_port = _start_mosquitto(Path(tmp))
        try:
            bus = bus_config_for("bench", "tcp", [_device_of(array)], host="127.0.0.1", port=port)
            base = gateway_config_for([bus])
            # one real snapshot of the 64-channel device to publish copies of
            poller = Poller(base)
            worker = poller.workers[0]
            await worker.transport.connect()
            polled: list[DeviceSnapshot] = []
            for _ in range(DERIVED_POLLS):
                await worker.poll_device(worker.runners[0])
                worker.settle_now(worker.runners[0])
                polled.append(poller.holder.get().devices["bench"])
            await worker.close()
            snap = polled[-1]
            print(f"MQTT, local mosquitto, {CHANNELS}-channel frames; {cores}")
            print(f"  {_derivation_text(polled)}")
            frame = frame_dict(snap, 1)
            sizes = {"json": len(encode_json(frame)), "binary": len(encode_binary(frame))}
            cases = [("json", 1, None), ("json", 1, (1, 0.0)), ("json", 0, None)]
            cases += [("binary", 1, None), ("binary", 0, None)]
            for encoding, qos, batching in cases:
                config = _with_mqtt(base, broker_port, encoding, qos, batching)
                rate, per_message = await asyncio.to_thread(_publisher_rate, config, snap)
                print(
                    f"  publisher, {encoding:6s} ({sizes[encoding]:5d} bytes), QoS {qos}, "
                    f"{_batching_text(config)}: {rate:8.0f} frames/s, {per_message:5.1f} frames/message"
                )
            for batching in (None, *BATCHINGS):
                config = _with_mqtt(base, broker_port, "json", 1, batching)
                run = await _poll_rates(config, broker.pid)
                default = " (the default)" if batching is None else ""
                print(f"  gateway back-to-back polls, JSON, QoS 1, {_batching_text(config)}{default}:")
                print(
                    f"    MQTT off {run.off_polls_s:7.1f} polls/s, on {run.on_polls_s:7.1f} polls/s: "
                    f"ratio on / off {run.on_polls_s / run.off_polls_s:.3f} (goal >= 0.9)"
                )
                print(
                    f"    frames polled while on {run.polled}, handed to the client {run.sent}, "
                    f"acknowledged {run.acknowledged}, dropped {run.dropped}; "
                    f"{run.acknowledged / max(1, run.messages):.1f} frames/message"
                )
                off_us, on_us, broker_us = (1e6 * run.off_cpu_s, 1e6 * run.on_cpu_s, 1e6 * run.broker_cpu_s)
                print(
                    f"    CPU per poll: gateway {off_us:5.0f} us off, {on_us:5.0f} us on "
                    f"(+{on_us - off_us:4.0f} us), broker {broker_us:4.0f} us on"
                )
        finally:
            broker.terminate()
            broker.wait(timeout=10)
            os.sched_setaffinity(0, all_cores)
            await _end(proc)


def main() -> None:
    asyncio.run(bench())


if __name__ == "__main__":
    main()
