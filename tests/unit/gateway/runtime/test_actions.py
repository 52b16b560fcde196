"""A device action run from the command line (``action``, ``tare --device-zero``) makes the
configured set-up writes first, as the gateway does at every connect (issue 33 §16: a mask the
configuration sets to 0 stayed at the device's 20 when the device zeroed itself)."""

from __future__ import annotations

import asyncio

import pytest

from gateway.config import parse_config
from gateway.errors import DeviceError
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.actions import run_action

CONFIG = """
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = 502
timeout_s = 0.2
retries = 0

[[bus.device]]
name = "arr"
device_id = 1
channels = 4
columns = 2
pitch_mm = 2.5
encoding = "float32"
[bus.device.registers]
float_address = 100

[[bus.device.setup]]
what = "mask: every channel on"
address = 7
value = 0

[bus.device.actions]
zero = [{ what = "dynamic zero", address = 3, value = 1, verify = false }]
"""


def test_the_set_up_writes_come_before_the_actions_and_hold_on_the_device() -> None:
    config = parse_config(CONFIG)
    bus = config.buses[0]
    device = bus.devices[0]
    board = VirtualDevice()
    board.set_holding(7, [20])  # the device's own mask, not the configuration's
    board.set_holding(3, [0])
    vt = VirtualTransport("line", {1: board}, timeout_s=0.2)
    done = asyncio.run(run_action(bus, device, "zero", transport_factory=lambda _bus: vt))
    assert done[0].describe().startswith("mask: every channel on")
    # function, address, values: the mask first, then the zero
    assert [(address, values) for _, address, values in vt.writes] == [(7, (0,)), (3, (1,))]
    assert board.holding[7] == 0


def test_an_action_that_the_set_up_cannot_prepare_writes_nothing_of_itself() -> None:
    config = parse_config(CONFIG)
    bus = config.buses[0]
    device = bus.devices[0]
    vt = VirtualTransport("line", {1: VirtualDevice()}, timeout_s=0.2)
    vt.fail_next("timeout", 10)
    with pytest.raises(DeviceError):
        asyncio.run(run_action(bus, device, "zero", transport_factory=lambda _bus: vt))
    assert all(address != 3 for _, address, _ in vt.writes)
