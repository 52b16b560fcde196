"""The gateway configuration: a TOML file turned into frozen dataclasses, validated at load.

``load_config`` / ``parse_config`` return a ``GatewayConfig`` or raise ``ConfigError``. Every
message names the file, the key path (``bus[0].device[1].divider.adc_bits``) and the allowed
range or values; unknown keys get a "did you mean" suggestion. The schema is documented key by
key in ``docs/configuration.md``.

``read_plan`` turns a device into the Modbus reads one poll needs: the register blocks of
``docs/register-map.md`` coalesced into the fewest requests a bus allows.
"""

from __future__ import annotations

import difflib
import ipaddress
import math
import os
import re
import stat
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from .errors import ConfigError
from .model.divider import Divider
from .model.effects import EFFECT_NAMES, PAPER_EFFECTS, UnknownEffectError, parse_effects
from .model.params import PARAMETER_RANGES, Interval, ParameterError, SensorParams, parameter_names

__all__ = [
    "BUS_KINDS",
    "ENCODINGS",
    "MAX_GAP_REGISTERS",
    "NETWORK_KINDS",
    "STANDARD_BAUDRATES",
    "BusConfig",
    "ChannelConfig",
    "DeviceConfig",
    "GatewayConfig",
    "MetricsConfig",
    "ReadRequest",
    "RegisterBlock",
    "RegisterMap",
    "TlsConfig",
    "block_registers",
    "load_config",
    "parse_config",
    "read_plan",
    "register_blocks",
]

BUS_KINDS: Final = ("tcp", "rtu", "rtu-over-tcp", "tls")
#: Bus kinds that reach the device over the network (host and port).
NETWORK_KINDS: Final = ("tcp", "rtu-over-tcp", "tls")
STANDARD_BAUDRATES: Final = (
    1200,
    2400,
    4800,
    9600,
    14400,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    921600,
)
ENCODINGS: Final = ("adc", "float32")
BYTE_ORDERS: Final = ("big", "little")
PARITIES: Final = ("N", "E", "O")
#: Two register ranges at most this many registers apart are read in one request.
MAX_GAP_REGISTERS: Final = 8
#: Modbus allows at most 125 registers in one read (function codes 3 and 4).
MODBUS_MAX_READ: Final = 125
MAX_CHANNELS: Final = 256
#: The three status bitmaps (open, short, saturated) start 16 registers apart.
STATUS_BITMAP_STRIDE: Final = 16
STATUS_BITMAPS: Final = ("open", "short", "saturated")
#: Channel positions must lie within this many millimetres of the origin.
MAX_POSITION_MM: Final = 10_000.0
MAX_PITCH_MM: Final = 1_000.0
DEFAULT_METRICS_HOST: Final = "127.0.0.1"
DEFAULT_METRICS_PORT: Final = 9830

_NAME_RE: Final = re.compile(r"[a-z0-9_-]{1,32}")
_NAME_RULE: Final = "a name matching [a-z0-9_-]{1,32}"
_HOST_RE: Final = re.compile(
    r"(?=.{1,253}\Z)[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,62})(?:\.[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,62}))*\.?"
)
_BARE_KEY_RE: Final = re.compile(r"[A-Za-z0-9_-]+")


# ----------------------------------------------------------------------------------------------
# The configuration dataclasses


@dataclass(frozen=True)
class TlsConfig:
    """Modbus/TCP Security (``kind = "tls"``): client certificate and server verification."""

    ca_file: Path | None
    cert_file: Path | None
    key_file: Path | None
    server_hostname: str | None
    verify: bool = True


@dataclass(frozen=True)
class MetricsConfig:
    """Where the Prometheus endpoint listens, and its optional exporter-toolkit web config."""

    host: str = DEFAULT_METRICS_HOST
    port: int = DEFAULT_METRICS_PORT
    web_config: Path | None = None


@dataclass(frozen=True)
class RegisterMap:
    """Input-register addresses of a device (defaults: ``docs/register-map.md``).

    ``word_order`` is the order of the two registers of a float32 (``big``: high word first),
    ``byte_order`` the order of the bytes within a register. ``None`` disables an optional block.
    """

    adc_address: int = 100
    float_address: int = 400
    word_order: str = "big"
    byte_order: str = "big"
    status_address: int | None = 16
    force_reference_address: int | None = None
    temperature_address: int | None = None


