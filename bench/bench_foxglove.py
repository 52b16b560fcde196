"""Foxglove publishing at 1,062 channels (the dexhand-1062 profile: 17 regions): what a frame
costs, against the 33 ms a poll has at the hand's 30 Hz.

1. ``region_grids``: one poll's forces as the 17 float32 grids (µs per frame).
2. ``on_snapshot``: the poll loop's side, the hand-off to the bounded queue (µs per frame).
3. Publishing one frame with a client subscribed to every topic (17 ``foxglove.Grid``
   messages, the summary): building, encoding and handing them to the SDK's server, in the
   publisher's thread (µs per frame); and the frames per second the publisher thread sustains
   end to end (fed as fast as it takes them, counted as it hands them to the server), with
   the client reading them on loopback in another thread.

Each measurement runs for ``BENCH_SECONDS`` (default 5) seconds.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import threading
import time
from collections.abc import Callable

import aiohttp
import numpy as np

from gateway.config import GatewayConfig, parse_config
from gateway.config.foxglove import FoxgloveConfig
from gateway.foxglove.grids import region_grids, region_places
from gateway.foxglove.publisher import FoxglovePublisher
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot, GatewaySnapshot

MEASURE_S = float(os.environ.get("BENCH_SECONDS", "5"))
FRAME_BUDGET_S = 1.0 / 30.0  # the hand refreshes its taxels at about 30 Hz

CONFIG = """
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = 6000

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
"""


def _config() -> GatewayConfig:
    return dataclasses.replace(parse_config(CONFIG), foxglove=FoxgloveConfig(port=0, queue_frames=1000))


def _snapshot(n: int, seed: int = 1) -> DeviceSnapshot:
    rng = np.random.default_rng(seed)
    force = rng.uniform(0.0, 2.0, n)
    t = time.time()
    return DeviceSnapshot(
        device="hand",
        bus="hand",
        channel_index=np.arange(n),
        channel_names=tuple(f"c{k}" for k in range(n)),
        x_mm=np.zeros(n),
        y_mm=np.zeros(n),
        resistance_ohm=np.full(n, 1000.0),
        force_n=force,
        static_estimate=None,
        reference_force_n=np.full(n, np.nan),
        status=np.full(n, ChannelStatus.OK, dtype=np.int8),
        up=True,
        timestamp_s=t,
        last_success_timestamp_s=t,
        device_time_s=None,
        poll_interval_s=1 / 30,
        total_force_n=float(force.sum()),
        channels_in_contact=n,
    )


def _rate(call: Callable[[], object], seconds: float) -> float:
    """Seconds per call of ``call`` over about ``seconds``."""
    count, t0 = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - t0) < seconds:
        for _ in range(20):
            call()
        count += 20
    return elapsed / count


class _Reader:
    """A Foxglove client in its own thread, subscribed to every topic, counting messages."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.messages = 0
        self.subscribed = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), name="bench-fox-reader")
        self._thread.start()

    async def _run(self) -> None:
        async with (
            aiohttp.ClientSession() as session,
            session.ws_connect(
                f"ws://127.0.0.1:{self.port}", protocols=["foxglove.sdk.v1"], max_msg_size=0
            ) as ws,
        ):
            channels: list[dict[str, object]] = []
            while len(channels) < 19:  # 17 grids, the layout, the summary
                body = json.loads((await ws.receive()).data)
                if body["op"] == "advertise":
                    channels.extend(body["channels"])
            subs = [{"id": k + 1, "channelId": c["id"]} for k, c in enumerate(channels)]
            await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))
            await ws.receive()  # the layout, sent on subscribing: every subscription is in place
            self.subscribed.set()
            while not self._stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.receive(), 0.2)
                except TimeoutError:
                    continue
                if msg.type is aiohttp.WSMsgType.BINARY:
                    self.messages += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)


def main() -> None:
    config = _config()
    device = config.buses[0].devices[0]
    places = region_places(device)
    snap = _snapshot(device.n_channels)
    print(f"device: {device.n_channels} channels in {len(places)} regions")
    grids_s = _rate(lambda: region_grids(snap, device, places), MEASURE_S / 2)
    print(f"region_grids: {grids_s * 1e6:8.1f} us per frame")

    publisher = FoxglovePublisher(config).start()
    reader = _Reader(publisher.port)
    try:
        if not reader.subscribed.wait(30):
            raise RuntimeError("the bench client did not subscribe")
        served = publisher._devices["hand"]
        publish_s = _rate(lambda: served.publish(snap), MEASURE_S)
        print(
            f"publish one frame (17 grids + summary, subscribed): {publish_s * 1e6:8.1f} us per frame, "
            f"{publish_s / FRAME_BUDGET_S:.1%} of a 30 Hz frame"
        )
        snaps = [dataclasses.replace(snap) for _ in range(64)]
        k = 0

        def hand_off() -> None:
            nonlocal k
            k += 1
            publisher.on_snapshot(GatewaySnapshot.build({"hand": snaps[k % 64]}, {}, k))

        before = publisher.stats().published.get("hand", 0)
        t0 = time.perf_counter()
        deadline = t0 + MEASURE_S
        handed = 0
        hand_off_s = 0.0
        while time.perf_counter() < deadline:
            if publisher.stats().queued < 10:
                t1 = time.perf_counter()
                hand_off()
                hand_off_s += time.perf_counter() - t1
                handed += 1
            else:
                time.sleep(0.0005)
        elapsed = time.perf_counter() - t0
        published = publisher.stats().published.get("hand", 0) - before
        print(
            f"on_snapshot (the poll loop's hand-off): {hand_off_s / max(1, handed) * 1e6:8.1f} us per frame"
        )
        print(
            f"publisher thread, end to end: {published / elapsed:8.0f} frames/s "
            f"({published / elapsed * FRAME_BUDGET_S:.0f} x the hand's 30 Hz); "
            f"client received {reader.messages} messages"
        )
    finally:
        reader.stop()
        publisher.stop()


if __name__ == "__main__":
    main()
