"""A zero taken while the hand's palm is loaded (issue 34, done-when): our hand simulator
(``sim_device.hand``, scenario ``palm-held``: 0.5 N on each palm taxel from long before the
start, every other taxel idle) with a skin whose taxels each read their own offset at rest
(``rest_offset_lsb``: uniform in 0..600 LSB, comparable to the palm's load of about 490) and
2 LSB of noise, served over loopback Modbus TCP in this process with another register layout
than the profile's (``test_hand_gateway.configuration``: the 17 regions written out).

The gateway reads the simulator's own circuit (a transimpedance stage, 1 kohm into a 16-bit
converter: ``docs/register-map-hand.md``), so the paper's model reads newtons. Before the zero
the idle taxels' offsets read as forces; ``tactile-gateway tare --moving-load`` (a real
process) zeroes each idle taxel at its own rest, names the palm as loaded throughout as a
region and leaves it unzeroed; afterwards no idle taxel reads any force, and the palm reads
what it read before (its load was not zeroed away)."""

from __future__ import annotations

import random
import re
from pathlib import Path

import numpy as np
import pytest
from test_hand_gateway import OFFSET, configuration
from test_tare_moving_load_sim import run_tare

from gateway.config import load_config
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot
from sim_device.hand import HandDevice
from sim_device.hand_map import Layout
from sim_device.hand_server import serve_hand_tcp

pytestmark = pytest.mark.slow

#: The simulator's read-out: raw = 65535 x 1 kohm / r (docs/register-map-hand.md).
FRONT_END = """
[bus.device.front_end]
kind = "transimpedance"
bias_v = 1.0
feedback_ohm = 1000.0
adc_bits = 16
adc_reference_v = 1.0
"""


async def poll_once(path: Path) -> DeviceSnapshot:
    poller = Poller(load_config(path), rng=random.Random(1))
    worker = poller.workers[0]
    try:
        await worker.poll_cycle()
    finally:
        await worker.close()
    snap = poller.snapshot().devices["hand"]
    assert snap.up, snap.error
    return snap


async def test_a_zero_taken_while_the_palm_is_loaded_leaves_no_phantom_force(tmp_path: Path) -> None:
    hand = HandDevice(
        "palm-held", layout=Layout("register", OFFSET), noise_lsb=2.0, rest_offset_lsb=300.0, seed=4
    )
    async with serve_hand_tcp(hand) as server:
        path = tmp_path / "hand.toml"
        path.write_text(configuration(server.port).replace("timeout_s = 2.0", "timeout_s = 5.0") + FRONT_END)
        before = await poll_once(path)
        names = list(before.channel_names)
        palm = np.array([n.startswith("palm-") for n in names])
        idle = ~palm
        assert (palm.sum(), idle.sum()) == (112, 950)
        # without a zero the idle taxels' offsets read as forces (flagged no_zero: kept out of
        # the totals, but a force in every per-taxel output)
        phantom_before = float(np.nansum(before.force_n[idle]))
        assert phantom_before > 50.0, phantom_before
        assert np.count_nonzero(before.status[idle] == ChannelStatus.NO_ZERO) > 300

        code, out, err = await run_tare(path, "--moving-load", "--seconds", "3")
        assert code == 0, (out, err)
        assert "baseline_ohm written for 950 of 1062 channels" in out, out
        refused = re.findall(r"^not zeroed: (\S+) \((.*)\)$", out, re.M)
        assert sorted(name for name, _ in refused) == sorted(n for n in names if n.startswith("palm-")), (
            refused
        )
        assert all("with its region: region palm's least loaded tenth conducts" in why for _, why in refused)

        after = await poll_once(path)
    assert list(after.channel_names) == names
    # no phantom force: every idle taxel reads no contact, 0 N
    assert np.all(after.status[idle] == ChannelStatus.NO_CONTACT), np.unique(after.status[idle])
    assert float(np.nansum(after.force_n[idle])) == 0.0
    # the palm was not zeroed away: it reads its load as before, unzeroed (no_zero)
    assert np.all(after.status[palm] == ChannelStatus.NO_ZERO)
    assert np.allclose(after.force_n[palm], before.force_n[palm], rtol=0.05, atol=0.02)
    assert float(np.median(after.force_n[palm])) > 0.4
    channels = load_config(path).buses[0].devices[0].channels
    assert all((ch.baseline_ohm is None) == ch.name.startswith("palm-") for ch in channels)
