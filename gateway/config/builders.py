"""Configurations built in code (the demo, the paper replay, tests, benchmarks).

Each builder makes the table a configuration file would hold and passes it through the same
parser checks, so a configuration made in code is validated exactly as one read from TOML and
``ConfigError`` names the offending key.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

from ..modbus.register_map import MAX_READ_REGISTERS, DeviceClock, RegisterMap
from ..model import Divider, FrontEnd, SensorParams
from ..model.effects import PAPER_EFFECTS
from .device import parse_device
from .parser import ROOT_KEYS, check_unique_names, parse_bus, parse_metrics
from .schema import DEFAULT_METRICS_PORT, BusConfig, BusKind, DeviceConfig, GatewayConfig, TlsConfig
from .tables import Context, Table

__all__ = ["bus_config_for", "device_config_for", "gateway_config_for"]


# --------------------------------------------------------------------------- built in code
def _registers_table(registers: RegisterMap) -> dict[str, Any]:
    """A register map as the ``registers`` table the parser reads (None addresses as -1)."""
    skip = ("clock", "frame", "setup", "actions")  # tables of their own (a frame is parsed, not built)
    return {k: (-1 if v is None else v) for k, v in vars(registers).items() if k not in skip}


def _clock_value(clock: DeviceClock | None) -> object:
    if clock is None:
        return "host"
    return {
        "address": clock.address,
        "registers": clock.registers,
        "tick_s": clock.tick_s,
        "table": clock.table,
    }


def _front_end_table(front_end: FrontEnd) -> dict[str, Any]:
    """A front end as the ``front_end`` table the parser reads."""
    table: dict[str, Any] = {"kind": front_end.kind}
    for f in fields(front_end):  # type: ignore[arg-type]
        value = getattr(front_end, f.name)
        if value is not None and f.name != "kind":
            table[f.name] = value
    return table


def device_config_for(
    name: str,
    device_id: int,
    params: Sequence[SensorParams],
    columns: int,
    pitch_mm: float,
    *,
    encoding: str = "adc",
    front_end: FrontEnd | None = None,
    effects: Sequence[str] = PAPER_EFFECTS,
    registers: RegisterMap | None = None,
    allow_write: bool = False,
) -> DeviceConfig:
    """A device of ``len(params)`` channels laid out row-major (``x = (i % columns) * pitch``),
    built in code (the demo describes the array it simulates; tests and benchmarks do the
    same) and validated exactly as a ``[[bus.device]]`` table of a configuration file.
    ``ConfigError`` names the offending key."""
    defaults = vars(SensorParams())
    table: dict[str, Any] = {
        "name": name,
        "device_id": device_id,
        "encoding": encoding,
        "channels": len(params),
        "columns": columns,
        "pitch_mm": float(pitch_mm),
        "allow_write": allow_write,
        "registers": _registers_table(registers or RegisterMap()),
        "clock": _clock_value((registers or RegisterMap()).clock),
        "front_end": _front_end_table(front_end or Divider()),
        "model": {"effects": list(effects)},
        "channel": [
            {"index": i, "params": {k: v for k, v in vars(p).items() if v != defaults[k]}}
            for i, p in enumerate(params)
        ],
    }
    return parse_device(Context(None), f"device {name!r}", table)


def bus_config_for(
    name: str,
    kind: str,
    devices: Sequence[DeviceConfig],
    *,
    host: str | None = None,
    port: int | None = None,
    serial_port: str | None = None,
    baudrate: int = 115200,
    tls: TlsConfig | None = None,
    timeout_s: float = 0.5,
    retries: int = 1,
    poll_interval_s: float = 0.1,
    max_read_registers: int = MAX_READ_REGISTERS,
    backoff_initial_s: float = 0.1,
    backoff_max_s: float = 2.0,
    serial_client: str | None = None,
) -> BusConfig:
    """A bus of already built devices, validated as a ``[[bus]]`` table (see ``BusConfig``)."""
    table: dict[str, Any] = {
        "name": name,
        "kind": kind,
        "timeout_s": timeout_s,
        "retries": retries,
        "poll_interval_s": poll_interval_s,
        "max_read_registers": max_read_registers,
        "backoff_initial_s": backoff_initial_s,
        "backoff_max_s": backoff_max_s,
    }
    if kind == BusKind.RTU:
        table.update(serial_port=serial_port, baudrate=baudrate, parity="N", stopbits=1, bytesize=8)
        table.update(serial_client=serial_client)
    else:
        table.update(host=host, port=port)
    if tls is not None:
        table["tls"] = {
            k: (str(v) if isinstance(v, Path) else v) for k, v in vars(tls).items() if v is not None
        }
    return parse_bus(
        Context(None), f"bus {name!r}", {k: v for k, v in table.items() if v is not None}, devices
    )


def gateway_config_for(
    buses: Sequence[BusConfig], host: str = "127.0.0.1", port: int = DEFAULT_METRICS_PORT
) -> GatewayConfig:
    """A configuration of already built buses, metrics on ``host:port``."""
    ctx = Context(None)
    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    metrics = parse_metrics(ctx, Table(ctx, {"metrics": {"address": address}}, "", ROOT_KEYS))
    check_unique_names(ctx, buses)
    return GatewayConfig(metrics=metrics, buses=tuple(buses), source=None)
