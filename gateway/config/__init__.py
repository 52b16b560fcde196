"""The gateway configuration: TOML validated into frozen dataclasses.

* ``schema``: the dataclasses (``GatewayConfig``, ``BusConfig``, ``DeviceConfig``,
  ``ChannelConfig``, ``MetricsConfig``, ``TlsConfig``);
* ``tables``: typed TOML-table getters whose errors name the file, key path and allowed range;
* ``parser``: ``load_config`` / ``parse_config`` (and calibration files);
* ``builders``: the same checks for configurations built in code;
* ``editor``: the comment-keeping editor behind ``tactile-gateway channels``.

Every key is documented in ``docs/configuration.md``.
"""

from .builders import bus_config_for, device_config_for, gateway_config_for
from .parser import load_config, parse_config
from .schema import (
    BUS_KINDS,
    NETWORK_KINDS,
    STANDARD_BAUDRATES,
    BusConfig,
    BusKind,
    ChannelConfig,
    DeviceConfig,
    Encoding,
    GatewayConfig,
    MetricsConfig,
    RegisterMap,
    SerialClient,
    TlsConfig,
)

__all__ = [
    "BUS_KINDS",
    "NETWORK_KINDS",
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
    "bus_config_for",
    "device_config_for",
    "gateway_config_for",
    "load_config",
    "parse_config",
]
