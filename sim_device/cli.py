"""``tactile-sim``: run simulated arrays behind a Modbus server, or list the built-in scenarios.

Examples::

    tactile-sim run --tcp 127.0.0.1:5020 --scenario holds --speed 60
    tactile-sim run --rtu /dev/ttyUSB0 --baud 19200 --device-ids 1,2,3 --world-effects creep2
    tactile-sim run --rtu-tcp 127.0.0.1:5021 --scenario my_protocol.toml --record out.csv
    tactile-sim run --tls 0.0.0.0:802 --cert server.crt --key server.key
    tactile-sim run --map rawgrid --channels 36 --tcp 127.0.0.1:5022
    tactile-sim run --map skin60 --rtu /dev/ttyUSB0 --baud 4000000 --scenario cycles
    tactile-sim run --map hand --tcp 127.0.0.1:6000 --layout register --base-offset 100 --dead thumb-pad
    tactile-sim scenarios
    tactile-sim fsr-record fsr.csv --runs 3 --protocol calibration --seed 2
    tactile-sim fsr-record slow.csv --preset real-like --protocol slow-loading --runs 1

SIGINT and SIGTERM stop the server cleanly (a recording is closed as a valid file).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import signal
import sys
from collections.abc import AsyncIterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TextIO

import click

from .array import SimArray
from .config import (
    DEFAULT_BOARD_LEAKAGE_OHM,
    REGISTER_MAPS,
    WORLD_EFFECTS,
    ArrayConfig,
    ConfigError,
    parse_world_effects,
)
from .faults import FaultError
from .fsr_emulator import PRESETS, PROTOCOLS, REAL_LIKE_SAMPLE_INTERVAL_S, FsrEmulator, write_record
from .maps import VENDOR_MAPS
from .modbus_server import ServerStartError, SimServer, serve_serial, serve_tcp, serve_tls
from .record import Recorder, array_metadata
from .scenarios import Scenario, ScenarioError, builtin_scenarios

_USER_ERRORS = (ConfigError, ScenarioError, ServerStartError, FaultError, OSError, ValueError)


def _host_port(text: str, option: str) -> tuple[str, int]:
    """Parse HOST:PORT (``[v6]:PORT`` for IPv6; an empty host listens on all interfaces)."""
    host, sep, port_text = text.rpartition(":")
    if not sep:
        raise click.BadParameter(f"{text!r} is not HOST:PORT", param_hint=option)
    host = host.strip("[]") or "0.0.0.0"
    try:
        port = int(port_text)
    except ValueError:
        raise click.BadParameter(
            f"port {port_text!r} in {text!r} is not a number", param_hint=option
        ) from None
    if not 0 <= port <= 65535:
        raise click.BadParameter(f"port {port} is outside 0..65535", param_hint=option)
    return host, port


def _device_ids(text: str) -> list[int]:
    ids: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            value = int(part)
        except ValueError:
            raise click.BadParameter(f"{part!r} is not an integer", param_hint="--device-ids") from None
        if not 1 <= value <= 247:
            raise click.BadParameter(f"device id {value} is outside 1..247", param_hint="--device-ids")
        ids.append(value)
    if not ids or len(set(ids)) != len(ids):
        raise click.BadParameter(f"need distinct device ids, got {text!r}", param_hint="--device-ids")
    return ids


@dataclass(frozen=True)
class _Transport:
    kind: str  # tcp | rtu | rtu-tcp | tls
    host: str = ""
    port: int = 0
    device: str = ""


def _transport(tcp: str | None, rtu: str | None, rtu_tcp: str | None, tls: str | None) -> _Transport:
    given = [(k, v) for k, v in (("tcp", tcp), ("rtu", rtu), ("rtu-tcp", rtu_tcp), ("tls", tls)) if v]
    if len(given) > 1:
        raise click.UsageError("give only one of --tcp, --rtu, --rtu-tcp, --tls")
    if not given:
        return _Transport("tcp", "127.0.0.1", 5020)
    kind, value = given[0]
    assert value is not None
    if kind == "rtu":
        return _Transport("rtu", device=value)
    host, port = _host_port(value, f"--{kind}")
    return _Transport(kind, host, port)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="tactile-gateway", prog_name="tactile-sim")  # one distribution
def main() -> None:
    """Simulated MIS tactile sensor arrays (piezoresistive, Kalantari et al.) on Modbus."""


@main.command("scenarios")
def scenarios_cmd() -> None:
    """List the built-in scenarios with a one-line description each."""
    table = builtin_scenarios()
    width = max(len(name) for name in table)
    for name, description in table.items():
        click.echo(f"{name:<{width}}  {description}")


@main.command("fsr-record")
@click.argument("out", type=click.Path(dir_okay=False))
@click.option("--runs", type=click.IntRange(min=1), default=3, show_default=True, help="Measurement runs.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True)
@click.option("--protocol", type=click.Choice(list(PROTOCOLS)), default="holds", show_default=True)
@click.option("--wear-per-cycle", type=float, default=0.0, show_default=True, help="Loss of k per loading.")
@click.option("--rate-gain-s", type=float, default=0.0, show_default=True, help="Rate dependence, s.")
@click.option("--humidity", type=float, default=0.0, show_default=True, help="Drift amplitude, relative.")
@click.option(
    "--preset",
    type=click.Choice(list(PRESETS)),
    default="default",
    show_default=True,
    help="The emulated sensor: real-like (creep, a set that recovers slowly, 2x run-to-run "
    "sensitivity, a lagging load cell) or fast-creep (docs/fsr-emulator.md).",
)
@click.option(
    "--sample-interval-s",
    type=click.FloatRange(min=0.0, min_open=True),
    default=None,
    help=f"Sampling interval, s [default: 0.1; {REAL_LIKE_SAMPLE_INTERVAL_S:g} within bursts for the "
    "real-like and fast-creep presets].",
)
def fsr_record_cmd(
    out: str,
    runs: int,
    seed: int,
    protocol: str,
    wear_per_cycle: float,
    rate_gain_s: float,
    humidity: float,
    preset: str,
    sample_interval_s: float | None,
) -> None:
    """Write a record of an emulated FSR (sim_device.fsr_emulator), not of the paper's model."""
    if sample_interval_s is None:
        sample_interval_s = 0.1 if preset == "default" else REAL_LIKE_SAMPLE_INTERVAL_S
    try:
        params = replace(
            PRESETS[preset](), wear_per_cycle=wear_per_cycle, rate_gain_s=rate_gain_s, humidity=humidity
        )
        records = FsrEmulator(params, seed).run_many(PROTOCOLS[protocol](), runs, sample_interval_s)
        path = write_record(out, records, metadata={"preset": preset} if preset != "default" else None)
    except (ValueError, OSError) as exc:
        raise click.ClickException(str(exc)) from None
    rows = sum(r.n_samples for r in records)
    named = f", preset {preset}" if preset != "default" else ""
    click.echo(
        f"tactile-sim: wrote {path}: {runs} run(s) of protocol {protocol}, {rows} rows, seed {seed}{named}"
    )


