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

from ..errors import ConfigError
from ..modbus.endpoint import BusKind, SerialClient
from ..modbus.register_map import (
    ENCODINGS,
    FRAME_ENCODINGS,
    MAX_READ_REGISTERS,
    DeviceChecks,
    Encoding,
    RegisterMap,
    config_word,
)
from ..modbus.status_word import StatusWord
from ..model import FrontEnd, RatioFrontEnd, SensorParams, UnknownEffectError, parse_effects
from ..model.conversion import Conversion
from ..model.curves import CurveChannel, Drift
from ..model.params import Interval
from .foxglove import FoxgloveConfig
from .layout import GridLayout
from .limits import MAX_CHANNELS, MAX_PITCH_MM, MAX_POSITION_MM, PITCH_MM, POSITION_MM
from .mqtt import MqttConfig
from .regions import Region
from .rois import Roi
from .web import WebSettings

NO_CHECKS: Final = DeviceChecks()
DEFAULT_WEB: Final = WebSettings()

__all__ = [
    "BUS_KINDS",
    "DEFAULT_METRICS_HOST",
    "DEFAULT_METRICS_PORT",
    "MAX_CHANNELS",
    "MAX_PITCH_MM",
    "MAX_POSITION_MM",
    "NETWORK_KINDS",
    "PARITIES",
    "PITCH_MM",
    "POSITION_MM",
    "SERIAL_CLIENTS",
    "STANDARD_BAUDRATES",
    "BusConfig",
    "BusKind",
    "ChannelConfig",
    "DeviceConfig",
    "Encoding",
    "GatewayConfig",
    "MetricsConfig",
    "RegisterMap",
    "SerialClient",
    "TlsConfig",
]

BUS_KINDS: Final = tuple(BusKind)
#: Bus kinds that reach the device over the network (host and port).
NETWORK_KINDS: Final = tuple(k for k in BusKind if k.is_network)
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
    1000000,
    1500000,
    2000000,
    3000000,
    4000000,
)
PARITIES: Final = ("N", "E", "O")
#: Who frames Modbus RTU on a serial line (``SerialClient``).
SERIAL_CLIENTS: Final = tuple(SerialClient)

# The allowed values of the fields, shared by the dataclasses' own checks and the parser.
DEVICE_ID: Final = (1, 247)
PORT: Final = (1, 65535)
RETRIES: Final = (0, 10)
STOPBITS: Final = (1, 2)
BYTESIZE: Final = (7, 8)
TIMEOUT_S: Final = Interval(0.0, 60.0, low_inclusive=False)
#: 0 polls back to back: the next poll starts as soon as the last answer is in
POLL_INTERVAL_S: Final = Interval(0.0, 3600.0, low_inclusive=True)
BACKOFF_INITIAL_S: Final = Interval(0.0, 60.0, low_inclusive=False)
BACKOFF_MAX_S: Final = 3600.0
DEAD_AFTER_S: Final = Interval(0.0, 86400.0, low_inclusive=True)
#: What a converter rail means on a device (``DeviceConfig.rails``).
RAILS: Final = ("faults", "readings")