@dataclass(frozen=True)
class ChannelConfig:
    """One sensor of an array, fully resolved (defaults, device, calibration, channel overrides)."""

    index: int
    name: str
    x_mm: float
    y_mm: float
    enabled: bool
    effects: tuple[str, ...]
    params: SensorParams


@dataclass(frozen=True)
class DeviceConfig:
    """One sensor array on a bus; ``channels`` holds all ``n_channels`` channels in index order."""

    name: str
    device_id: int
    encoding: str
    n_channels: int
    registers: RegisterMap
    divider: Divider
    channels: tuple[ChannelConfig, ...]
    allow_write: bool
    columns: int
    pitch_mm: float
    calibration: Path | None

    def channel(self, name: str) -> ChannelConfig:
        """The channel called ``name`` (``KeyError`` if there is none)."""
        for ch in self.channels:
            if ch.name == name:
                return ch
        raise KeyError(name)

    @property
    def enabled_channels(self) -> tuple[ChannelConfig, ...]:
        return tuple(ch for ch in self.channels if ch.enabled)


@dataclass(frozen=True)
class BusConfig:
    """One Modbus connection (a TCP socket or a serial line) and the devices polled over it."""

    name: str
    kind: str
    host: str | None
    port: int | None
    serial_port: str | None
    baudrate: int
    parity: str
    stopbits: int
    bytesize: int
    tls: TlsConfig | None
    timeout_s: float
    retries: int
    poll_interval_s: float
    max_read_registers: int
    backoff_initial_s: float
    backoff_max_s: float
    devices: tuple[DeviceConfig, ...]

    @property
    def endpoint(self) -> str:
        """``host:port`` (``[v6]:port``) for network buses, the serial port for ``rtu``."""
        if self.kind == "rtu":
            return self.serial_port or ""
        host = self.host or ""
        return f"[{host}]:{self.port}" if ":" in host else f"{host}:{self.port}"


@dataclass(frozen=True)
class GatewayConfig:
    """The whole file: the metrics endpoint and the buses; ``source`` is the file it came from."""

    metrics: MetricsConfig
    buses: tuple[BusConfig, ...]
    source: Path | None

    def devices(self) -> tuple[tuple[BusConfig, DeviceConfig], ...]:
        """Every (bus, device) pair, in file order."""
        return tuple((bus, dev) for bus in self.buses for dev in bus.devices)

    def find_device(self, name: str) -> tuple[BusConfig, DeviceConfig]:
        """The bus and device called ``name`` (device names are unique in a file)."""
        for bus, dev in self.devices():
            if dev.name == name:
                return bus, dev
        raise KeyError(name)


# ----------------------------------------------------------------------------------------------
# Read plan


@dataclass(frozen=True)
class ReadRequest:
    """One Modbus read of a poll: ``count`` registers from ``address``.

    ``kind`` is ``"input"`` (function 4) or ``"holding"`` (function 3); ``purpose`` names the
    register blocks it covers, in address order, e.g. ``("status", "adc")``.
    """

    kind: str
    address: int
    count: int
    purpose: tuple[str, ...]

    @property
    def end(self) -> int:
        """The last address read (inclusive)."""
        return self.address + self.count - 1


@dataclass(frozen=True)
class RegisterBlock:
    """One block of the register map a poll needs.

    ``name`` is one of ``status_open``, ``status_short``, ``status_saturated``, ``adc``,
    ``float``, ``force_reference``, ``temperature``; ``purpose`` groups the three status
    bitmaps as ``status``. ``value_registers`` is 1 for uint16 values, 2 for float32 values.
    """

    name: str
    purpose: str
    kind: str
    address: int
    count: int
    value_registers: int

    @property
    def end(self) -> int:
        return self.address + self.count - 1


def _status_registers(n_channels: int) -> int:
    return (n_channels + 15) // 16