@main.command("run")
@click.option("--tcp", metavar="HOST:PORT", help="Modbus TCP (default 127.0.0.1:5020).")
@click.option("--rtu", metavar="DEVICE", help="Modbus RTU on a serial device.")
@click.option("--rtu-tcp", metavar="HOST:PORT", help="RTU framing over TCP.")
@click.option("--tls", metavar="HOST:PORT", help="Modbus/TCP over TLS (needs --cert and --key).")
@click.option("--cert", type=click.Path(dir_okay=False), help="TLS certificate (PEM).")
@click.option("--key", type=click.Path(dir_okay=False), help="TLS private key (PEM).")
@click.option(
    "--baud", type=click.IntRange(min=1), default=115200, show_default=True, help="Serial baud rate."
)
@click.option(
    "--line-timing/--no-line-timing", default=True, show_default=True, help="Emulate RTU wire time."
)
@click.option("--turnaround-ms", type=click.FloatRange(min=0.0), default=0.0, show_default=True)
@click.option("--channels", type=click.IntRange(1, 256), default=16, show_default=True)
@click.option(
    "--columns", type=click.IntRange(1, 256), default=None, help="Grid columns [default: ceil(sqrt(N))]."
)
@click.option("--pitch-mm", type=click.FloatRange(min=0.001, max=65.535), default=2.5, show_default=True)
@click.option("--device-ids", default="1", show_default=True, help="Comma-separated ids, one array each.")
@click.option("--scenario", default="idle", show_default=True, help="Built-in name or TOML file.")
@click.option("--speed", type=float, default=1.0, show_default=True, help="Device seconds per wall second.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True)
@click.option("--world-effects", default="", help=f"Comma-separated: {', '.join(WORLD_EFFECTS)}.")
@click.option("--no-spread", is_flag=True, help="Identical channels (no part-to-part spread).")
@click.option("--noise-lsb", type=float, default=2.0, show_default=True, help="ADC noise, LSB RMS.")
@click.option(
    "--sensor-noise",
    type=float,
    default=0.0,
    show_default=True,
    help="Sensor resistance noise, relative RMS.",
)
@click.option("--sample-period", type=float, default=0.01, show_default=True, help="ADC sample period, s.")
@click.option(
    "--map",
    "register_map",
    type=click.Choice(REGISTER_MAPS + VENDOR_MAPS),
    default=REGISTER_MAPS[0],
    show_default=True,
    help="Register map: docs/register-map.md, docs/register-map-rawgrid.md or "
    "docs/register-map-skin60.md (skin60: 60 points, function 0x42; --channels, --columns, "
    "--pitch-mm do not apply); dfrobot: a DFRobot-style 6x6 board (TCP only, no physics); "
    "hand: a 1,062-taxel robot hand, docs/register-map-hand.md.",
)
@click.option(
    "--layout",
    "hand_layout",
    type=click.Choice(["byte", "register"]),
    default="byte",
    show_default=True,
    help="hand only: the public block addresses are byte addresses (register = byte/2) or registers.",
)
@click.option(
    "--base-offset", type=int, default=0, show_default=True, help="hand only: shift every taxel block."
)
@click.option("--dead", default="", help="hand only: taxels reading 0, e.g. thumb-pad,palm:17.")
@click.option("--frozen", default="", help="hand only: taxels frozen, e.g. middle-tip or index-pad:3=1200.")
@click.option(
    "--stuck", default="", help="hand only: taxels stuck at the rail (saturation code), e.g. palm:5."
)
@click.option(
    "--saturation-code",
    type=click.IntRange(0xFF00, 0xFFFF),
    default=0xFFFF,
    show_default=True,
    help="hand only: the raw value of a saturated taxel.",
)
@click.option(
    "--rest-offset-lsb",
    type=click.FloatRange(0.0, 10000.0),
    default=0.0,
    show_default=True,
    help="hand only: each taxel's own reading at rest, uniform in 0..2x this (a preloaded skin).",
)
@click.option(
    "--joint-error",
    "joint_errors",
    multiple=True,
    help="hand only: JOINT:BIT set from the start, e.g. index:stall.",
)
@click.option(
    "--log-requests",
    "log_requests",
    type=click.Path(dir_okay=False),
    help="skin60 only: write every request received to this file (tab-separated).",
)
@click.option(
    "--board-leakage-ohm",
    type=float,
    default=DEFAULT_BOARD_LEAKAGE_OHM,
    show_default=True,
    help="rawgrid only: board leakage in parallel with each sensor, ohm (inf: none).",
)
@click.option(
    "--record", "record_path", type=click.Path(dir_okay=False), help="Write a measurement record CSV."
)
@click.option("--record-period", type=float, default=0.1, show_default=True, help="Record row period, s.")
@click.option(
    "--stop-after", type=click.FloatRange(min=0.0), default=None, help="Stop after this many wall seconds."
)
def run_cmd(
    tcp: str | None,
    rtu: str | None,
    rtu_tcp: str | None,
    tls: str | None,
    cert: str | None,
    key: str | None,
    baud: int,
    line_timing: bool,
    turnaround_ms: float,
    channels: int,
    columns: int | None,
    pitch_mm: float,
    device_ids: str,
    scenario: str,
    speed: float,
    seed: int,
    world_effects: str,
    no_spread: bool,
    noise_lsb: float,
    sensor_noise: float,
    sample_period: float,
    register_map: str,
    board_leakage_ohm: float,
    log_requests: str | None,
    record_path: str | None,
    record_period: float,
    stop_after: float | None,
    hand_layout: str,
    base_offset: int,
    dead: str,
    frozen: str,
    stuck: str,
    saturation_code: int,
    joint_errors: tuple[str, ...],
    rest_offset_lsb: float,
) -> None:
    """Serve simulated arrays until SIGINT/SIGTERM (or --stop-after)."""
    transport = _transport(tcp, rtu, rtu_tcp, tls)
    if transport.kind == "tls" and not (cert and key):
        raise click.UsageError("--tls needs --cert and --key")
    if (cert or key) and transport.kind != "tls":
        raise click.UsageError("--cert/--key are only used with --tls")
    if not (math.isfinite(record_period) and record_period > 0):
        raise click.BadParameter("must be > 0", param_hint="--record-period")
    ids = _device_ids(device_ids)
    cols = columns if columns is not None else min(channels, math.ceil(math.sqrt(channels)))
    hand_options = (
        hand_layout != "byte" or base_offset or dead or frozen or stuck or joint_errors or rest_offset_lsb
    )
    if register_map != "hand" and (hand_options or saturation_code != 0xFFFF):
        raise click.UsageError(
            "--layout, --base-offset, --dead, --frozen, --stuck, --saturation-code, --rest-offset-lsb and "
            "--joint-error are only used with --map hand"
        )
    if register_map == "hand":
        if transport.kind == "tls":
            raise click.UsageError("--map hand is served over --tcp, --rtu-tcp or --rtu")
        if record_path or log_requests:
            raise click.UsageError("--record and --log-requests are not used with --map hand")
        try:
            from .hand_cli import make_hand

            hand = make_hand(
                scenario,
                hand_layout,
                base_offset,
                dead,
                frozen,
                stuck,
                saturation_code,
                joint_errors,
                seed=seed,
                speed=speed,
                noise_lsb=noise_lsb,
                device_id=ids[0],
                rest_offset_lsb=rest_offset_lsb,
                world_effects=parse_world_effects(world_effects),
                param_spread=not no_spread,
                sensor_noise_rel=sensor_noise,
            )
            asyncio.run(_serve_hand(hand, transport, baud, line_timing, turnaround_ms / 1000.0, stop_after))
        except _USER_ERRORS as exc:
            raise click.ClickException(str(exc)) from None
        return
    if register_map == "dfrobot":
        if transport.kind != "tcp":
            raise click.UsageError("--map dfrobot is served over --tcp")
        asyncio.run(_serve_dfrobot(transport, ids[0], stop_after))
        return
    skin = register_map == "skin60"
    if skin and transport.kind == "tls":
        raise click.UsageError("--map skin60 is served over --tcp, --rtu-tcp or --rtu")
    if log_requests and not skin:
        raise click.UsageError("--log-requests is only used with --map skin60")
    log_file: TextIO | None = None
    try:
        effects = parse_world_effects(world_effects)
        if skin:
            from .skin60 import Skin60Device, open_request_log, skin60_config

            base = skin60_config(
                seed=seed,
                speed=speed,
                noise_lsb_rms=noise_lsb,
                sensor_noise_rel=sensor_noise,
                world_effects=effects,
                param_spread=not no_spread,
                sample_period_s=sample_period,
            )
            loaded = Scenario.load(scenario, base.layout)
            config = base.with_changes(scenario=loaded)
            log_file = open_request_log(log_requests) if log_requests else None
            skins = [Skin60Device(SimArray(config, device_id), log_file) for device_id in ids]
            for device in skins:
                device.power_on()
            options = (
                baud,
                line_timing,
                turnaround_ms / 1000.0,
                cert,
                key,
                record_path,
                record_period,
                stop_after,
            )
            asyncio.run(_serve([d.array for d in skins], transport, *options, skins=skins))
            return
        base = ArrayConfig(
            channels=channels,
            columns=cols,
            pitch_mm=pitch_mm,
            seed=seed,
            scenario="idle",
            speed=speed,
            noise_lsb_rms=noise_lsb,
            sensor_noise_rel=sensor_noise,
            world_effects=effects,
            param_spread=not no_spread,
            sample_period_s=sample_period,
            register_map=register_map,
            board_leakage_ohm=board_leakage_ohm,
        )
        loaded = Scenario.load(scenario, base.layout)
        config = base.with_changes(scenario=loaded)
        arrays = [SimArray(config, device_id) for device_id in ids]
        turnaround_s = turnaround_ms / 1000.0
        options = (baud, line_timing, turnaround_s, cert, key, record_path, record_period, stop_after)
        serving = _serve(arrays, transport, *options)
        asyncio.run(serving)
    except _USER_ERRORS as exc:
        raise click.ClickException(str(exc)) from None
    finally:
        if log_file is not None:
            log_file.close()


async def _serve_dfrobot(t: _Transport, device_id: int, stop_after: float | None) -> None:
    """The DFRobot-style board (``dfrobot_map``) over Modbus TCP until SIGINT or SIGTERM."""
    from .dfrobot_map import DFRobotBoard, serve_dfrobot_tcp

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    async with serve_dfrobot_tcp(DFRobotBoard(), t.host, t.port, device_id) as port:
        click.echo(
            f"tactile-sim: serving a DFRobot-style 6x6 board (device id {device_id}) on tcp {t.host}:{port}; "
            "map dfrobot",
            err=True,
        )
        sys.stderr.flush()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), timeout=stop_after)
    click.echo("tactile-sim: stopped", err=True)


