"""One read of a poll's plan and the writes a configuration names, on a ``Transport``.

The one place that turns a ``plan.ReadRequest`` into a transport call: function 4 or 3, a
vendor-defined read (``vendor_fc.VendorRead``), or a read behind a row select (the row's
number is written to the select register first). ``run_writes`` makes a list of
configured writes (``register_map.DeviceWrite``: set-up at connect, or a named action) and
reads each back where the configuration says the register allows it. Nothing else is
ever written.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..errors import DeviceMismatchError
from ..modbus.plan import ReadRequest
from ..modbus.register_map import DeviceWrite
from ..modbus.transport import Transport

__all__ = ["read_request", "run_writes"]


async def read_request(transport: Transport, device_id: int, request: ReadRequest) -> list[int]:
    """The registers (16-bit words) one request of a read plan answers."""
    if request.vendor is not None:
        return await transport.read_vendor(device_id, request.vendor, request.address, request.count)
    if request.select is not None:
        select_address, row = request.select
        await transport.write_register(device_id, select_address, row, allow_write=True)
    if request.table == "input":
        return await transport.read_input_registers(device_id, request.address, request.count)
    return await transport.read_holding_registers(device_id, request.address, request.count)


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