def register_blocks(device: DeviceConfig) -> tuple[RegisterBlock, ...]:
    """The register blocks one poll of ``device`` reads, in the order of the register map."""
    n = device.n_channels
    regs = device.registers
    blocks: list[RegisterBlock] = []
    if regs.status_address is not None:
        width = _status_registers(n)
        for i, bitmap in enumerate(STATUS_BITMAPS):
            address = regs.status_address + i * STATUS_BITMAP_STRIDE
            blocks.append(RegisterBlock(f"status_{bitmap}", "status", "input", address, width, 1))
    if device.encoding == "adc":
        blocks.append(RegisterBlock("adc", "adc", "input", regs.adc_address, n, 1))
    else:
        blocks.append(RegisterBlock("float", "float", "input", regs.float_address, 2 * n, 2))
    if regs.force_reference_address is not None:
        blocks.append(
            RegisterBlock(
                "force_reference", "force_reference", "input", regs.force_reference_address, 2 * n, 2
            )
        )
    if regs.temperature_address is not None:
        blocks.append(
            RegisterBlock("temperature", "temperature", "input", regs.temperature_address, 2 * n, 2)
        )
    return tuple(blocks)


def read_plan(
    device: DeviceConfig, max_read_registers: int, max_gap: int = MAX_GAP_REGISTERS
) -> tuple[ReadRequest, ...]:
    """The reads of one poll of ``device``, coalesced into the fewest requests.

    Register ranges of the same kind that touch or lie at most ``max_gap`` registers apart are
    read together (the gap registers are read and ignored); no request is longer than
    ``max_read_registers``, and a float32 value is never split across two requests. Raises
    ``ValueError`` if ``max_read_registers`` cannot hold one value.
    """
    if not 1 <= max_read_registers <= MODBUS_MAX_READ:
        raise ValueError(f"max_read_registers = {max_read_registers} is outside 1..{MODBUS_MAX_READ}")
    if max_gap < 0:
        raise ValueError(f"max_gap = {max_gap} must be >= 0")
    blocks = register_blocks(device)
    widest = max(b.value_registers for b in blocks)
    if widest > max_read_registers:
        raise ValueError(
            f"max_read_registers = {max_read_registers} cannot hold a float32 value (2 registers, "
            f"never split across reads); allowed: 2..{MODBUS_MAX_READ}"
        )
    requests: list[ReadRequest] = []
    for kind in ("holding", "input"):
        # Every value of every block as (start, registers, purpose), in address order.
        units = sorted(
            (b.address + k * b.value_registers, b.value_registers, b.purpose)
            for b in blocks
            if b.kind == kind
            for k in range(b.count // b.value_registers)
        )
        start = end = -1
        purposes: list[str] = []
        for unit_start, width, purpose in units:
            unit_end = unit_start + width - 1
            if (
                start >= 0
                and unit_start - end - 1 <= max_gap
                and max(end, unit_end) - start < max_read_registers
            ):
                end = max(end, unit_end)
                if purpose not in purposes:
                    purposes.append(purpose)
                continue
            if start >= 0:
                requests.append(ReadRequest(kind, start, end - start + 1, tuple(purposes)))
            start, end, purposes = unit_start, unit_end, [purpose]
        if start >= 0:
            requests.append(ReadRequest(kind, start, end - start + 1, tuple(purposes)))
    return tuple(requests)


def block_registers(
    block: RegisterBlock, responses: Iterable[tuple[ReadRequest, Sequence[int]]]
) -> list[int]:
    """Assemble the registers of ``block`` from the answers to a read plan.

    ``responses`` pairs each request with the registers it returned. Raises ``ValueError`` if
    the answers do not cover the whole block.
    """
    out: list[int | None] = [None] * block.count
    for request, registers in responses:
        if request.kind != block.kind:
            continue
        if len(registers) != request.count:
            raise ValueError(
                f"read of {request.count} registers at {request.address} returned {len(registers)} registers"
            )
        low = max(block.address, request.address)
        high = min(block.end, request.end)
        for address in range(low, high + 1):
            out[address - block.address] = registers[address - request.address]
    missing = [block.address + i for i, v in enumerate(out) if v is None]
    if missing:
        raise ValueError(f"block {block.name} misses register {missing[0]} in the responses")
    return [v for v in out if v is not None]


# ----------------------------------------------------------------------------------------------
# Reading tables with precise errors


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


_REQUIRED: Final = _Required()


def _type_name(value: object) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "table"
    return "date/time"


def _show(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, dict):
        return "{...}"
    if isinstance(value, list):
        return "[...]"
    return str(value)


def _join(path: str, key: str) -> str:
    shown = key if _BARE_KEY_RE.fullmatch(key) else '"' + key.replace('"', '\\"') + '"'
    return f"{path}.{shown}" if path else shown


def _suggest(word: str, choices: Iterable[str], cutoff: float = 0.6) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=cutoff)
    return f"; did you mean {close[0]!r}?" if close else ""


