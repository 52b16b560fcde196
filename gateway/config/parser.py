"""The TOML parser: a configuration file into a validated ``GatewayConfig``.

``load_config`` / ``parse_config`` return a ``GatewayConfig`` or raise ``ConfigError``. Every
message names the file, the key path (``bus[0].device[1].divider.adc_bits``) and the allowed
range or values; unknown keys get a "did you mean" suggestion. The schema is documented key by
key in ``docs/configuration.md``; calibration files (``[channel.<name>]`` parameter tables)
are merged into the channels they name.
"""

from __future__ import annotations

import ipaddress
import math
import re
import stat
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

from ..errors import ConfigError
from ..modbus.plan import MODBUS_MAX_READ, read_plan
from ..modbus.register_map import (
    BYTE_ORDERS,
    ENCODINGS,
    MAX_ADDRESS,
    STATUS_BITMAP_STRIDE,
    RegisterMap,
    register_blocks,
    status_registers,
)
from ..model import Divider
from ..model.effects import EFFECT_NAMES, PAPER_EFFECTS, UnknownEffectError, parse_effects
from ..model.params import PARAMETER_RANGES, Interval, ParameterError, SensorParams, parameter_names
from .schema import (
    BUS_KINDS,
    DEFAULT_METRICS_HOST,
    DEFAULT_METRICS_PORT,
    MAX_CHANNELS,
    MAX_PITCH_MM,
    MAX_POSITION_MM,
    NETWORK_KINDS,
    PARITIES,
    STANDARD_BAUDRATES,
    BusConfig,
    ChannelConfig,
    DeviceConfig,
    GatewayConfig,
    MetricsConfig,
    TlsConfig,
)
from .tables import REQUIRED, Context, Table, join_key, show_value, suggest, type_name

_HOST_RE: Final = re.compile(
    r"(?=.{1,253}\Z)[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,62})(?:\.[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,62}))*\.?"
)
ROOT_KEYS: Final = ("metrics", "bus")
_METRICS_KEYS: Final = ("address", "web_config")
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
    "timeout_s",
    "retries",
    "poll_interval_s",
    "max_read_registers",
    "backoff_initial_s",
    "backoff_max_s",
    "tls",
    "device",
)
_SERIAL_KEYS: Final = ("serial_port", "baudrate", "parity", "stopbits", "bytesize")
_NETWORK_KEYS: Final = ("host", "port")
_TLS_KEYS: Final = ("ca_file", "cert_file", "key_file", "server_hostname", "verify")
_DEVICE_KEYS: Final = (
    "name",
    "device_id",
    "encoding",
    "channels",
    "columns",
    "pitch_mm",
    "allow_write",
    "calibration",
    "registers",
    "divider",
    "model",
    "channel",
)
_REGISTER_KEYS: Final = (
    "adc_address",
    "float_address",
    "word_order",
    "byte_order",
    "status_address",
    "force_reference_address",
    "temperature_address",
)
_DIVIDER_KEYS: Final = ("supply_v", "reference_ohm", "adc_bits")
_MODEL_KEYS: Final = ("effects", "params")
_CHANNEL_KEYS: Final = ("index", "name", "x_mm", "y_mm", "enabled", "effects", "params")
_CALIBRATION_CHANNEL_TABLE: Final = "channel"

_POSITIVE: Final = Interval(0.0, math.inf, low_inclusive=False, high_inclusive=False)
_TIMEOUT: Final = Interval(0.0, 60.0, low_inclusive=False)
_POLL: Final = Interval(0.001, 3600.0, low_inclusive=True)
_BACKOFF_INITIAL: Final = Interval(0.0, 60.0, low_inclusive=False)
_POSITION: Final = Interval(-MAX_POSITION_MM, MAX_POSITION_MM, low_inclusive=True)
_PITCH: Final = Interval(0.0, MAX_PITCH_MM, low_inclusive=False)


