"""Verifying at connect that a device is the one its configuration describes.

A configuration (or its profile) may name checks (``DeviceChecks``): registers with a fixed
value (a product id, the channel count) and FC 43/14 identification objects. They are read
once per connection, before the device is polled; a device that answers differently is not
polled and its snapshot says why (``DeviceMismatchError``), so forces are never computed
with a register map, front end or channel count that belongs to another device. Then the
configuration's set-up writes are made (``prepare_device``), each read back where allowed.
"""

from __future__ import annotations

from typing import Final

from ..config import DeviceConfig
from ..errors import DeviceMismatchError
from ..modbus.transport import Transport
from .writes import run_writes

__all__ = ["IDENTIFICATION_OBJECTS", "needs_preparing", "prepare_device", "verify_device"]

#: Configuration keys of the FC 43/14 objects and the names the transport reports them by.
IDENTIFICATION_OBJECTS: Final = {
    "vendor_name": "VendorName",
    "product_code": "ProductCode",
    "revision": "MajorMinorRevision",
    "product_name": "ProductName",
    "model_name": "ModelName",
}


def _source(device: DeviceConfig) -> str:
    return f" ({device.profile})" if device.profile else ""


async def verify_device(transport: Transport, device: DeviceConfig) -> None:
    """Read the device's checks; ``DeviceMismatchError`` names the first that fails.
    Transport errors (timeouts, exception responses) propagate as they are."""
    for check in device.checks.registers:
        values = await transport.read_registers(device.device_id, check.table, check.address, 1)
        value = int(values[0])
        if value != check.value:
            raise DeviceMismatchError(
                f"not the configured device: its {check.what} ({check.table} register {check.address}) reads "
                f"{value} (0x{value:04X}), the configuration{_source(device)} expects {check.value} "
                f"(0x{check.value:04X}); not polled until it matches"
            )
    if device.checks.identification:
        info = await transport.read_device_identification(device.device_id)
        for key, expected in device.checks.identification:
            actual = info.get(IDENTIFICATION_OBJECTS[key])
            if actual != expected:
                shown = "nothing" if actual is None else repr(actual)
                raise DeviceMismatchError(
                    f"not the configured device: its identification {key} is {shown}, the "
                    f"configuration{_source(device)} expects {expected!r}; not polled until it matches"
                )


def needs_preparing(device: DeviceConfig) -> bool:
    """Whether anything is read or written at connect (checks or set-up writes)."""
    return bool(device.checks) or bool(device.registers.setup)


async def prepare_device(transport: Transport, device: DeviceConfig) -> None:
    """``verify_device``, then the set-up writes of the configuration, in order."""
    await verify_device(transport, device)
    await run_writes(transport, device.device_id, device.registers.setup)