async def _serve_hand(
    hand: Any, t: _Transport, baud: int, line_timing: bool, turnaround_s: float, stop_after: float | None
) -> None:
    """The hand (``sim_device.hand``) until SIGINT or SIGTERM (or ``stop_after`` wall seconds)."""
    from .hand_cli import describe
    from .hand_server import serve_hand_serial, serve_hand_tcp

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    serving = (
        serve_hand_serial(hand, t.device, baud, line_timing, turnaround_s)
        if t.kind == "rtu"
        else serve_hand_tcp(hand, t.host, t.port, "rtu" if t.kind == "rtu-tcp" else "socket")
    )
    async with serving as server:
        where = t.device if t.kind == "rtu" else f"{server.host}:{server.port}"
        click.echo(f"tactile-sim: serving {describe(hand)} on {t.kind} {where}", err=True)
        sys.stderr.flush()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), timeout=stop_after)
    click.echo("tactile-sim: stopped", err=True)


@contextlib.asynccontextmanager
async def _open(
    arrays: list[SimArray],
    t: _Transport,
    baud: int,
    line_timing: bool,
    turnaround_s: float,
    cert: str | None,
    key: str | None,
    skins: list[Any] | None = None,
) -> AsyncIterator[SimServer]:
    if skins is not None:
        from .skin60 import serve_skin60_serial, serve_skin60_tcp

        if t.kind == "rtu":
            async with serve_skin60_serial(skins, t.device, baud, line_timing, turnaround_s) as server:
                yield server
        else:
            async with serve_skin60_tcp(
                skins, t.host, t.port, "rtu" if t.kind == "rtu-tcp" else "socket"
            ) as server:
                yield server
    elif t.kind == "rtu":
        async with serve_serial(arrays, t.device, baud, line_timing, turnaround_s) as server:
            yield server
    elif t.kind == "tls":
        assert cert is not None and key is not None
        async with serve_tls(arrays, t.host, t.port, certfile=cert, keyfile=key) as server:
            yield server
    else:
        async with serve_tcp(arrays, t.host, t.port, "rtu" if t.kind == "rtu-tcp" else "socket") as server:
            yield server


