"""A gateway with its page, polling a simulated array in-process, and a headless Debian
chromium driven by Playwright (nothing is downloaded: the system browser is used)."""

from __future__ import annotations

import asyncio
import contextlib
import shutil
import time
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pytest
from prometheus_client import CollectorRegistry
from test_gateway_tcp import array_device

from gateway.analysis.recorder import export_record
from gateway.config import (
    ChannelConfig,
    DeviceConfig,
    GatewayConfig,
    RegisterMap,
    bus_config_for,
    gateway_config_for,
)
from gateway.config.layout import GridLayout
from gateway.config.rois import Roi
from gateway.metrics.collector import make_registry
from gateway.metrics.server import MAX_CONNECTIONS, MetricsServer
from gateway.metrics.web_config import WebConfig
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.model.conversion import line_conversion
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import DeviceSnapshot, GatewaySnapshot
from gateway.runtime.summary import device_summary
from gateway.web import FrameHub, WebPage
from gateway.web.app import KEEPALIVE_S, WRITE_TIMEOUT_S
from gateway.web.hub import Latest
from sim_device import ArrayConfig, SimArray, serve_tcp

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
]  # fmt: skip
PITCH_MM = 2.5
COLUMNS = 4


async def until(cond: Callable[[], object], timeout_s: float, what: str, step_s: float = 0.05) -> float:
    """Wait for ``cond()`` to be truthy; fail naming ``what`` after ``timeout_s``. Returns the wait."""
    t0 = time.monotonic()
    while True:
        if cond():
            return time.monotonic() - t0
        if time.monotonic() - t0 > timeout_s:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(step_s)


async def first_poll(gw: Gateway, device: str = "arr", timeout_s: float = 10) -> Latest:
    """The hub's entry of ``device`` once a poll of it has completed (``seq`` 1 or more). The
    hub lists a device as soon as the poller starts, with a placeholder snapshot (seq 0, no
    frame) until its first poll completes, which a busy machine can take a while to do."""

    seen: list[Latest] = []

    def polled() -> bool:
        entry = gw.hub.latest(device)
        if entry is None or entry.seq == 0:
            return False
        seen.append(entry)
        return True

    await until(polled, timeout_s, f"a poll of {device}")
    assert seen[-1].snapshot.polled
    return seen[-1]


async def until_async(cond: Callable[[], object], timeout_s: float, what: str, step_s: float = 0.05) -> float:
    """``until`` for a coroutine condition."""
    t0 = time.monotonic()
    while True:
        if await cond():  # type: ignore[misc]
            return time.monotonic() - t0
        if time.monotonic() - t0 > timeout_s:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(step_s)


def indentation_array(speed: float = 3.0) -> SimArray:
    cfg = ArrayConfig(
        channels=16, columns=COLUMNS, pitch_mm=PITCH_MM, seed=1, scenario="indentation", speed=speed
    )
    return SimArray(cfg, device_id=1)


