"""The TOML parser: a configuration file into a validated ``GatewayConfig``.

``load_config`` / ``parse_config`` return a ``GatewayConfig`` or raise ``ConfigError``. Every
message names the file, the key path (``bus[0].device[1].divider.adc_bits``) and the allowed
range or values; unknown keys get a "did you mean" suggestion. The schema is documented key by
key in ``docs/configuration.md``; calibration files (``[channel.<name>]`` parameter tables)
are merged into the channels they name.
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

from ..modbus.plan import read_plan
from ..modbus.register_map import MAX_READ_REGISTERS
from ..model.params import Interval
from .device import parse_device
from .foxglove import parse_foxglove
from .mqtt import parse_mqtt
from .schema import (
    BACKOFF_INITIAL_S,
    BACKOFF_MAX_S,
    BUS_KINDS,
    BYTESIZE,
    DEFAULT_METRICS_HOST,
    DEFAULT_METRICS_PORT,
    NETWORK_KINDS,
    PARITIES,
    POLL_INTERVAL_S,
    PORT,
    RETRIES,
    SERIAL_CLIENTS,
    STANDARD_BAUDRATES,
    STOPBITS,
    TIMEOUT_S,
    BusConfig,
    BusKind,
    DeviceConfig,
    GatewayConfig,
    MetricsConfig,
    TlsConfig,
)
from .tables import REQUIRED, Context, Table, check_exists, check_private, parse_toml, read_text_file
from .web import parse_web

_HOST_RE: Final = re.compile(
    r"(?=.{1,253}\Z)[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,62})(?:\.[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,62}))*\.?"
)
ROOT_KEYS: Final = ("metrics", "bus", "mqtt", "foxglove", "web")
_METRICS_KEYS: Final = ("address", "web_config", "page")
_BUS_KEYS: Final = (
    "name",
    "kind",
    "host",
    "port",
    "serial_port",
    "baudrate",
    "parity",
    "stopbits",
    "bytesize",
    "serial_client",
    "timeout_s",
    "retries",
    "poll_interval_s",
    "max_read_registers",
    "backoff_initial_s",
    "backoff_max_s",
    "tls",
    "device",
)
_SERIAL_KEYS: Final = ("serial_port", "baudrate", "parity", "stopbits", "bytesize", "serial_client")
_NETWORK_KEYS: Final = ("host", "port")
_TLS_KEYS: Final = ("ca_file", "cert_file", "key_file", "server_hostname", "verify")


def load_config(path: Path) -> GatewayConfig:
    """Read and validate the configuration file ``path``; raises ``ConfigError``."""
    path = Path(path)
    return parse_config(read_text_file(path, "configuration file"), source=path)


def parse_config(text: str, source: Path | None = None) -> GatewayConfig:
    """Validate TOML ``text``; ``source`` names the file in messages and anchors relative paths."""
    ctx = Context(Path(source) if source is not None else None)
    data = parse_toml(ctx, text, "configuration")
    root = Table(ctx, data, "", ROOT_KEYS)
    metrics = parse_metrics(ctx, root)
    bus_items = root.tables("bus", "[[bus]]")
    if not bus_items:
        raise ctx.error("bus", "at least one [[bus]] table is required")
    buses = tuple(parse_bus(ctx, path, item) for path, item in bus_items)
    check_unique_names(ctx, buses)
    mqtt = parse_mqtt(ctx, root)
    foxglove = parse_foxglove(ctx, root, tuple(d.name for b in buses for d in b.devices))
    web = parse_web(ctx, root)
    return GatewayConfig(
        metrics=metrics, buses=buses, source=ctx.source, mqtt=mqtt, foxglove=foxglove, web=web
    )


def _parse_host(value: str) -> str | None:
    """A host name or IP address (IPv6 with or without brackets), or ``None`` if malformed."""
    inner = value[1:-1] if value.startswith("[") and value.endswith("]") else value
    try:
        return str(ipaddress.ip_address(inner))
    except ValueError:
        pass
    if inner is value and _HOST_RE.fullmatch(value):
        return value
    return None


def parse_metrics(ctx: Context, root: Table) -> MetricsConfig:
    table = root.table("metrics", _METRICS_KEYS, "[metrics]")
    host, port = DEFAULT_METRICS_HOST, DEFAULT_METRICS_PORT
    expected = "HOST:PORT with port 1..65535 (IPv6 as [::1]:9830)"
    address = table.string("address", None, f"a string {expected}")
    if address is not None:
        if address.startswith("["):
            close = address.find("]")
            host_text, rest = (address[: close + 1], address[close + 1 :]) if close > 0 else (address, "")
            port_text = rest[1:] if rest.startswith(":") else None
        else:
            host_text, sep, port_text_part = address.rpartition(":")
            port_text = port_text_part if sep else None
            if ":" in host_text:
                raise table.error(
                    "address", f"{address!r}: an IPv6 address needs brackets, e.g. '[::1]:9830'"
                )
        parsed = _parse_host(host_text) if host_text else None
        if parsed is None or port_text is None:
            raise table.error("address", f"{address!r} is not {expected}")
        if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
            raise table.error(
                "address", f"port {port_text!r} in {address!r} is out of range; allowed: 1..65535"
            )
        host, port = parsed, int(port_text)
    web_config = table.path_value("web_config")
    if web_config is not None:
        check_private(ctx, table.at("web_config"), web_config, "web config: TLS keys and basic-auth users")
    return MetricsConfig(host=host, port=port, web_config=web_config, page=table.boolean("page", True))


def _network_host(table: Table, key: str) -> str:
    value = table.required_string(key, "a host name or IP address")
    host = _parse_host(value)
    if host is None:
        raise table.error(key, f"{value!r} is not a host name or IP address")
    return host


def parse_bus(
    ctx: Context, path: str, data: dict[str, Any], built: Sequence[DeviceConfig] | None = None
) -> BusConfig:
    """A ``[[bus]]`` table; its devices from its ``[[bus.device]]`` tables, or ``built``
    (devices built in code) given instead and checked the same way."""
    table = Table(ctx, data, path, _BUS_KEYS)
    name = table.name("name")
    kind = table.choice("kind", REQUIRED, BUS_KINDS)
    forbidden = _NETWORK_KEYS if kind is BusKind.RTU else _SERIAL_KEYS
    for key in forbidden:
        if table.has(key):
            allowed_kinds = BusKind.RTU if key in _SERIAL_KEYS else ", ".join(NETWORK_KINDS)
            raise table.error(key, f"not used by kind = {kind!r}; allowed only with kind {allowed_kinds}")
    if table.has("tls") and kind is not BusKind.TLS:
        raise table.error("tls", f"[bus.tls] is not used by kind = {kind!r}; allowed only with kind tls")

    host: str | None = None
    port: int | None = None
    serial_port: str | None = None
    baudrate, parity, stopbits, bytesize = 19200, "E", 1, 8
    serial_client = SERIAL_CLIENTS[0]
    tls: TlsConfig | None = None
    if kind is BusKind.RTU:
        serial_port = table.required_string("serial_port", "a serial device such as /dev/ttyUSB0")
        if not serial_port.strip():
            raise table.error(
                "serial_port", "expected a serial device such as /dev/ttyUSB0, got an empty string"
            )
        baudrate = table.integer("baudrate", baudrate, 1, 4000000)
        if baudrate not in STANDARD_BAUDRATES:
            rates = ", ".join(str(r) for r in STANDARD_BAUDRATES)
            raise table.error("baudrate", f"{baudrate} is not a standard rate; allowed: {rates}")
        parity = table.choice("parity", parity, PARITIES)
        stopbits = table.integer("stopbits", stopbits, *STOPBITS)
        bytesize = table.integer("bytesize", bytesize, *BYTESIZE)
        serial_client = table.choice("serial_client", serial_client, SERIAL_CLIENTS)
    else:
        host = _network_host(table, "host")
        port = table.integer("port", 802 if kind is BusKind.TLS else 502, *PORT)
        if kind is BusKind.TLS:
            tls = _parse_tls(ctx, table)

    timeout_s = table.number("timeout_s", 1.0, TIMEOUT_S, " s")
    retries = table.integer("retries", 2, *RETRIES)
    poll_interval_s = table.number("poll_interval_s", 0.1, POLL_INTERVAL_S, " s")
    max_read_registers = table.integer("max_read_registers", MAX_READ_REGISTERS, 1, MAX_READ_REGISTERS)
    backoff_initial_s = table.number("backoff_initial_s", 0.5, BACKOFF_INITIAL_S, " s")
    backoff_max_s = table.number(
        "backoff_max_s",
        max(30.0, backoff_initial_s),
        Interval(backoff_initial_s, BACKOFF_MAX_S, low_inclusive=True),
        " s (>= backoff_initial_s)",
    )

    if built is None:
        device_items = table.tables("device", "[[bus.device]]")
        devices = tuple(parse_device(ctx, dpath, item) for dpath, item in device_items)
        dpaths = [dpath for dpath, _ in device_items]
    else:
        devices = tuple(built)
        dpaths = [f"{path}.device {dev.name!r}" for dev in devices]
    if not devices:
        raise table.error("device", "at least one [[bus.device]] table is required per bus")
    seen_ids: dict[int, str] = {}
    for dpath, dev in zip(dpaths, devices, strict=True):
        if dev.device_id in seen_ids:
            raise ctx.error(
                f"{dpath}.device_id",
                f"duplicate device_id {dev.device_id} on bus {name!r} (also {seen_ids[dev.device_id]}); "
                "allowed: 1..247, unique per bus",
            )
        seen_ids[dev.device_id] = f"{dpath}.device_id"
        try:
            read_plan(dev, max_read_registers)
        except ValueError as exc:
            raise table.error(
                "max_read_registers", f"{max_read_registers} is too small for device {dev.name!r}: {exc}"
            ) from None
    return BusConfig(
        name=name,
        kind=kind,
        host=host,
        port=port,
        serial_port=serial_port,
        baudrate=baudrate,
        parity=parity,
        stopbits=stopbits,
        bytesize=bytesize,
        serial_client=serial_client,
        tls=tls,
        timeout_s=timeout_s,
        retries=retries,
        poll_interval_s=poll_interval_s,
        max_read_registers=max_read_registers,
        backoff_initial_s=backoff_initial_s,
        backoff_max_s=backoff_max_s,
        devices=devices,
    )


def _parse_tls(ctx: Context, bus: Table) -> TlsConfig:
    table = bus.table("tls", _TLS_KEYS, "[bus.tls]")
    ca_file = table.path_value("ca_file")
    cert_file = table.path_value("cert_file")
    key_file = table.path_value("key_file")
    server_hostname = table.string("server_hostname", None, "a host name")
    verify = table.boolean("verify", True)
    if server_hostname is not None and _parse_host(server_hostname) is None:
        raise table.error("server_hostname", f"{server_hostname!r} is not a host name or IP address")
    if key_file is not None and cert_file is None:
        raise table.error("key_file", "needs cert_file as well (the certificate the key belongs to)")
    if ca_file is not None:
        check_exists(ctx, table.at("ca_file"), ca_file, "CA certificates")
    if cert_file is not None:
        check_exists(ctx, table.at("cert_file"), cert_file, "client certificate")
    if key_file is not None:
        check_private(ctx, table.at("key_file"), key_file, "the client's private key")
    return TlsConfig(
        ca_file=ca_file,
        cert_file=cert_file,
        key_file=key_file,
        server_hostname=server_hostname,
        verify=verify,
    )


def check_unique_names(ctx: Context, buses: Sequence[BusConfig]) -> None:
    bus_seen: dict[str, str] = {}
    device_seen: dict[str, str] = {}
    serial_seen: dict[str, str] = {}
    for b, bus in enumerate(buses):
        here = f"bus[{b}]"
        if bus.name in bus_seen:
            raise ctx.error(
                f"{here}.name",
                f"duplicate bus name {bus.name!r} (also {bus_seen[bus.name]}); bus names are unique",
            )
        bus_seen[bus.name] = f"{here}.name"
        if bus.serial_port is not None:
            if bus.serial_port in serial_seen:
                raise ctx.error(
                    f"{here}.serial_port",
                    f"{bus.serial_port!r} is already used by {serial_seen[bus.serial_port]}; "
                    "one serial port carries one bus (put all its devices under one [[bus]])",
                )
            serial_seen[bus.serial_port] = here
        for d, dev in enumerate(bus.devices):
            there = f"{here}.device[{d}].name"
            if dev.name in device_seen:
                raise ctx.error(
                    there,
                    f"duplicate device name {dev.name!r} (also {device_seen[dev.name]}); "
                    "device names are unique across the file",
                )
            device_seen[dev.name] = there
