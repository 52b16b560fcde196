"""Running a device's named action (``[bus.device.actions]``: a device zero, its undo, a mode
switch) once, from the command line: connect, verify the device is the configured one, make its
set-up writes as the gateway does at every connect (``[[bus.device.setup]]``: an action such as
a device zero works on the device as configured, not as it was left), then the action's writes,
each read back where the configuration allows."""

from __future__ import annotations

from collections.abc import Callable

from ..config import BusConfig, DeviceConfig
from ..errors import ConfigError
from ..modbus.backends import open_transport
from ..modbus.register_map import DeviceWrite
from ..modbus.transport import Transport
from .identity import prepare_device
from .writes import run_writes

__all__ = ["action_writes", "run_action"]


def action_writes(device: DeviceConfig, name: str) -> tuple[DeviceWrite, ...]:
    """The writes of ``device``'s action ``name``; ``ConfigError`` lists the actions it has."""
    actions = dict(device.registers.actions)
    if name not in actions:
        have = ", ".join(actions) if actions else "none"
        raise ConfigError(
            f"device {device.name!r} has no action {name!r} (its actions: {have}); "
            "name them in [bus.device.actions], docs/configuration.md"
        )
    return actions[name]


async def run_action(
    bus: BusConfig,
    device: DeviceConfig,
    name: str,
    *,
    transport_factory: Callable[[BusConfig], Transport] = open_transport,
) -> tuple[DeviceWrite, ...]:
    """Make the set-up writes, then the action's, on the device; returns them in that order.
    Raises ``ConfigError`` for an unknown action and the transport's ``DeviceError`` on any
    failure (nothing of the action is written after a set-up write failed)."""
    writes = action_writes(device, name)
    async with transport_factory(bus) as transport:
        await prepare_device(transport, device)
        await run_writes(transport, device.device_id, writes)
    return (*device.registers.setup, *writes)