def true_cop(array: SimArray) -> tuple[float, float] | None:
    """The centre of the simulator's true forces, at the gateway's channel positions (mm)."""
    f = np.asarray(array.true_force_n(), dtype=np.float64)
    total = float(f.sum())
    if total <= 0.05:
        return None
    idx = np.arange(len(f))
    return float(np.dot(f, (idx % COLUMNS) * PITCH_MM) / total), float(
        np.dot(f, (idx // COLUMNS) * PITCH_MM) / total
    )


@dataclass
class Gateway:
    array: SimArray
    server: MetricsServer
    holder: SnapshotHolder
    hub: FrameHub
    sim_port: int
    sim: contextlib.AsyncExitStack
    page: WebPage

    async def stop_sim(self) -> None:
        await self.sim.aclose()

    async def start_sim(self) -> None:
        """Serve the array (again: on the same port once it has one)."""
        self.sim = contextlib.AsyncExitStack()
        served = await self.sim.enter_async_context(
            serve_tcp([self.array], host="127.0.0.1", port=self.sim_port)
        )
        self.sim_port = served.port


@contextlib.asynccontextmanager
async def gateway_with_page(
    web_config: WebConfig | None = None,
    speed: float = 3.0,
    scale_max_n: float = 1.0,
    *,
    max_connections: int = MAX_CONNECTIONS,
    write_timeout_s: float = WRITE_TIMEOUT_S,
    keepalive_s: float = KEEPALIVE_S,
    rois: tuple[Roi, ...] = (),
    history_s: float = 0.0,
    export_s: float = 0.0,
) -> AsyncIterator[Gateway]:
    """The simulated array served over loopback Modbus TCP, polled at 20 Hz, and the server
    with the page on an ephemeral port; the simulator can be stopped and restarted. ``rois``:
    the device's regions of interest."""
    holder = SnapshotHolder()
    registry = make_registry(holder.get, CollectorRegistry())
    hub = FrameHub(holder, history_s=history_s, export_s=export_s)
    configs: list[DeviceConfig] = []  # the page reads the device's configuration once it is made
    whole: list[GatewayConfig] = []

    def export_csv(name: str, snapshots: Sequence[DeviceSnapshot]) -> str:
        return export_record(whole[0], name, snapshots, {"source": "test export"})

    page = WebPage(hub, scale_max_n=scale_max_n, write_timeout_s=write_timeout_s, keepalive_s=keepalive_s,
                   device_configs=lambda: configs, export_csv=export_csv)  # fmt: skip
    server = MetricsServer(
        registry, "127.0.0.1", 0, web_config, page.install, max_connections=max_connections
    )
    gw = Gateway(indentation_array(speed), server, holder, hub, 0, contextlib.AsyncExitStack(), page)
    try:
        await gw.start_sim()
        device = replace(array_device(gw.array, "arr", bench=False), rois=rois)
        configs.append(device)
        bus = bus_config_for("sim", "tcp", [device], host="127.0.0.1", port=gw.sim_port,
                             poll_interval_s=0.05, timeout_s=0.3, backoff_max_s=0.3)  # fmt: skip
        whole.append(gateway_config_for([bus]))
        with server:
            async with Poller(whole[0], holder):
                yield gw
    finally:
        await gw.sim.aclose()
        server.stop()


@contextlib.asynccontextmanager
async def steady_page(
    forces: list[float], disabled: tuple[int, ...] = (), scale_max_n: float = 5.0
) -> AsyncIterator[MetricsServer]:
    """A 4 x 4 array (pitch 2.5 mm: cells of 6.25 mm^2) whose channels read ``forces`` (N)
    at its one poll, the channels ``disabled`` turned off in its configuration, served
    with the page: the map does not move, so its pixels can be checked exactly."""
    m, n = 2e-5, 1e-6
    line = line_conversion(m, n, 0.01, 50.0)
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", (k % 4) * PITCH_MM, (k // 4) * PITCH_MM, k not in disabled,
                      PAPER_EFFECTS, SensorParams(), None, line)
        for k in range(16)
    )  # fmt: skip
    device = DeviceConfig("arr", 1, "float32", 16, RegisterMap(), Divider(), channels, False,
                          GridLayout(16, 4, PITCH_MM, PITCH_MM), None)  # fmt: skip
    r = np.array([1.0 / (m * f + n) for f in forces])
    proc = DeviceProcessor(device, "sim", 0.05)
    holder = SnapshotHolder()
    page = WebPage(
        FrameHub(holder),
        scale_max_n=scale_max_n,
        device_configs=lambda: [device],
        what_is_on=lambda _name: device_summary(device),
    )
    server = MetricsServer(make_registry(holder.get, CollectorRegistry()), "127.0.0.1", 0, None, page.install)

    # one poll: the load does not change, and the page draws the newest frame it is sent
    now = time.time()
    snap, _ = proc.process(proc.initial_state(), RawSample(resistance_ohm=r, device_time_s=0.05), now, now)
    holder.publish(GatewaySnapshot.build({"arr": snap}, {}, 1))

    with server:
        yield server
