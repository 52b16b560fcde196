"""Raw samples of one device, for ``tactile-gateway tare``: the registers of the read plan,
decoded (counts or resistances), not converted to force.

The device's checks and set-up writes run first (``identity.prepare_device``), so a tare is
never taken from a device that is not the one the configuration describes, or in another mode.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from ..config import BusConfig, DeviceConfig
from ..modbus.backends import open_transport
from ..modbus.image import RawSample, RegisterImage, RegisterSpace, decode_sample
from ..modbus.plan import MERGE_GAP, device_plan
from ..modbus.transport import Transport
from .identity import prepare_device

__all__ = ["sample_device"]


async def sample_device(
    bus: BusConfig,
    device: DeviceConfig,
    duration_s: float,
    *,
    transport_factory: Callable[[BusConfig], Transport] = open_transport,
) -> list[tuple[float, RawSample]]:
    """Poll ``device`` every ``bus.poll_interval_s`` for ``duration_s`` seconds: (host
    monotonic time, sample) pairs. Raises the transport's ``DeviceError`` on any failure
    (a tare from a device that drops answers is not one to trust)."""
    plan = device_plan(device, bus.max_read_registers, MERGE_GAP, clock=False)
    samples: list[tuple[float, RawSample]] = []
    async with transport_factory(bus) as transport:
        await prepare_device(transport, device)
        start = time.monotonic()
        next_poll = start
        while True:
            reads: list[tuple[RegisterSpace, int, list[int]]] = []
            for req in plan:
                reads.append((req.kind, req.address, await transport.read(device.device_id, req)))
            now = time.monotonic()
            samples.append((now, decode_sample(device, RegisterImage.from_reads(reads))))
            if now - start >= duration_s:
                return samples
            next_poll += bus.poll_interval_s
            await asyncio.sleep(max(0.0, next_poll - time.monotonic()))
