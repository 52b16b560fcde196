"""The writes a configuration names, on a ``Transport``: ``run_writes`` makes a list of
configured writes (``register_map.DeviceWrite``: set-up at connect, or a named action) and
reads each back where the configuration says the register allows it. Nothing else is ever
written (a frame's row select is written by ``Transport.read``, from the read plan).
"""

from __future__ import annotations

from collections.abc import Sequence

from ..errors import DeviceMismatchError
from ..modbus.register_map import DeviceWrite
from ..modbus.transport import Transport

__all__ = ["run_writes"]


async def run_writes(transport: Transport, device_id: int, writes: Sequence[DeviceWrite]) -> None:
    """Make ``writes`` in order (each is named by the configuration, so it is allowed); a
    register read back with another value raises ``DeviceMismatchError``."""
    for w in writes:
        if w.function == 6:
            await transport.write_register(device_id, w.address, w.values[0], allow_write=True)
        else:
            await transport.write_registers(device_id, w.address, list(w.values), allow_write=True)
        if not w.verify:
            continue
        back = tuple(await transport.read_holding_registers(device_id, w.address, len(w.values)))
        if back != w.values:
            raise DeviceMismatchError(
                f"{w.what}: wrote {', '.join(map(str, w.values))} to holding {w.address}, read back "
                f"{', '.join(map(str, back))}; the device did not take the set-up (set verify = false "
                "for a register that reads back something else)"
            )
