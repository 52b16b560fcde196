"""The configuration schema: frozen dataclasses a validated configuration is made of.

A ``GatewayConfig`` holds the metrics endpoint and the buses; a ``BusConfig`` one Modbus
connection (TCP, RTU, RTU over TCP, Modbus/TCP over TLS) and its devices; a ``DeviceConfig``
one tactile array with its register map (``gateway.modbus.register_map.RegisterMap``), its
divider (eq. 18) and its channels; a ``ChannelConfig`` one sensor with its position (mm), its
effects and its resolved ``SensorParams``. ``parser.parse_config`` builds them from TOML and
``builders`` from code; every key is documented in ``docs/configuration.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

from ..modbus.register_map import RegisterMap
from ..model import Divider, SensorParams

__all__ = [
    "BUS_KINDS",
    "DEFAULT_METRICS_HOST",
    "DEFAULT_METRICS_PORT",
    "MAX_CHANNELS",
    "MAX_PITCH_MM",
    "MAX_POSITION_MM",
    "NETWORK_KINDS",
    "PARITIES",
    "STANDARD_BAUDRATES",
    "BusConfig",
    "ChannelConfig",
    "DeviceConfig",
    "GatewayConfig",
    "MetricsConfig",
    "RegisterMap",
    "TlsConfig",
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
PARITIES: Final = ("N", "E", "O")
MAX_CHANNELS: Final = 256
#: Channel positions must lie within this many millimetres of the origin.
MAX_POSITION_MM: Final = 10_000.0
MAX_PITCH_MM: Final = 1_000.0
DEFAULT_METRICS_HOST: Final = "127.0.0.1"
DEFAULT_METRICS_PORT: Final = 9830


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