class _Context:
    """What every message needs: the file, and the directory relative paths start from."""

    def __init__(self, source: Path | None) -> None:
        self.source = source
        self.label = str(source) if source is not None else "<string>"
        base = source.parent if source is not None else Path.cwd()
        self.base_dir = Path(os.path.abspath(base))

    def error(self, path: str, message: str) -> ConfigError:
        return ConfigError(f"{self.label}: {path}: {message}" if path else f"{self.label}: {message}")

    def resolve(self, text: str) -> Path:
        p = Path(text).expanduser()
        return Path(os.path.abspath(p if p.is_absolute() else self.base_dir / p))


class _Table:
    """A TOML table being read: typed getters that raise ``ConfigError`` with the key path."""

    def __init__(self, ctx: _Context, data: Mapping[str, Any], path: str, allowed: Sequence[str]) -> None:
        self.ctx = ctx
        self.data = data
        self.path = path
        for key in data:
            if key not in allowed:
                raise ctx.error(
                    _join(path, key),
                    f"unknown key{_suggest(key, allowed)} (allowed keys: {', '.join(allowed)})",
                )

    def at(self, key: str) -> str:
        return _join(self.path, key)

    def has(self, key: str) -> bool:
        return key in self.data

    def error(self, key: str, message: str) -> ConfigError:
        return self.ctx.error(self.at(key), message)

    def _get(self, key: str, default: object, expected: str) -> Any:
        if key in self.data:
            return self.data[key]
        if default is _REQUIRED:
            raise self.error(key, f"required key is missing; expected {expected}")
        return default

    def _wrong_type(self, key: str, value: object, expected: str) -> ConfigError:
        return self.error(key, f"expected {expected}, got {_type_name(value)} {_show(value)}")

    def integer(self, key: str, default: int | _Required, low: int, high: int, unit: str = "") -> int:
        expected = f"an integer in {low}..{high}{unit}"
        value = self._get(key, default, expected)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._wrong_type(key, value, expected)
        if not low <= value <= high:
            raise self.error(key, f"{value} is out of range; allowed: {low}..{high}{unit}")
        return value

    def optional_address(self, key: str, default: int | None, high: int) -> int | None:
        """An address 0..high, or -1 (or absent with a ``None`` default) for "not present"."""
        expected = f"an integer in 0..{high}, or -1 to disable"
        if key not in self.data:
            return default
        value = self.data[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._wrong_type(key, value, expected)
        if value == -1:
            return None
        if not 0 <= value <= high:
            raise self.error(key, f"{value} is out of range; allowed: 0..{high}, or -1 to disable")
        return value

    def number(self, key: str, default: float | _Required, interval: Interval, unit: str = "") -> float:
        expected = f"a number in {interval.describe()}{unit}"
        value = self._get(key, default, expected)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self._wrong_type(key, value, expected)
        number = float(value)
        if not interval.contains(number):
            raise self.error(key, f"{_show(value)} is out of range; allowed: {interval.describe()}{unit}")
        return number

    def boolean(self, key: str, default: bool) -> bool:
        value = self._get(key, default, "true or false")
        if not isinstance(value, bool):
            raise self._wrong_type(key, value, "a boolean (true or false)")
        return value

    def string(self, key: str, default: str | _Required | None, expected: str = "a string") -> str | None:
        value = self._get(key, default, expected)
        if value is None:
            return None
        if not isinstance(value, str):
            raise self._wrong_type(key, value, expected)
        return value

    def required_string(self, key: str, expected: str = "a string") -> str:
        value = self.string(key, _REQUIRED, expected)
        assert value is not None  # a required key is never None
        return value

    def choice(self, key: str, default: str | _Required, choices: Sequence[str]) -> str:
        listed = " | ".join(choices)
        expected = f"one of {listed}"
        value = self._get(key, default, expected)
        if not isinstance(value, str):
            raise self._wrong_type(key, value, expected)
        if value not in choices:
            raise self.error(
                key, f"{value!r} is not allowed{_suggest(value, choices, 0.3)} (allowed: {listed})"
            )
        return value

    def name(self, key: str) -> str:
        value = self.required_string(key, _NAME_RULE)
        if not _NAME_RE.fullmatch(value):
            raise self.error(key, f"{value!r} is not {_NAME_RULE}")
        return value

    def path_value(self, key: str) -> Path | None:
        value = self.string(key, None, "a file path (string)")
        if value is None:
            return None
        if not value.strip():
            raise self.error(key, "expected a file path, got an empty string")
        return self.ctx.resolve(value)

    def table(self, key: str, allowed: Sequence[str], header: str) -> _Table:
        value = self.data.get(key, {})
        if not isinstance(value, dict):
            raise self._wrong_type(key, value, f"a table ({header})")
        return _Table(self.ctx, value, self.at(key), allowed)

    def raw_table(self, key: str, header: str) -> dict[str, Any]:
        value = self.data.get(key, {})
        if not isinstance(value, dict):
            raise self._wrong_type(key, value, f"a table ({header})")
        return value

    def tables(self, key: str, header: str) -> list[tuple[str, dict[str, Any]]]:
        """An array of tables, as (key path, table) pairs."""
        value = self.data.get(key, [])
        if isinstance(value, dict):
            raise self.error(
                key, f"expected an array of tables ({header}), got a single table; write {header}"
            )
        if not isinstance(value, list):
            raise self._wrong_type(key, value, f"an array of tables ({header})")
        out: list[tuple[str, dict[str, Any]]] = []
        for i, item in enumerate(value):
            if not isinstance(item, dict):
                raise self.ctx.error(
                    f"{self.at(key)}[{i}]", f"expected a table, got {_type_name(item)} {_show(item)}"
                )
            out.append((f"{self.at(key)}[{i}]", item))
        return out


# ----------------------------------------------------------------------------------------------
# The schema

_ROOT_KEYS: Final = ("metrics", "bus")
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
_ADDRESS_MAX: Final = 65535


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
    ctx = _Context(Path(source) if source is not None else None)
    data = _parse_toml(ctx, text, "configuration")
    root = _Table(ctx, data, "", _ROOT_KEYS)
    metrics = _parse_metrics(ctx, root)
    bus_items = root.tables("bus", "[[bus]]")
    if not bus_items:
        raise ctx.error("bus", "at least one [[bus]] table is required")
    buses = tuple(_parse_bus(ctx, path, item) for path, item in bus_items)
    _check_unique_names(ctx, buses)
    return GatewayConfig(metrics=metrics, buses=buses, source=ctx.source)


def _parse_toml(ctx: _Context, text: str, what: str) -> dict[str, Any]:
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


def _check_private(ctx: _Context, path: str, file: Path, what: str) -> None:
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


def _check_exists(ctx: _Context, path: str, file: Path, what: str) -> None:
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


def _parse_metrics(ctx: _Context, root: _Table) -> MetricsConfig:
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


def _network_host(table: _Table, key: str) -> str:
    value = table.required_string(key, "a host name or IP address")
    host = _parse_host(value)
    if host is None:
        raise table.error(key, f"{value!r} is not a host name or IP address")
    return host


def _parse_bus(
    ctx: _Context, path: str, data: dict[str, Any], built: Sequence[DeviceConfig] | None = None
) -> BusConfig:
    """A ``[[bus]]`` table; its devices from its ``[[bus.device]]`` tables, or ``built``
    (devices built in code) given instead and checked the same way."""
    table = _Table(ctx, data, path, _BUS_KEYS)
    name = table.name("name")
    kind = table.choice("kind", _REQUIRED, BUS_KINDS)
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
        devices = tuple(_parse_device(ctx, dpath, item) for dpath, item in device_items)
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


def _parse_tls(ctx: _Context, bus: _Table) -> TlsConfig:
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


def _parse_registers(table: _Table, n: int) -> RegisterMap:
    status_span = 2 * STATUS_BITMAP_STRIDE + _status_registers(n)
    return RegisterMap(
        adc_address=table.integer(
            "adc_address", 100, 0, _ADDRESS_MAX + 1 - n, f" (the {n}-register ADC block)"
        ),
        float_address=table.integer(
            "float_address", 400, 0, _ADDRESS_MAX + 1 - 2 * n, f" (the {2 * n}-register float32 block)"
        ),
        word_order=table.choice("word_order", "big", BYTE_ORDERS),
        byte_order=table.choice("byte_order", "big", BYTE_ORDERS),
        status_address=table.optional_address("status_address", 16, _ADDRESS_MAX + 1 - status_span),
        force_reference_address=table.optional_address(
            "force_reference_address", None, _ADDRESS_MAX + 1 - 2 * n
        ),
        temperature_address=table.optional_address("temperature_address", None, _ADDRESS_MAX + 1 - 2 * n),
    )


def _check_overlaps(ctx: _Context, path: str, device: DeviceConfig) -> None:
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


def _parse_divider(table: _Table) -> Divider:
    return Divider(
        supply_v=table.number("supply_v", 5.0, _POSITIVE, " V"),
        reference_ohm=table.number("reference_ohm", 10e3, _POSITIVE, " ohm"),
        adc_bits=table.integer("adc_bits", 16, 8, 16, " (ADC counts are one 16-bit register)"),
    )


def _parse_effects(ctx: _Context, path: str, value: object) -> tuple[str, ...]:
    expected = f"an array of effect names ({', '.join(EFFECT_NAMES)})"
    if not isinstance(value, list):
        raise ctx.error(path, f"expected {expected}, got {_type_name(value)} {_show(value)}")
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise ctx.error(f"{path}[{i}]", f"expected an effect name, got {_type_name(item)} {_show(item)}")
        try:
            parse_effects([item])
        except UnknownEffectError as exc:
            raise ctx.error(f"{path}[{i}]", str(exc)) from None
    return parse_effects(value)


def _parse_param_overrides(ctx: _Context, path: str, value: object) -> dict[str, float]:
    """Check each override on its own: a known name, a number, inside its allowed range."""
    if not isinstance(value, dict):
        raise ctx.error(
            path, f"expected a table of sensor parameters, got {_type_name(value)} {_show(value)}"
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
                raise ctx.error(_join(path, key), str(exc)) from None
        out[key] = float(raw)
    return out


def _load_calibration(
    ctx: _Context, path: str, file: Path, channel_names: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Per-channel parameter tables ``[channel.<name>]`` of a calibration file."""
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ctx.error(path, f"{file} does not exist (calibration file)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ctx.error(path, f"cannot read calibration file {file}: {exc}") from None
    cal_ctx = _Context(file)
    note = f" (calibration file of {path} in {ctx.label})"
    try:
        data = _parse_toml(cal_ctx, text, "calibration")
        tables = data.get(_CALIBRATION_CHANNEL_TABLE, {})
        if not isinstance(tables, dict):
            raise cal_ctx.error("channel", f"expected tables [channel.<name>], got {_type_name(tables)}")
        out: dict[str, dict[str, float]] = {}
        for name, params in tables.items():
            if name not in channel_names:
                raise cal_ctx.error(
                    _join("channel", name),
                    f"no channel {name!r} in this device{_suggest(name, channel_names)} "
                    f"(channels: {', '.join(channel_names[:8])}{', ...' if len(channel_names) > 8 else ''})",
                )
            out[name] = _parse_param_overrides(cal_ctx, _join("channel", name), params)
    except ConfigError as exc:
        raise ConfigError(f"{exc}{note}") from None
    return out


def _parse_device(ctx: _Context, path: str, data: dict[str, Any]) -> DeviceConfig:
    table = _Table(ctx, data, path, _DEVICE_KEYS)
    name = table.name("name")
    device_id = table.integer("device_id", _REQUIRED, 1, 247)
    encoding = table.choice("encoding", "adc", ENCODINGS)
    n = table.integer("channels", _REQUIRED, 1, MAX_CHANNELS)
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
    entries: dict[int, tuple[_Table, dict[str, float]]] = {}
    entry_paths: dict[int, str] = {}
    for cpath, item in table.tables("channel", "[[bus.device.channel]]"):
        entry = _Table(ctx, item, cpath, _CHANNEL_KEYS)
        index = entry.integer("index", _REQUIRED, 0, n - 1, f" (channels = {n})")
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


def _check_unique_names(ctx: _Context, buses: Sequence[BusConfig]) -> None:
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


# ------------------------------------------------------------------ the reads of one poll
#: The device clock (input registers 2-5, uint64 ms; docs/register-map.md).
DEVICE_TIME_ADDRESS = 2
DEVICE_TIME_REGISTERS = 4

#: Reads merge across gaps of at most this many registers. The three status bitmaps are 16
#: registers apart and every register between them exists (docs/register-map.md), so the
#: bitmaps of any channel count come in one request. Registers in a wider gap may not exist
#: (a device answers exception 2), so nothing wider is merged; a device that refuses a
#: merged read anyway falls back to unmerged reads.
MERGE_GAP = 15


def plan_with_device_time(plan: tuple[ReadRequest, ...], max_read_registers: int) -> tuple[ReadRequest, ...]:
    """Add the device clock (input registers 2-5, uint64 ms) to a read plan.

    The clock makes the creep time steps right whatever the poll timing (and with a
    simulator running faster than real time). It joins an input read that touches it,
    else it is one more request (registers 7-15 do not exist, so it cannot ride on the
    status read). A device without the clock answers exception 2 and the poller falls
    back to the plan without it (host clock).
    """
    lo, hi = DEVICE_TIME_ADDRESS, DEVICE_TIME_ADDRESS + DEVICE_TIME_REGISTERS - 1
    inputs = [r for r in plan if r.kind == "input"]
    if any(r.address <= lo and r.end >= hi for r in inputs):
        return plan
    for r in inputs:
        start, end = min(r.address, lo), max(r.end, hi)
        if r.address <= hi + 1 and r.end >= lo - 1 and end - start + 1 <= max_read_registers:
            merged = ReadRequest("input", start, end - start + 1, ("device_time", *r.purpose))
            return tuple(merged if q is r else q for q in plan)
    return (ReadRequest("input", lo, DEVICE_TIME_REGISTERS, ("device_time",)), *plan)


def device_plan(
    device: DeviceConfig, max_read_registers: int, merge_gap: int, clock: bool
) -> tuple[ReadRequest, ...]:
    """The reads of one poll: the configuration's ``read_plan`` (coalesced across gaps of
    ``merge_gap`` registers) plus the device clock when ``clock``."""
    plan = tuple(read_plan(device, max_read_registers, max_gap=merge_gap))
    return plan_with_device_time(plan, max_read_registers) if clock else plan


# --------------------------------------------------------------------------- built in code
def _tables_of(value: object) -> dict[str, Any]:
    """A frozen dataclass as the TOML table the parser reads (None addresses as -1)."""
    return {k: (-1 if v is None else v) for k, v in vars(value).items()}


def device_config_for(
    name: str,
    device_id: int,
    params: Sequence[SensorParams],
    columns: int,
    pitch_mm: float,
    *,
    encoding: str = "adc",
    divider: Divider | None = None,
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
        "registers": _tables_of(registers or RegisterMap()),
        "divider": _tables_of(divider or Divider()),
        "model": {"effects": list(effects)},
        "channel": [
            {"index": i, "params": {k: v for k, v in vars(p).items() if v != defaults[k]}}
            for i, p in enumerate(params)
        ],
    }
    return _parse_device(_Context(None), f"device {name!r}", table)


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
    max_read_registers: int = 125,
    backoff_initial_s: float = 0.1,
    backoff_max_s: float = 2.0,
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
    if kind == "rtu":
        table.update(serial_port=serial_port, baudrate=baudrate, parity="N", stopbits=1, bytesize=8)
    else:
        table.update(host=host, port=port)
    if tls is not None:
        table["tls"] = {
            k: (str(v) if isinstance(v, Path) else v) for k, v in vars(tls).items() if v is not None
        }
    return _parse_bus(
        _Context(None), f"bus {name!r}", {k: v for k, v in table.items() if v is not None}, devices
    )


def gateway_config_for(
    buses: Sequence[BusConfig], host: str = "127.0.0.1", port: int = DEFAULT_METRICS_PORT
) -> GatewayConfig:
    """A configuration of already built buses, metrics on ``host:port``."""
    ctx = _Context(None)
    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    metrics = _parse_metrics(ctx, _Table(ctx, {"metrics": {"address": address}}, "", _ROOT_KEYS))
    _check_unique_names(ctx, buses)
    return GatewayConfig(metrics=metrics, buses=tuple(buses), source=None)