async def _serve(
    arrays: list[SimArray],
    t: _Transport,
    baud: int,
    line_timing: bool,
    turnaround_s: float,
    cert: str | None,
    key: str | None,
    record_path: str | None,
    record_period: float,
    stop_after: float | None,
    *,
    skins: list[Any] | None = None,
) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    handlers: list[signal.Signals] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
            handlers.append(sig)
    recorder: Recorder | None = None
    try:
        async with _open(arrays, t, baud, line_timing, turnaround_s, cert, key, skins) as server:
            if record_path:
                meta = array_metadata(arrays[0], record_period)
                meta["device_id"] = ",".join(str(a.device_id) for a in arrays)
                recorder = Recorder(Path(record_path), record_period, meta)
                for a in arrays:
                    labels = None if len(arrays) == 1 else [f"{a.device_id}.{i}" for i in range(a.n_channels)]
                    recorder.attach(a, labels)
            where = t.device if t.kind == "rtu" else f"{server.host}:{server.port}"
            ids = ",".join(str(a.device_id) for a in arrays)
            scenario = arrays[0].scenario
            register_map = "skin60" if skins is not None else arrays[0].config.register_map
            map_note = "" if register_map == REGISTER_MAPS[0] else f", map {register_map}"
            click.echo(
                f"tactile-sim: serving {len(arrays)} array(s) of {arrays[0].n_channels} channels "
                f"(device ids {ids}) on {t.kind} {where}; scenario {scenario.name}, "
                f"speed {arrays[0].config.speed:g}{map_note}",
                err=True,
            )
            sys.stderr.flush()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), timeout=stop_after)
    finally:
        if recorder is not None:
            recorder.close()
        for sig in handlers:
            loop.remove_signal_handler(sig)
    click.echo("tactile-sim: stopped", err=True)


if __name__ == "__main__":
    main()