def check_integer(where: str, name: str, value: object, low: int, high: int, unit: str = "") -> None:
    """``ConfigError`` unless ``value`` is an integer in ``low..high``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where}: {name}: expected an integer in {low}..{high}{unit}, got {value!r}")
    if not low <= value <= high:
        raise ConfigError(f"{where}: {name}: {value} is out of range; allowed: {low}..{high}{unit}")


def check_number(where: str, name: str, value: object, interval: Interval, unit: str = "") -> None:
    """``ConfigError`` unless ``value`` is a number inside ``interval``."""
    allowed = f"{interval.describe()}{unit}"
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: {name}: expected a number in {allowed}, got {value!r}")
    if not interval.contains(float(value)):
        raise ConfigError(f"{where}: {name}: {value!r} is out of range; allowed: {allowed}")


def check_choice(where: str, name: str, value: object, choices: tuple[object, ...]) -> None:
    """``ConfigError`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        shown = ", ".join(repr(str(c)) if isinstance(c, str) else str(c) for c in choices)
        raise ConfigError(f"{where}: {name}: {value!r} is not allowed; allowed: {shown}")


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
    page: bool = True  # the live page and its API at / (off: /metrics only)

    def __post_init__(self) -> None:
        if not isinstance(self.page, bool):
            raise ConfigError(f"metrics: page: expected true or false, got {self.page!r}")
        if not isinstance(self.host, str) or not self.host:
            raise ConfigError(f"metrics: host: expected a host name or IP address, got {self.host!r}")
        check_integer("metrics", "port", self.port, *PORT)


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
    #: the resistance this channel reads unloaded (ohm; ``tare``), or None: the model's own
    baseline_ohm: float | None = None
    #: a calibration's line or lookup that reads force instead of the physical model, or None
    conversion: Conversion | None = None
    #: the force range the channel was calibrated on (N; the calibration file's
    #: ``calibrated_min_n``/``calibrated_max_n``), or None: a force the channel reads outside
    #: it is flagged ``extrapolated``
    calibrated_range_n: tuple[float, float] | None = None
    #: where the parameters came from, most specific last: ``defaults``, ``config``
    #: (the device's model.params), ``calibration`` (the file), ``channel`` (its own entry)
    params_source: tuple[str, ...] = ("defaults",)

    def __post_init__(self) -> None:
        where = f"channel {self.name!r}"
        if self.baseline_ohm is not None and not (
            isinstance(self.baseline_ohm, float | int) and 0.0 < self.baseline_ohm <= float("inf")
        ):
            raise ConfigError(
                f"{where}: baseline_ohm: {self.baseline_ohm!r} is out of range; allowed: (0, inf] ohm"
            )
        check_integer(where, "index", self.index, 0, MAX_CHANNELS - 1)
        check_number(where, "x_mm", self.x_mm, POSITION_MM, " mm")
        check_number(where, "y_mm", self.y_mm, POSITION_MM, " mm")
        try:
            canonical = parse_effects(self.effects)
        except UnknownEffectError as exc:
            raise ConfigError(f"{where}: effects: {exc}") from None
        if tuple(self.effects) != canonical:
            raise ConfigError(f"{where}: effects: {self.effects!r} must be in canonical order: {canonical!r}")
        if not isinstance(self.params, SensorParams):
            raise ConfigError(f"{where}: params: expected SensorParams, got {type(self.params).__name__}")
        if self.calibrated_range_n is not None:
            low, high = self.calibrated_range_n
            if not (0.0 <= low < high <= float("inf")):
                raise ConfigError(
                    f"{where}: calibrated_range_n: {self.calibrated_range_n!r} is out of range; "
                    "allowed: 0 <= low < high <= inf N"
                )
        if self.conversion is not None and not isinstance(self.conversion, CurveChannel):
            raise ConfigError(
                f"{where}: conversion: expected None or a CurveChannel, got {type(self.conversion).__name__}"
            )


@dataclass(frozen=True)
class DeviceConfig:
    """One sensor array on a bus; ``channels`` holds all ``n_channels`` channels in index order.

    ``registers`` is what is read and written (nothing else is), ``checks`` what is verified at connect,
    ``front_end`` the read-out circuit that turns ADC counts into ohm, ``layout`` where the
    channels sit, ``profile`` the profile the settings came from (for messages).
    """

    name: str
    device_id: int
    encoding: Encoding
    n_channels: int
    registers: RegisterMap
    front_end: FrontEnd
    channels: tuple[ChannelConfig, ...]
    allow_write: bool
    layout: GridLayout
    calibration: Path | None
    checks: DeviceChecks = NO_CHECKS
    profile: str | None = None
    #: drift correction on top of the device's own force or pressure output (None: passed through)
    output_drift: Drift | None = None
    #: the named sub-grids the channels come from, in channel order (``regions.Region``);
    #: () for a device whose channels are the one grid of ``layout``
    regions: tuple[Region, ...] = ()
    #: named status words read with every poll (``config.status_words``)
    status_words: tuple[StatusWord, ...] = ()
    #: seconds a taxel frozen while its region moves takes to read dead (0: not tracked;
    #: ``runtime.dead_taxels``)
    dead_after_s: float = 0.0
    #: what a converter rail means (``RAILS``): ``faults`` (the open rail an open circuit, the
    #: short rail a short) or ``readings`` (the open rail no current at rest: no contact, 0 N;
    #: the short rail more load than the converter resolves: saturated), for read-outs whose
    #: unloaded taxel reads 0 (a robot hand's raw values); a broken taxel is then found by
    #: ``dead_after_s``
    rails: str = "faults"
    #: regions of interest (``[[bus.device.roi]]``): named channel sets summed every poll
    rois: tuple[Roi, ...] = ()

    def __post_init__(self) -> None:
        where = f"device {self.name!r}"
        check_integer(where, "device_id", self.device_id, *DEVICE_ID)
        check_choice(where, "encoding", self.encoding, ENCODINGS)
        object.__setattr__(self, "encoding", config_word(Encoding, where, "encoding", self.encoding))
        frame = self.registers.frame
        if frame is not None and FRAME_ENCODINGS[frame.quantity] is not self.encoding:
            raise ConfigError(f"{where}: encoding: {self.encoding!r} but the frame carries {frame.quantity}")
        if self.encoding is Encoding.OUTPUT and frame is None:
            raise ConfigError(
                f"{where}: encoding: 'output' (the device's own force or pressure) needs a frame"
            )
        if self.output_drift is not None and self.encoding is not Encoding.OUTPUT:
            raise ConfigError(
                f"{where}: output_drift applies to a device's own force or pressure output only"
            )
        check_integer(where, "channels", self.n_channels, 1, MAX_CHANNELS)
        if not isinstance(self.front_end, FrontEnd):
            raise ConfigError(f"{where}: front_end: expected a FrontEnd, got {type(self.front_end).__name__}")
        if not isinstance(self.layout, GridLayout) or self.layout.n_channels != self.n_channels:
            raise ConfigError(f"{where}: layout: expected a GridLayout of {self.n_channels} channels")
        if not isinstance(self.checks, DeviceChecks):
            raise ConfigError(f"{where}: checks: expected DeviceChecks, got {type(self.checks).__name__}")
        if len(self.channels) != self.n_channels:
            raise ConfigError(
                f"{where}: {len(self.channels)} channel entries for channels = {self.n_channels}"
            )
        names: set[str] = set()
        for i, channel in enumerate(self.channels):
            if channel.index != i:
                raise ConfigError(
                    f"{where}: channel {channel.name!r} has index {channel.index}, expected {i}"
                )
            if channel.name in names:
                raise ConfigError(f"{where}: duplicate channel name {channel.name!r}")
            names.add(channel.name)
        check_number(where, "dead_after_s", self.dead_after_s, DEAD_AFTER_S, " s (0: off)")
        check_choice(where, "rails", self.rails, RAILS)
        first = 0
        for region in self.regions:
            if region.first_channel != first:
                raise ConfigError(
                    f"{where}: region {region.name!r} starts at channel {region.first_channel}, "
                    f"expected {first} (the regions hold the channels in order)"
                )
            first += region.n_channels
        if self.regions and first != self.n_channels:
            raise ConfigError(f"{where}: the regions hold {first} channels for channels = {self.n_channels}")
        roi_names: set[str] = set()
        for roi in self.rois:
            if roi.name in roi_names:
                raise ConfigError(f"{where}: duplicate region of interest {roi.name!r}")
            roi_names.add(roi.name)
            if roi.channels[-1] >= self.n_channels:
                raise ConfigError(
                    f"{where}: region of interest {roi.name!r}: channel {roi.channels[-1]} is out of range; "
                    f"allowed: 0..{self.n_channels - 1}"
                )

    @property
    def columns(self) -> int:
        return self.layout.columns

    @property
    def cell_areas_mm2(self) -> float | tuple[float, ...]:
        """The area of each channel's cell (mm^2): one for the device's one grid, or per channel
        for a device made of regions, each region's pitch x pitch (regions may differ)."""
        if not self.regions:
            return self.layout.cell_area_mm2
        areas: list[float] = []
        for region in self.regions:
            areas.extend([region.pitch_x_mm * region.pitch_y_mm] * region.n_channels)
        return tuple(areas)

    @property
    def pitch_mm(self) -> float:
        """The pitch along x (mm); ``layout`` has both."""
        return self.layout.pitch_x_mm

    def channel(self, name: str) -> ChannelConfig:
        """The channel called ``name`` (``KeyError`` if there is none)."""
        for ch in self.channels:
            if ch.name == name:
                return ch
        raise KeyError(name)

    @property
    def enabled_channels(self) -> tuple[ChannelConfig, ...]:
        return tuple(ch for ch in self.channels if ch.enabled)

    def needs_calibration(self, channel: ChannelConfig) -> bool:
        """Whether ``channel`` has nothing to read a force with: a ``ratio`` front end reads
        r / R_ref of an unknown reference resistor, where the default sensor parameters (ohm)
        mean nothing, and the channel has neither a calibration table nor parameters of its own.
        It reads ``uncalibrated``: its reading, no force (docs/front-ends.md)."""
        return (
            self.encoding is Encoding.ADC
            and isinstance(self.front_end, RatioFrontEnd)
            and channel.conversion is None
            and channel.params_source == ("defaults",)
        )


@dataclass(frozen=True)
class BusConfig:
    """One Modbus connection (a TCP socket or a serial line) and the devices polled over it."""

    name: str
    kind: BusKind
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
    #: who frames RTU on the serial line; only ``kind = "rtu"`` uses it
    serial_client: SerialClient = SerialClient.PYMODBUS

    def __post_init__(self) -> None:
        where = f"bus {self.name!r}"
        check_choice(where, "kind", self.kind, BUS_KINDS)
        check_choice(where, "serial_client", self.serial_client, SERIAL_CLIENTS)
        object.__setattr__(self, "kind", config_word(BusKind, where, "kind", self.kind))
        object.__setattr__(
            self, "serial_client", config_word(SerialClient, where, "serial_client", self.serial_client)
        )
        if self.kind is BusKind.RTU:
            if not isinstance(self.serial_port, str) or not self.serial_port.strip():
                raise ConfigError(f"{where}: serial_port: expected a serial device such as /dev/ttyUSB0")
            check_choice(where, "baudrate", self.baudrate, STANDARD_BAUDRATES)
            check_choice(where, "parity", self.parity, PARITIES)
            check_integer(where, "stopbits", self.stopbits, *STOPBITS)
            check_integer(where, "bytesize", self.bytesize, *BYTESIZE)
        else:
            if not isinstance(self.host, str) or not self.host:
                raise ConfigError(f"{where}: host: expected a host name or IP address, got {self.host!r}")
            check_integer(where, "port", self.port, *PORT)
        if (self.kind is BusKind.TLS) != (self.tls is not None):
            raise ConfigError(f"{where}: tls: kind 'tls' needs TLS settings, and only it uses them")
        check_number(where, "timeout_s", self.timeout_s, TIMEOUT_S, " s")
        check_integer(where, "retries", self.retries, *RETRIES)
        check_number(where, "poll_interval_s", self.poll_interval_s, POLL_INTERVAL_S, " s")
        check_integer(where, "max_read_registers", self.max_read_registers, 1, MAX_READ_REGISTERS)
        check_number(where, "backoff_initial_s", self.backoff_initial_s, BACKOFF_INITIAL_S, " s")
        check_number(
            where,
            "backoff_max_s",
            self.backoff_max_s,
            Interval(float(self.backoff_initial_s), BACKOFF_MAX_S, low_inclusive=True),
            " s (>= backoff_initial_s)",
        )
        if not self.devices:
            raise ConfigError(f"{where}: at least one device is required per bus")
        ids = [d.device_id for d in self.devices]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"{where}: duplicate device_id; allowed: 1..247, unique per bus")

    @property
    def endpoint(self) -> str:
        """``host:port`` (``[v6]:port``) for network buses, the serial port for ``rtu``."""
        if self.kind is BusKind.RTU:
            return self.serial_port or ""
        host = self.host or ""
        return f"[{host}]:{self.port}" if ":" in host else f"{host}:{self.port}"


@dataclass(frozen=True)
class GatewayConfig:
    """The whole file: the metrics endpoint and the buses; ``source`` is the file it came from."""

    metrics: MetricsConfig
    buses: tuple[BusConfig, ...]
    source: Path | None
    mqtt: MqttConfig | None = None  # publishing to a broker: off when None
    foxglove: FoxgloveConfig | None = None  # serving Foxglove's WebSocket protocol: off when None
    web: WebSettings = DEFAULT_WEB  # what the page's server keeps of the past ([web])

    def __post_init__(self) -> None:
        buses = [b.name for b in self.buses]
        devices = [d.name for b in self.buses for d in b.devices]
        if len(set(buses)) != len(buses):
            raise ConfigError("configuration: duplicate bus name; bus names are unique")
        if len(set(devices)) != len(devices):
            raise ConfigError("configuration: duplicate device name; device names are unique across the file")

    def devices(self) -> tuple[tuple[BusConfig, DeviceConfig], ...]:
        """Every (bus, device) pair, in file order."""
        return tuple((bus, dev) for bus in self.buses for dev in bus.devices)

    def find_device(self, name: str) -> tuple[BusConfig, DeviceConfig]:
        """The bus and device called ``name`` (device names are unique in a file)."""
        for bus, dev in self.devices():
            if dev.name == name:
                return bus, dev
        raise KeyError(name)
