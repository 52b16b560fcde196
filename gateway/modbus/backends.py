"""Which transport backend serves a bus: the one place that chooses.

``open_transport(bus)``: the pymodbus client (``client.ModbusTransport``) for every bus kind,
unless a ``kind = "rtu"`` bus sets ``serial_client = "direct"``: then the gateway's own RTU
framing on the port (``rtu_line.RtuLineTransport``), for lines polled thousands of times a
second.
"""

from __future__ import annotations

from .client import ModbusTransport
from .endpoint import BusKind, Endpoint, SerialClient
from .rtu_line import RtuLineTransport
from .transport import Transport

__all__ = ["open_transport"]


def open_transport(bus: Endpoint) -> Transport:
    """The transport of ``bus`` (not yet connected)."""
    if bus.kind is BusKind.RTU and bus.serial_client is SerialClient.DIRECT:
        return RtuLineTransport(bus)
    return ModbusTransport(bus)