def load_config(path: Path) -> GatewayConfig:
    """Read and validate the configuration file ``path``; raises ``ConfigError``."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the configuration file: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}): TOML files are UTF-8") from None
    return parse_config(text, source=path)


def parse_config(text: str, source: Path | None = None) -> GatewayConfig:
    """Validate TOML ``text``; ``source`` names the file in messages and anchors relative paths."""
    ctx = Context(Path(source) if source is not None else None)
    data = _parse_toml(ctx, text, "configuration")
    root = Table(ctx, data, "", ROOT_KEYS)
    metrics = parse_metrics(ctx, root)
    bus_items = root.tables("bus", "[[bus]]")
    if not bus_items:
        raise ctx.error("bus", "at least one [[bus]] table is required")
    buses = tuple(parse_bus(ctx, path, item) for path, item in bus_items)
    check_unique_names(ctx, buses)
    return GatewayConfig(metrics=metrics, buses=buses, source=ctx.source)


def _parse_toml(ctx: Context, text: str, what: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        found = re.search(r"\s*\(at line (\d+), column (\d+)\)$", message)
        if found:
            reason = message[: found.start()]
            raise ctx.error("", f"invalid TOML at line {found[1]}, column {found[2]}: {reason}") from None
        if "end of document" in message:
            line = text.count("\n") + 1
            raise ctx.error("", f"invalid TOML at line {line} (end of {what}): {message}") from None
        raise ctx.error("", f"invalid TOML: {message}") from None


def _check_private(ctx: Context, path: str, file: Path, what: str) -> None:
    """Refuse a secret-holding file that users other than its owner can access."""
    try:
        mode = stat.S_IMODE(file.stat().st_mode)
    except FileNotFoundError:
        raise ctx.error(path, f"{file} does not exist ({what})") from None
    except OSError as exc:
        raise ctx.error(path, f"cannot access {file}: {exc.strerror or exc}") from None
    if not file.is_file():
        raise ctx.error(path, f"{file} is not a regular file ({what})")
    if mode & 0o077:
        raise ctx.error(
            path,
            f"{file} holds secrets ({what}) but is accessible to other users (mode {mode:04o}; allowed: "
            f"no group/other permissions, e.g. 0600): run `chmod 600 {file}`",
        )


def _check_exists(ctx: Context, path: str, file: Path, what: str) -> None:
    if not file.exists():
        raise ctx.error(path, f"{file} does not exist ({what})")
    if not file.is_file():
        raise ctx.error(path, f"{file} is not a regular file ({what})")


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
        _check_private(ctx, table.at("web_config"), web_config, "web config: TLS keys and basic-auth users")
    return MetricsConfig(host=host, port=port, web_config=web_config)


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
    forbidden = _NETWORK_KEYS if kind == "rtu" else _SERIAL_KEYS
    for key in forbidden:
        if table.has(key):
            allowed_kinds = "rtu" if key in _SERIAL_KEYS else ", ".join(NETWORK_KINDS)
            raise table.error(key, f"not used by kind = {kind!r}; allowed only with kind {allowed_kinds}")
    if table.has("tls") and kind != "tls":
        raise table.error("tls", f"[bus.tls] is not used by kind = {kind!r}; allowed only with kind tls")

    host: str | None = None
    port: int | None = None
    serial_port: str | None = None
    baudrate, parity, stopbits, bytesize = 19200, "E", 1, 8
    tls: TlsConfig | None = None
    if kind == "rtu":
        serial_port = table.required_string("serial_port", "a serial device such as /dev/ttyUSB0")
        if not serial_port.strip():
            raise table.error(
                "serial_port", "expected a serial device such as /dev/ttyUSB0, got an empty string"
            )
        baudrate = table.integer("baudrate", baudrate, 1, 921600)
        if baudrate not in STANDARD_BAUDRATES:
            rates = ", ".join(str(r) for r in STANDARD_BAUDRATES)
            raise table.error("baudrate", f"{baudrate} is not a standard rate; allowed: {rates}")
        parity = table.choice("parity", parity, PARITIES)
        stopbits = table.integer("stopbits", stopbits, 1, 2)
        bytesize = table.integer("bytesize", bytesize, 7, 8)
    else:
        host = _network_host(table, "host")
        port = table.integer("port", 802 if kind == "tls" else 502, 1, 65535)
        if kind == "tls":
            tls = _parse_tls(ctx, table)

    timeout_s = table.number("timeout_s", 1.0, _TIMEOUT, " s")
    retries = table.integer("retries", 2, 0, 10)
    poll_interval_s = table.number("poll_interval_s", 0.1, _POLL, " s")
    max_read_registers = table.integer("max_read_registers", MODBUS_MAX_READ, 1, MODBUS_MAX_READ)
    backoff_initial_s = table.number("backoff_initial_s", 0.5, _BACKOFF_INITIAL, " s")
    backoff_max_s = table.number(
        "backoff_max_s",
        max(30.0, backoff_initial_s),
        Interval(backoff_initial_s, 3600.0, low_inclusive=True),
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
        _check_exists(ctx, table.at("ca_file"), ca_file, "CA certificates")
    if cert_file is not None:
        _check_exists(ctx, table.at("cert_file"), cert_file, "client certificate")
    if key_file is not None:
        _check_private(ctx, table.at("key_file"), key_file, "the client's private key")
    return TlsConfig(
        ca_file=ca_file,
        cert_file=cert_file,
        key_file=key_file,
        server_hostname=server_hostname,
        verify=verify,
    )


def _parse_registers(table: Table, n: int) -> RegisterMap:
    status_span = 2 * STATUS_BITMAP_STRIDE + status_registers(n)
    return RegisterMap(
        adc_address=table.integer(
            "adc_address", 100, 0, MAX_ADDRESS + 1 - n, f" (the {n}-register ADC block)"
        ),
        float_address=table.integer(
            "float_address", 400, 0, MAX_ADDRESS + 1 - 2 * n, f" (the {2 * n}-register float32 block)"
        ),
        word_order=table.choice("word_order", "big", BYTE_ORDERS),
        byte_order=table.choice("byte_order", "big", BYTE_ORDERS),
        status_address=table.optional_address("status_address", 16, MAX_ADDRESS + 1 - status_span),
        force_reference_address=table.optional_address(
            "force_reference_address", None, MAX_ADDRESS + 1 - 2 * n
        ),
        temperature_address=table.optional_address("temperature_address", None, MAX_ADDRESS + 1 - 2 * n),
    )


def _check_overlaps(ctx: Context, path: str, device: DeviceConfig) -> None:
    keys = {
        "status": "status_address",
        "adc": "adc_address",
        "float": "float_address",
        "force_reference": "force_reference_address",
        "temperature": "temperature_address",
    }
    blocks = register_blocks(device)
    for i, later in enumerate(blocks):
        for earlier in blocks[:i]:
            if later.kind == earlier.kind and later.address <= earlier.end and earlier.address <= later.end:
                raise ctx.error(
                    f"{path}.registers.{keys[later.purpose]}",
                    f"the {later.name} block {later.address}..{later.end} overlaps the {earlier.name} block "
                    f"{earlier.address}..{earlier.end}; register blocks must not overlap",
                )


def _parse_divider(table: Table) -> Divider:
    return Divider(
        supply_v=table.number("supply_v", 5.0, _POSITIVE, " V"),
        reference_ohm=table.number("reference_ohm", 10e3, _POSITIVE, " ohm"),
        adc_bits=table.integer("adc_bits", 16, 8, 16, " (ADC counts are one 16-bit register)"),
    )


def _parse_effects(ctx: Context, path: str, value: object) -> tuple[str, ...]:
    expected = f"an array of effect names ({', '.join(EFFECT_NAMES)})"
    if not isinstance(value, list):
        raise ctx.error(path, f"expected {expected}, got {type_name(value)} {show_value(value)}")
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise ctx.error(
                f"{path}[{i}]", f"expected an effect name, got {type_name(item)} {show_value(item)}"
            )
        try:
            parse_effects([item])
        except UnknownEffectError as exc:
            raise ctx.error(f"{path}[{i}]", str(exc)) from None
    return parse_effects(value)


def _parse_param_overrides(ctx: Context, path: str, value: object) -> dict[str, float]:
    """Check each override on its own: a known name, a number, inside its allowed range."""
    if not isinstance(value, dict):
        raise ctx.error(
            path, f"expected a table of sensor parameters, got {type_name(value)} {show_value(value)}"
        )
    out: dict[str, float] = {}
    known = parameter_names()
    for key, raw in value.items():
        try:
            if key not in known:
                SensorParams.from_mapping({key: raw})
            SensorParams(**{key: raw})
        except ParameterError as exc:
            in_range = (
                key in known
                and not isinstance(raw, bool)
                and isinstance(raw, int | float)
                and PARAMETER_RANGES[key].contains(float(raw))
            )
            if not in_range:  # else it only conflicts with a default; the resolved set is checked later
                raise ctx.error(join_key(path, key), str(exc)) from None
        out[key] = float(raw)
    return out


def _load_calibration(
    ctx: Context, path: str, file: Path, channel_names: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Per-channel parameter tables ``[channel.<name>]`` of a calibration file."""
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ctx.error(path, f"{file} does not exist (calibration file)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ctx.error(path, f"cannot read calibration file {file}: {exc}") from None
    cal_ctx = Context(file)
    note = f" (calibration file of {path} in {ctx.label})"
    try:
        data = _parse_toml(cal_ctx, text, "calibration")
        tables = data.get(_CALIBRATION_CHANNEL_TABLE, {})
        if not isinstance(tables, dict):
            raise cal_ctx.error("channel", f"expected tables [channel.<name>], got {type_name(tables)}")
        out: dict[str, dict[str, float]] = {}
        for name, params in tables.items():
            if name not in channel_names:
                raise cal_ctx.error(
                    join_key("channel", name),
                    f"no channel {name!r} in this device{suggest(name, channel_names)} "
                    f"(channels: {', '.join(channel_names[:8])}{', ...' if len(channel_names) > 8 else ''})",
                )
            out[name] = _parse_param_overrides(cal_ctx, join_key("channel", name), params)
    except ConfigError as exc:
        raise ConfigError(f"{exc}{note}") from None
    return out


def parse_device(ctx: Context, path: str, data: dict[str, Any]) -> DeviceConfig:
    table = Table(ctx, data, path, _DEVICE_KEYS)
    name = table.name("name")
    device_id = table.integer("device_id", REQUIRED, 1, 247)
    encoding = table.choice("encoding", "adc", ENCODINGS)
    n = table.integer("channels", REQUIRED, 1, MAX_CHANNELS)
    columns = table.integer("columns", math.isqrt(n - 1) + 1, 1, n, f" (at most channels = {n})")
    pitch_mm = table.number("pitch_mm", 2.5, _PITCH, " mm")
    allow_write = table.boolean("allow_write", False)
    calibration = table.path_value("calibration")
    registers = _parse_registers(table.table("registers", _REGISTER_KEYS, "[bus.device.registers]"), n)
    divider = _parse_divider(table.table("divider", _DIVIDER_KEYS, "[bus.device.divider]"))

    model = table.table("model", _MODEL_KEYS, "[bus.device.model]")
    device_effects = (
        _parse_effects(ctx, model.at("effects"), model.data["effects"])
        if model.has("effects")
        else PAPER_EFFECTS
    )
    device_params = _parse_param_overrides(
        ctx, model.at("params"), model.raw_table("params", "[bus.device.model.params]")
    )

    # Per-channel entries, keyed by channel index.
    entries: dict[int, tuple[Table, dict[str, float]]] = {}
    entry_paths: dict[int, str] = {}
    for cpath, item in table.tables("channel", "[[bus.device.channel]]"):
        entry = Table(ctx, item, cpath, _CHANNEL_KEYS)
        index = entry.integer("index", REQUIRED, 0, n - 1, f" (channels = {n})")
        if index in entries:
            raise entry.error(
                "index",
                f"duplicate channel index {index} (also {entry_paths[index]}); each index once, 0..{n - 1}",
            )
        overrides = _parse_param_overrides(
            ctx, entry.at("params"), entry.raw_table("params", "params = {...}")
        )
        entries[index] = (entry, overrides)
        entry_paths[index] = entry.at("index")

    names: list[str] = []
    # name -> (index, key path of an explicit name or None for a default name)
    name_owner: dict[str, tuple[int, str | None]] = {}
    for i in range(n):
        channel_name = f"ch{i:02d}"
        where: str | None = None
        if i in entries and entries[i][0].has("name"):
            channel_name = entries[i][0].name("name")
            where = entries[i][0].at("name")
        if channel_name in name_owner:
            other, other_where = name_owner[channel_name]
            blame_path = where or other_where or f"{path}.channel"
            raise ctx.error(
                blame_path,
                f"duplicate channel name {channel_name!r}: channels {other} and {i} both have it "
                "(unnamed channels are called ch00, ch01, ...); channel names are unique within a device",
            )
        name_owner[channel_name] = (i, where)
        names.append(channel_name)

    calibrated: dict[str, dict[str, float]] = {}
    if calibration is not None:
        calibrated = _load_calibration(ctx, table.at("calibration"), calibration, names)

    channels: list[ChannelConfig] = []
    for i, channel_name in enumerate(names):
        x_mm = float((i % columns) * pitch_mm)
        y_mm = float((i // columns) * pitch_mm)
        enabled = True
        effects = device_effects
        merged = dict(device_params)
        merged.update(calibrated.get(channel_name, {}))
        blame = model.at("params")
        if channel_name in calibrated:
            blame = f"{table.at('calibration')} [channel.{channel_name}]"
        if i in entries:
            entry, overrides = entries[i]
            x_mm = entry.number("x_mm", x_mm, _POSITION, " mm")
            y_mm = entry.number("y_mm", y_mm, _POSITION, " mm")
            enabled = entry.boolean("enabled", True)
            if entry.has("effects"):
                effects = _parse_effects(ctx, entry.at("effects"), entry.data["effects"])
            merged.update(overrides)
            if overrides:
                blame = entry.at("params")
        try:
            params = SensorParams(**merged)
        except ParameterError as exc:
            raise ctx.error(blame, f"{exc} (channel {channel_name!r}, index {i})") from None
        channels.append(ChannelConfig(i, channel_name, x_mm, y_mm, enabled, effects, params))

    device = DeviceConfig(
        name=name,
        device_id=device_id,
        encoding=encoding,
        n_channels=n,
        registers=registers,
        divider=divider,
        channels=tuple(channels),
        allow_write=allow_write,
        columns=columns,
        pitch_mm=pitch_mm,
        calibration=calibration,
    )
    _check_overlaps(ctx, path, device)
    return device


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
