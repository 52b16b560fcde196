"""The gateway against our hand simulator (``sim_device``) over Modbus TCP on an ephemeral
loopback port, the simulator started with another register layout than the profile's
(public numbers read as registers, one register per taxel, every block shifted by 11): the
configuration alone (17 regions written out) reads every region, each region's frozen taxel
lands in its own named channel, a taxel stuck at the saturation code reads ``saturated``,
and every frozen taxel is found dead within ``dead_after_s`` (a simulated clock shared by
the simulator and the gateway)."""

from __future__ import annotations

import random

import numpy as np
from waiting import ManualClock

from gateway.config import parse_config
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus
from sim_device.hand import FRAME_PERIOD_S, HandDevice
from sim_device.hand_map import Layout
from sim_device.hand_scenarios import parse_taxel_specs
from sim_device.hand_server import serve_hand_tcp

OFFSET = 11
DEAD_AFTER_S = 1.5
#: The 17 regions as a user writes them from the public facts: the block starts (bytes in the
#: documents, registers in this unit) and each sub-grid in turn inside its block.
BLOCKS = {
    "little": (3000, (("tip", 3, 3), ("nail", 12, 8), ("pad", 10, 8))),
    "ring": (3370, (("tip", 3, 3), ("nail", 12, 8), ("pad", 10, 8))),
    "middle": (3740, (("tip", 3, 3), ("nail", 12, 8), ("pad", 10, 8))),
    "index": (4110, (("tip", 3, 3), ("nail", 12, 8), ("pad", 10, 8))),
    "thumb": (4480, (("tip", 3, 3), ("nail", 12, 8), ("middle", 3, 3), ("pad", 12, 8))),
    "palm": (4900, (("", 14, 8),)),
}


def configuration(port: int) -> str:
    text = f"""
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = {port}
timeout_s = 2.0
retries = 0

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
address_unit = "register"
value_stride = 1
dead_after_s = {DEAD_AFTER_S}
"""
    x_mm = 0.0
    for group, (start, parts) in BLOCKS.items():
        address = start + OFFSET
        for part, rows, columns in parts:
            name = f"{group}-{part}" if part else group
            text += (
                f'[[bus.device.region]]\nname = "{name}"\ngroup = "{group}"\naddress = {address}\n'
                f"rows = {rows}\ncolumns = {columns}\nx_mm = {x_mm}\ny_mm = 0.0\n"
            )
            address += rows * columns
            x_mm += 2.5 * columns + 5.0
    return text


def frozen_taxels() -> dict[str, tuple[int, int]]:
    """One frozen taxel per region (its index in the region, row-major) and its raw value."""
    out = {}
    for i, (group, (_, parts)) in enumerate(BLOCKS.items()):
        for j, (part, rows, columns) in enumerate(parts):
            name = f"{group}-{part}" if part else group
            out[name] = ((i + 2 * j) % (rows * columns), 1000 + 37 * (4 * i + j))
    return out


async def test_the_hand_read_from_the_configuration_alone() -> None:
    frozen = frozen_taxels()
    specs = ",".join(f"{name}:{k}={value}" for name, (k, value) in frozen.items())
    clock = ManualClock()
    hand = HandDevice(
        "idle",
        layout=Layout("register", OFFSET),
        clock=clock,
        noise_lsb=3.0,
        frozen=parse_taxel_specs(specs, "frozen", allow_value=True),
        stuck=parse_taxel_specs("palm:50", "stuck"),
    )
    clock.advance(1.0)
    async with serve_hand_tcp(hand) as server:
        cfg = parse_config(configuration(server.port))
        dev = cfg.buses[0].devices[0]
        assert (dev.n_channels, len(dev.regions)) == (1062, 17)
        poller = Poller(cfg, rng=random.Random(1), monotonic=clock)
        worker = poller.workers[0]
        try:
            await worker.poll_cycle()
            first = poller.snapshot().devices["hand"]
            assert first.up, first.error
            names = list(first.channel_names)
            for region in dev.regions:
                k, value = frozen[region.name]
                row, col = divmod(k, region.columns)
                channel = names.index(f"{region.name}-r{row}c{col}")
                # a ratio front end reads r / R_ref = 65535 / code - 1
                assert first.resistance_ohm[channel] == 65535 / value - 1, region.name
            stuck = names.index("palm-r6c2")  # taxel 50 of 8 columns
            assert first.status[stuck] == ChannelStatus.SATURATED
            assert np.isnan(first.force_n[stuck])
            found_at_s = None
            for step in range(1, 120):  # 4 s of 30 Hz frames
                clock.advance(FRAME_PERIOD_S)
                await worker.poll_cycle()
                snap = poller.snapshot().devices["hand"]
                dead = dict(snap.dead_by_region)
                if all(dead[name] >= 1 for name in frozen) and found_at_s is None:
                    found_at_s = step * FRAME_PERIOD_S
                    break
            assert found_at_s is not None, dict(snap.dead_by_region)
            # frozen from the first poll: found at the first poll dead_after_s on, not later
            assert DEAD_AFTER_S <= found_at_s <= DEAD_AFTER_S + 2 * FRAME_PERIOD_S
            # the stuck palm taxel is dead too (at its rail while the palm moves), and no other
            assert sum(dead.values()) == len(frozen) + 1
            assert snap.status[stuck] == ChannelStatus.ERROR
        finally:
            await worker.close()
