"""What a Modbus client needs to know of a bus: where it is and how to talk to it.

Protocols, so that the Modbus layer stays free of the configuration: a
``gateway.config.BusConfig`` (and its ``TlsConfig``) satisfies them as they are.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from ..keys import Choice

__all__ = ["BusKind", "Endpoint", "SerialClient", "TlsSettings"]


class BusKind(Choice):
    """How a bus frames Modbus: TCP (MBAP header), RTU on a serial line, RTU frames over a TCP
    socket, or Modbus/TCP over TLS."""

    TCP = "tcp"
    RTU = "rtu"
    RTU_OVER_TCP = "rtu-over-tcp"
    TLS = "tls"

    @property
    def is_network(self) -> bool:
        """Reached over the network (host and port), not a serial line."""
        return self is not BusKind.RTU


class SerialClient(Choice):
    """Who frames Modbus RTU on a serial line: pymodbus' client, or the gateway's own direct
    framing (``rtu_line``) for lines polled thousands of times a second."""

    PYMODBUS = "pymodbus"
    DIRECT = "direct"


class TlsSettings(Protocol):
    """Modbus/TCP Security: CA certificates, client certificate and key, server identity."""

    @property
    def ca_file(self) -> Path | None: ...

    @property
    def cert_file(self) -> Path | None: ...

    @property
    def key_file(self) -> Path | None: ...

    @property
    def server_hostname(self) -> str | None: ...

    @property
    def verify(self) -> bool: ...


class Endpoint(Protocol):
    """One Modbus connection: ``kind`` is tcp, rtu, rtu-over-tcp or tls; serial settings are
    used by rtu, host and port by the others; ``timeout_s`` bounds one request (s)."""

    @property
    def name(self) -> str: ...

    @property
    def kind(self) -> BusKind: ...

    @property
    def host(self) -> str | None: ...

    @property
    def port(self) -> int | None: ...

    @property
    def serial_port(self) -> str | None: ...

    @property
    def baudrate(self) -> int: ...

    @property
    def parity(self) -> str: ...

    @property
    def stopbits(self) -> int: ...

    @property
    def bytesize(self) -> int: ...

    @property
    def tls(self) -> TlsSettings | None: ...

    @property
    def serial_client(self) -> SerialClient:
        """Who frames RTU on a serial line (``rtu_line`` when direct)."""
        ...

    @property
    def timeout_s(self) -> float: ...
