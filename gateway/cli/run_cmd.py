"""``tactile-gateway run | poll-once | demo``: the gateway's long-running and one-shot commands.

* ``run -c FILE``: poll every bus and serve ``/metrics``. SIGHUP reloads the file (channels
  whose physics is unchanged keep their creep state; a bad file is logged and the old
  configuration stays), SIGTERM/SIGINT stop cleanly. A bad file at start exits with 2.
* ``poll-once -c FILE [--json]``: one poll of every device, printed as a table or JSON;
  exit 1 if a device could not be read.
* ``demo``: a simulated 4x4 array in this process, the gateway polling it over loopback
  Modbus TCP, metrics on 127.0.0.1:9830 and a live terminal view of the forces.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

import click
from prometheus_client import CollectorRegistry

from ..config import (
    DeviceConfig,
    GatewayConfig,
    MetricsConfig,
    bus_config_for,
    device_config_for,
    gateway_config_for,
    load_config,
)
from ..errors import ConfigError
from ..metrics.event_loop import EventLoopCollector
from ..metrics.exposition import SnapshotRegistry
from ..metrics.server import MetricsServer
from ..metrics.web_config import WebConfig, load_web_config
from ..modbus.plan import MERGE_GAP, device_plan
from ..model import Divider
from ..mqtt.link import MqttLink
from ..runtime.frame import frame_of
from ..runtime.poller import Poller, SnapshotHolder
from ..runtime.priority import polls_fast
from ..runtime.snapshot import VALUED_STATUSES, DeviceSnapshot, GatewaySnapshot
from ..runtime.summary import device_summary
from ..web import FrameHub, WebPage
from .common import config_option, finite_seconds
from .simulated import gateway_params

log = logging.getLogger("gateway.run")

EXIT_CONFIG = 2
EXIT_UNREACHABLE = 1


# --------------------------------------------------------------------------- helpers
def _setup_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # its errors are reported as ours


def _load(path: Path) -> tuple[GatewayConfig, WebConfig | None]:
    config = load_config(path)
    web = load_web_config(config.metrics.web_config) if config.metrics.web_config else None
    return config, web


_log_level = click.option(
    "--log-level",
    type=click.Choice(["debug", "info", "warning", "error"]),
    default="info",
    show_default=True,
    help="log messages from this level up (to stderr)",
)


# --------------------------------------------------------------------------- run
def _export(config: GatewayConfig, name: str, snapshots: Sequence[DeviceSnapshot]) -> str:
    """The page's export of ``name``'s ``snapshots``: a record, as ``record`` writes it."""
    from ..analysis.recorder import export_record  # the page's export only: not at start-up

    meta = {"source": f"tactile-gateway export of {name}"}
    if config.source is not None:
        meta["config"] = os.path.abspath(config.source)  # view finds it (# config:)
    return export_record(config, name, snapshots, meta)


def _page(
    holder: SnapshotHolder,
    config: GatewayConfig,
    enabled: bool = True,
    running: list[GatewayConfig] | None = None,
) -> WebPage | None:
    """The live page over ``holder``, unless it is turned off (``--no-page``, or a ``page =
    false`` of the metrics section where the configuration has that key). ``running`` holds
    the configuration in force (its one item replaced on a reload): the page's devices take
    their cell area and disabled channels from it."""
    if not enabled or not config.metrics.page:
        return None
    current = running if running is not None else [config]

    def what_is_on(name: str) -> list[str]:
        try:
            return device_summary(current[0].find_device(name)[1])
        except KeyError:  # a device a reload removed
            return []

    def export_csv(name: str, snapshots: Sequence[DeviceSnapshot]) -> str:
        return _export(current[0], name, snapshots)

    return WebPage(
        FrameHub(holder, history_s=config.web.history_s, export_s=config.web.export_s),
        device_configs=lambda: [d for b in current[0].buses for d in b.devices],
        what_is_on=what_is_on,
        export_csv=export_csv,
    )


async def serve(config_path: Path, config: GatewayConfig, web: WebConfig | None, page_on: bool = True) -> int:
    """Poll and serve until SIGTERM/SIGINT; SIGHUP reloads ``config_path``."""
    from ..foxglove.link import FoxgloveLink  # the SDK takes 40 ms to import: only for `run`

    holder = SnapshotHolder()
    registry = SnapshotRegistry(holder.get)
    registry.register(EventLoopCollector(asyncio.get_running_loop()))
    running = [config]
    page = _page(holder, config, page_on, running)
    install = page.install if page is not None else None
    try:
        fast = polls_fast(config)
        server = MetricsServer(
            registry, config.metrics.host, config.metrics.port, web, install, yield_to_polling=fast
        ).start()
    except OSError as exc:
        log.error("cannot serve metrics on %s:%s: %s", config.metrics.host, config.metrics.port, exc)
        return EXIT_CONFIG
    poller = Poller(config, holder)
    mqtt = MqttLink(registry)
    mqtt.apply(config)
    holder.subscribe(mqtt.on_snapshot, derive_now=lambda: mqtt.derivations)
    foxglove = FoxgloveLink()
    try:
        foxglove.apply(config)
    except OSError as exc:
        log.error("%s", exc)
        mqtt.stop()
        server.stop()
        return EXIT_CONFIG
    holder.subscribe(foxglove.on_snapshot)
    commands: asyncio.Queue[str] = asyncio.Queue()
    loop = asyncio.get_running_loop()
    handled = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
    for sig in handled:
        loop.add_signal_handler(sig, commands.put_nowait, "reload" if sig == signal.SIGHUP else "stop")
    await poller.start()
    log.info(
        "polling %d bus(es); metrics on %s; page %s", len(config.buses), server.url, server.page_url or "off"
    )
    try:
        while (command := await commands.get()) != "stop":
            try:
                new_config, new_web = _load(config_path)
            except (ConfigError, OSError) as exc:
                log.error("reload failed, keeping the running configuration: %s", exc)
                continue
            report = await poller.reload(new_config)
            mqtt.apply(new_config)
            try:
                foxglove.apply(new_config)
            except OSError as exc:
                log.error("%s; Foxglove is off until the next reload", exc)
            log.info(
                "reloaded %s (%s): %d channels keep their creep state, %d reset",
                config_path,
                command,
                report.channels_kept,
                report.channels_reset,
            )
            if new_config.metrics != config.metrics or new_web != web:
                server = _restart_server(server, registry, new_config.metrics, new_web, install)
            config, web = new_config, new_web
            running[0] = config
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)
        await poller.stop()
        mqtt.stop()
        foxglove.stop()
        server.stop()
        log.info("stopped")
    return 0


def _restart_server(
    old: MetricsServer,
    registry: CollectorRegistry,
    metrics: MetricsConfig,
    web: WebConfig | None,
    install: Callable[[Any], None] | None = None,
) -> MetricsServer:
    old.stop()
    try:
        return MetricsServer(registry, metrics.host, metrics.port, web, install).start()
    except OSError as exc:
        log.error(
            "cannot serve metrics on %s:%s (%s); keeping the old endpoint", metrics.host, metrics.port, exc
        )
        return MetricsServer(registry, old.host, old.port, old.web_config, install).start()


@click.command("run")
@config_option
@click.option("--no-page", is_flag=True, help="serve /metrics only, without the live page and its API")
@_log_level
def run(config_path: Path, no_page: bool, log_level: str) -> None:
    """Poll the configured buses and serve Prometheus metrics until stopped.

    SIGHUP reloads the configuration file; SIGTERM or SIGINT stop cleanly.
    """
    _setup_logging(log_level)
    try:
        config, web = _load(config_path)
    except (ConfigError, OSError) as exc:
        click.echo(f"tactile-gateway: {exc}", err=True)
        sys.exit(EXIT_CONFIG)
    sys.exit(asyncio.run(serve(config_path, config, web, not no_page)))


# --------------------------------------------------------------------------- poll-once
def snapshot_json(snap: GatewaySnapshot) -> dict[str, Any]:
    """A JSON-ready view of a snapshot: each device's published ``Frame`` (``runtime.frame``:
    its rounding and its None for an absent value, never NaN), with the bus and each
    channel's index, position and reference force in N (a bench's load cell; None without one)."""
    devices = []
    for name in sorted(snap.devices):
        dev = snap.devices[name]
        frame = frame_of(dev)
        cop = frame.center_of_pressure_mm
        devices.append(
            {
                "device": name,
                "bus": dev.bus,
                "up": frame.up,
                "error": frame.error,
                "total_force_n": frame.total_force_n,
                "center_of_pressure_mm": None if cop is None else list(cop),
                "channels_in_contact": frame.channels_in_contact,
                "contact_area_mm2": frame.contact_area_mm2,
                "peak_channel": frame.peak_channel,
                "channels": [
                    {
                        "index": c.index,
                        "name": c.name,
                        "x_mm": c.x_mm,
                        "y_mm": c.y_mm,
                        "status": status.label,
                        "resistance_ohm": resistance_ohm,
                        "force_n": force_n,
                        "force_static_n": force_static_n,
                        "reference_force_n": c.reference_force_n,
                    }
                    for c, status, resistance_ohm, force_n, force_static_n in zip(
                        dev.channels(),
                        frame.status,
                        frame.resistance_ohm,
                        frame.force_n,
                        frame.force_static_n,
                        strict=True,
                    )
                ],
            }
        )
    return {"devices": devices}


def _fmt(x: float | None, width: int, decimals: int) -> str:
    """``x`` right-aligned in ``width`` characters; "-" (aligned the same) when absent."""
    return f"{'-':>{width}}" if x is None else f"{x:{width}.{decimals}f}"


def snapshot_table(snap: GatewaySnapshot) -> str:
    lines = []
    for name in sorted(snap.devices):
        dev = snap.devices[name]
        state = "up" if dev.up else f"DOWN ({dev.error})"
        lines.append(f"device {name} on bus {dev.bus}: {state}")
        lines.append(
            f"  {'channel':<10} {'status':<12} {'resistance_ohm':>15} {'force_n':>9} {'static_n':>9}"
        )
        for c in dev.channels():
            lines.append(
                f"  {c.name:<10} {c.status.label:<12} {_fmt(c.resistance_ohm, 15, 1)} "
                f"{_fmt(c.force_n, 9, 3)} {_fmt(c.force_static_n, 9, 3)}"
            )
        cop = dev.center_of_pressure_mm
        where = "-" if cop is None else f"({cop[0]:.2f}, {cop[1]:.2f}) mm"
        lines.append(
            f"  total {dev.total_force_n:.3f} N, centre of pressure {where}, "
            f"{dev.channels_in_contact} in contact ({dev.contact_area_mm2:.2f} mm^2)"
        )
    return "\n".join(lines)


def dead_taxel_lines(device: DeviceConfig, dev: DeviceSnapshot, watch_s: float) -> list[str]:
    """The dead taxels of a device by region (``runtime.dead_taxels``), or why none can be
    known yet; nothing for a device that tracks none."""
    if not device.dead_after_s > 0.0:
        return []
    after = device.dead_after_s
    if dev.dead is None or watch_s < after:
        return [
            f"dead taxels of {device.name}: a taxel is dead after {after:g} s frozen; "
            f"watch with --for {2 * after:g} or more"
        ]
    names = [name for name, dead in zip(dev.channel_names, dev.dead.tolist(), strict=True) if dead]
    lines = [f"dead taxels of {device.name} (frozen for {after:g} s while their region moved): {len(names)}"]
    for region in device.regions or ():
        inside = [n for n in names if n.startswith(f"{region.name}-")]
        lines.append(f"  {region.name}: {', '.join(inside) if inside else 'none'}")
    if not device.regions:
        lines.append(f"  {', '.join(names) if names else 'none'}")
    return lines


async def _poll_for(config: GatewayConfig, watch_s: float) -> GatewaySnapshot:
    """Poll every device once, then again at the fastest bus's poll interval until
    ``watch_s`` seconds have passed; the last snapshot."""
    poller = Poller(config)
    start = time.monotonic()
    snap = await poller.poll_once()
    interval = min(bus.poll_interval_s for bus in config.buses)
    while time.monotonic() - start < watch_s:
        await asyncio.sleep(interval)
        snap = await poller.poll_once()
    return snap


@click.command("poll-once")
@config_option
@click.option("--json", "as_json", is_flag=True, help="print JSON instead of a table")
@click.option(
    "--for",
    "watch_s",
    type=click.FloatRange(0.0, 3600.0),
    default=0.0,
    show_default=True,
    help="keep polling this many seconds and show the last poll (finds dead taxels)",
)
@_log_level
def poll_once(config_path: Path, as_json: bool, watch_s: float, log_level: str) -> None:
    """Poll every device once and print resistance, force and status of each channel.

    With --for S it keeps polling for S seconds and shows the last poll, with the dead
    taxels found by region. Exit status 1 if a device could not be read (its channels are
    listed as stale).
    """
    _setup_logging("error" if log_level == "info" else log_level)
    try:
        config = load_config(config_path)
    except (ConfigError, OSError) as exc:
        click.echo(f"tactile-gateway: {exc}", err=True)
        sys.exit(EXIT_CONFIG)
    snap = asyncio.run(_poll_for(config, watch_s))
    if as_json:
        click.echo(json.dumps(snapshot_json(snap), indent=2))
    else:
        click.echo(snapshot_table(snap))
        for bus, device in config.devices():
            click.echo(f"device {device.name}, what is on:")
            for line in device_summary(device):
                click.echo(f"  {line}")
            requests = len(device_plan(device, bus.max_read_registers, MERGE_GAP, clock=True))
            regions = f" of {len(device.regions)} regions" if device.regions else ""
            click.echo(f"  a frame{regions} takes {requests} request{'s' if requests != 1 else ''}")
            if device.name in snap.devices:
                for line in dead_taxel_lines(device, snap.devices[device.name], watch_s):
                    click.echo(line)
    if not all(d.up for d in snap.devices.values()):
        sys.exit(EXIT_UNREACHABLE)


# --------------------------------------------------------------------------- demo
_SHADES = (236, 238, 240, 94, 130, 166, 202, 208, 214, 220, 226)


def render_view(
    dev: DeviceSnapshot, columns: int, url: str, color: bool = True, page_url: str | None = None
) -> str:
    """A plain-text frame: the forces as a grid (N), total force, centre of pressure."""
    rows = -(-dev.n_channels // columns)
    fmax = max(1.0, max((float(f) for f in dev.force_n if math.isfinite(f)), default=0.0))
    page = f"page on {page_url} - " if page_url else ""
    out = [f"tactile-gateway demo - {page}metrics on {url} - Ctrl-C to stop", ""]
    views = dev.channels()
    for r in range(rows):
        cells = []
        for c in range(columns):
            k = r * columns + c
            if k >= len(views):
                break
            v = views[k]
            valued = v.status in VALUED_STATUSES  # extrapolated too: it carries a force
            text = f"{(v.force_n or 0.0):6.2f}" if valued else f"{v.status.label[:6]:>6}"
            if color:
                shade = _SHADES[min(len(_SHADES) - 1, int((v.force_n or 0.0) / fmax * (len(_SHADES) - 1)))]
                cells.append(f"\x1b[48;5;{shade}m\x1b[97m {text} \x1b[0m")
            else:
                cells.append(f" {text} ")
        out.append(" ".join(cells))
    out.append("")
    cop = dev.center_of_pressure_mm
    where = "no contact" if cop is None else f"x {cop[0]:5.2f} mm, y {cop[1]:5.2f} mm"
    out.append(f"total force   {dev.total_force_n:7.3f} N")
    out.append(f"centre of pr. {where}")
    out.append(f"in contact    {dev.channels_in_contact} channels, {dev.contact_area_mm2:.2f} mm^2")
    out.append(f"device        {'up' if dev.up else 'DOWN'}, clock {dev.device_time_s or 0.0:8.2f} s")
    return "\n".join(out)


async def run_demo(port: int, host: str, duration_s: float | None, out: TextIO) -> int:
    """Simulated array + gateway + metrics + live view, until SIGINT/SIGTERM or ``duration_s``."""
    from sim_device import ArrayConfig, SimArray, serve_tcp

    array_cfg = ArrayConfig(channels=16, columns=4, pitch_mm=2.5, scenario="indentation", speed=1.0)
    array = SimArray(array_cfg, device_id=1)
    divider = Divider(array_cfg.supply_v, array_cfg.reference_ohm, array_cfg.adc_bits)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    tty = out.isatty()
    try:
        async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
            device = device_config_for(
                "demo", 1, gateway_params(array.channel_params), 4, 2.5, front_end=divider
            )
            bus = bus_config_for(
                "sim", "tcp", [device], host="127.0.0.1", port=sim.port, poll_interval_s=0.05
            )
            config = gateway_config_for([bus])  # the demo serves on host:port itself (0: any port)
            holder = SnapshotHolder()
            registry = SnapshotRegistry(holder.get)
            try:
                server = MetricsServer(
                    registry,
                    host,
                    port,
                    install=WebPage(
                        FrameHub(holder, history_s=config.web.history_s, export_s=config.web.export_s),
                        device_configs=lambda: [device],
                        what_is_on=lambda _name: device_summary(device),
                        export_csv=lambda name, snapshots: _export(config, name, snapshots),
                    ).install,
                ).start()
            except OSError as exc:
                click.echo(f"tactile-gateway: cannot serve metrics on {host}:{port}: {exc}", err=True)
                return EXIT_CONFIG
            try:
                async with Poller(config, holder):
                    t_end = None if duration_s is None else time.monotonic() + duration_s
                    if tty:
                        out.write("\x1b[?25l\x1b[2J")
                    else:  # a log or a pipe: the addresses once, then a line every 5 s
                        out.write(f"page on {server.page_url or '(off)'} - metrics on {server.url}\n")
                        out.flush()
                    # the first line once the array answers (or after 5 s), then every 5 s
                    next_line = time.monotonic() + 5.0
                    first = True
                    while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
                        snap = holder.get().devices.get("demo")
                        if snap is not None and tty:
                            frame = render_view(snap, 4, server.url, color=tty, page_url=server.page_url)
                            out.write(redraw(frame))
                            out.flush()
                        elif snap is not None and (time.monotonic() >= next_line or (first and snap.up)):
                            first = False
                            next_line = time.monotonic() + 5.0
                            out.write(_summary_line(snap))
                            out.flush()
                        with contextlib.suppress(TimeoutError):
                            await asyncio.wait_for(stop.wait(), timeout=0.2)
            finally:
                server.stop()
                if tty:
                    out.write("\x1b[?25h\n")
                    out.flush()
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
    return 0


def redraw(frame: str) -> str:
    """``frame`` drawn over the previous one from the top-left corner: each line ends with
    "erase to the end of the line" (a shorter line must not leave the tail of a longer one,
    ``6.25 mm^2`` over ``156.25 mm^2`` read ``6.25 mm^22``), and the rest of the screen is
    erased below the last line."""
    return "\x1b[H" + "\x1b[K\n".join(frame.split("\n")) + "\x1b[K\x1b[J"


def _summary_line(snap: DeviceSnapshot) -> str:
    """One line of a device's state, for a demo whose output is not a terminal."""
    cop = snap.center_of_pressure_mm
    where = "-" if cop is None else f"({cop[0]:.1f}, {cop[1]:.1f}) mm"
    state = "up" if snap.up else "DOWN"
    return (
        f"{time.strftime('%H:%M:%S')} {snap.device} {state}: total {snap.total_force_n:.3f} N, "
        f"{snap.channels_in_contact} channels in contact, centre of pressure {where}\n"
    )


@click.command("demo")
@click.option("--port", default=9830, show_default=True, type=click.IntRange(0, 65535), help="metrics port")
@click.option("--host", default="127.0.0.1", show_default=True, help="metrics address")
@click.option(
    "--duration",
    "duration_s",
    type=click.FloatRange(min=0.0),
    callback=finite_seconds,
    help="stop after this many seconds",
)
@_log_level
def demo(port: int, host: str, duration_s: float | None, log_level: str) -> None:
    """Simulated 4x4 array (scenario "indentation") polled by the gateway, with a live view."""
    _setup_logging("warning" if log_level == "info" else log_level)
    sys.exit(asyncio.run(run_demo(port, host, duration_s, sys.stdout)))
