"""The hand read by configuration alone on the in-process virtual bus, its 17 regions laid
out in the device's memory differently from the profile (blocks in another order, each value
in the first of two registers): every taxel's value lands in its own channel, the frame takes
the hand-counted number of requests, and special codes and dead taxels show as statuses (a
taxel stuck at a saturation code while its region moves is dead too)."""

from __future__ import annotations

import math
import random

import numpy as np

from gateway.config import parse_config
from gateway.config.regions import Region
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus

HEAD = """
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = 6000
timeout_s = 0.2
retries = 0

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
address_unit = "register"
value_stride = 2
dead_after_s = 1.0

[bus.device.frame]
quantity = "force"
unit = "mN"
"""


def relaid(regions: tuple[Region, ...]) -> tuple[str, dict[str, int]]:
    """The profile's regions at new register addresses: the blocks in reverse order from
    register 8000, each value in the first of two registers; returns the TOML and where each
    region now starts."""
    text, starts, address = "", {}, 8000
    for r in reversed(regions):
        starts[r.name] = address
        text += (
            f'[[bus.device.region]]\nname = "{r.name}"\ngroup = "{r.group}"\naddress = {address}\n'
            f"rows = {r.rows}\ncolumns = {r.columns}\nx_mm = {r.x_mm}\ny_mm = {r.y_mm}\n"
            f"rotation_deg = {r.rotation_deg}\npitch_mm = {r.pitch_x_mm}\n"
        )
        address += 2 * r.n_channels
    return text, starts


async def test_all_17_regions_read_from_the_configuration_alone() -> None:
    profile = parse_config(HEAD.replace("address_unit", "# address_unit").replace("value_stride", "# v"))
    regions = profile.buses[0].devices[0].regions
    text, starts = relaid(regions)
    cfg = parse_config(HEAD + text)
    dev = cfg.buses[0].devices[0]
    assert [r.name for r in dev.regions] == [r.name for r in reversed(regions)]
    # 2,124 registers from 8000, 63 values a read: ceil(1062 / 63) = 17 requests
    device = VirtualDevice()
    expected = np.empty(dev.n_channels)
    for r in dev.regions:
        for k in range(r.n_channels):
            value = 1 + (r.first_channel + k) * 61 % 65000  # distinct, all below the codes
            device.holding[starts[r.name] + 2 * k] = value
            device.holding[starts[r.name] + 2 * k + 1] = 0xEEEE  # the unused register of two
            expected[r.first_channel + k] = value / 1000.0
    vt = VirtualTransport("hand", {1: device}, timeout_s=0.2)
    now = [100.0]
    poller = Poller(cfg, transport_factory=lambda _bus: vt, rng=random.Random(1), monotonic=lambda: now[0])
    await poller.workers[0].poll_cycle()
    snap = poller.snapshot().devices["hand"]
    assert snap.up, snap.error
    np.testing.assert_allclose(snap.force_n, expected, rtol=1e-12, atol=0.0)
    reads = [r for r in vt.requests if r[0] == "holding"]
    assert len(reads) == math.ceil(1062 / 63) == 17
    # the palm's channel called palm-r0c0 is where the palm's first value went
    palm = next(r for r in dev.regions if r.name == "palm")
    assert snap.channel_names[palm.first_channel] == "palm-r0c0"


async def test_saturation_and_a_dead_taxel_of_the_hand_show_as_statuses() -> None:
    profile = parse_config(HEAD.replace("address_unit", "# address_unit").replace("value_stride", "# v"))
    text, starts = relaid(profile.buses[0].devices[0].regions)
    cfg = parse_config(HEAD + text)
    dev = cfg.buses[0].devices[0]
    tip = next(r for r in dev.regions if r.name == "index-tip")
    device = VirtualDevice()
    for r in dev.regions:
        for k in range(r.n_channels):
            device.holding[starts[r.name] + 2 * k] = 100
            device.holding[starts[r.name] + 2 * k + 1] = 0
    vt = VirtualTransport("hand", {1: device}, timeout_s=0.2)
    now = [100.0]
    poller = Poller(cfg, transport_factory=lambda _bus: vt, rng=random.Random(1), monotonic=lambda: now[0])
    base = starts["index-tip"]
    for k in range(15):
        now[0] = 100.0 + 0.1 * k
        for j in range(9):  # the index tip's taxels move, but taxel 4 (its centre) stays put
            device.holding[base + 2 * j] = 100 + (j + k) % 3
        device.holding[base + 2 * 4] = 777
        device.holding[base + 2 * 8] = 65280  # a saturation code
        await poller.workers[0].poll_cycle()
        snap = poller.snapshot().devices["hand"]
        centre = tip.first_channel + 4
        rail = tip.first_channel + 8
        assert np.isnan(snap.force_n[rail])  # a code, never a force
        if k < 10:  # frozen since poll 0: dead at poll 10, 1.0 s on
            assert snap.status[centre] != ChannelStatus.ERROR, k
            assert snap.status[rail] == ChannelStatus.SATURATED, k
    # the frozen centre and the taxel stuck at the saturation code are both dead
    assert snap.status[centre] == ChannelStatus.ERROR and np.isnan(snap.force_n[centre])
    assert snap.status[rail] == ChannelStatus.ERROR
    assert dict(snap.dead_by_region)["index-tip"] == 2
    assert sum(n for _, n in snap.dead_by_region) == 2
