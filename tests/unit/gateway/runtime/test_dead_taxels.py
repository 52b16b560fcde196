"""Special codes and dead taxels.

A frame's declared special codes read as statuses (saturated, error), never as forces. A
taxel frozen while the rest of its region moves is dead after ``dead_after_s`` (hand-timed on
a simulated clock): status ``error``, left out of the totals and the contact area, counted by
region; it comes back as soon as it moves. Expected forces are the registers in mN / 1000."""

from __future__ import annotations

import random

import numpy as np
import pytest

from gateway.config import GatewayConfig, parse_config
from gateway.errors import ConfigError
from gateway.metrics.exposition import render
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.dead_taxels import DeadTaxelTracker
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot

BUS = """
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = 502
timeout_s = 0.2
retries = 0
backoff_initial_s = 0.1

[[bus.device]]
name = "hand"
device_id = 1
{device}

[bus.device.frame]
quantity = "force"
unit = "mN"
table = "holding"
{frame}

[[bus.device.region]]
name = "tip"
address = 0
rows = 2
columns = 2

[[bus.device.region]]
name = "pad"
address = 10
rows = 1
columns = 3
"""


def config(device: str = "", frame: str = "") -> GatewayConfig:
    return parse_config(BUS.format(device=device, frame=frame))


class Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def poller_for(cfg: GatewayConfig, dev: VirtualDevice) -> tuple[Poller, Clock]:
    vt = VirtualTransport("line", {1: dev}, timeout_s=0.2)
    clock = Clock()
    poller = Poller(
        cfg,
        transport_factory=lambda _bus: vt,
        rng=random.Random(3),
        wall_clock=lambda: 1_700_000_000.0,
        monotonic=clock,
    )
    return poller, clock


async def poll(poller: Poller) -> DeviceSnapshot:
    await poller.workers[0].poll_cycle()
    return poller.snapshot().devices["hand"]


# ------------------------------------------------------------------ special codes
async def test_special_codes_read_as_statuses_never_as_forces() -> None:
    cfg = config(frame="special = { saturated = [65535], error_from = 65280 }")
    dev = VirtualDevice()
    dev.set_holding(0, [1000, 65535, 65280, 65300])  # tip: 1 N, saturated, two error codes
    dev.set_holding(10, [500, 65279, 0])  # pad: 0.5 N, 65.279 N (below the codes), 0
    poller, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    assert snap.up, snap.error
    assert snap.status.tolist() == [
        ChannelStatus.OK,
        ChannelStatus.SATURATED,
        ChannelStatus.ERROR,
        ChannelStatus.ERROR,
        ChannelStatus.OK,
        ChannelStatus.OK,
        ChannelStatus.NO_CONTACT,
    ]
    assert np.isnan(snap.force_n[1:4]).all()
    assert snap.force_n[[0, 4, 5]].tolist() == [1.0, 0.5, 65.279]
    assert snap.total_force_n == pytest.approx(1.0 + 0.5 + 65.279)


def test_special_codes_are_checked_against_the_value_type() -> None:
    with pytest.raises(
        ConfigError, match=r"frame\.special\.saturated\[0\]: 70000 is out of range; allowed: 0\.\.65535"
    ):
        config(frame="special = { saturated = [70000] }")
    with pytest.raises(ConfigError, match=r"frame\.special\.saturate: unknown key; did you mean 'saturated'"):
        config(frame="special = { saturate = [1] }")


# ------------------------------------------------------------------ the tracker alone
def test_a_frozen_taxel_is_dead_after_dead_after_s_while_its_region_moves() -> None:
    # one region of 4; taxel 2 frozen, the others change at every poll; 30 Hz, 2 s
    tracker = DeadTaxelTracker(np.zeros(4, dtype=np.intp), ("r",), dead_after_s=2.0)
    state = tracker.initial_state(4)
    dt = 1.0 / 30.0
    flagged_at = None
    for k in range(90):
        values = np.array([k, 2 * k, 7, 3 * k], dtype=np.float64)
        state, dead = tracker.update(state, values, 100.0 + k * dt)
        if dead.any() and flagged_at is None:
            flagged_at = k
            assert dead.tolist() == [False, False, True, False]
    # frozen since poll 0: dead at the first poll at least 2 s later, 60 polls of 1/30 s
    assert flagged_at == 60
    assert tracker.counts(dead) == {"r": 1}
    # it moves: alive again at once
    state, dead = tracker.update(state, np.array([90, 180, 8, 270], dtype=np.float64), 100.0 + 90 * dt)
    assert not dead.any()


def test_polls_faster_than_the_device_refreshes_still_find_it() -> None:
    # the device refreshes every 5th poll (30 Hz frames polled at 150 Hz): taxel 1 frozen
    tracker = DeadTaxelTracker(np.zeros(3, dtype=np.intp), ("r",), dead_after_s=1.0)
    state = tracker.initial_state(3)
    dt = 1.0 / 150.0
    flagged_at = None
    for k in range(300):
        frame = k // 5
        state, dead = tracker.update(state, np.array([frame, 9, frame % 7], dtype=np.float64), 100.0 + k * dt)
        if dead[1] and flagged_at is None:
            flagged_at = k
    # frozen since poll 0: 1 s later is poll 150
    assert flagged_at == 150


def test_regions_need_not_be_runs_of_channels() -> None:
    # channels 0 and 2 in region "a", 1 and 3 in "b"; 2 frozen while 0 moves; b all still
    tracker = DeadTaxelTracker(np.array([0, 1, 0, 1], dtype=np.intp), ("a", "b"), dead_after_s=1.0)
    state = tracker.initial_state(4)
    for k in range(12):
        state, dead = tracker.update(state, np.array([k, 3, 5, 3], dtype=np.float64), 100.0 + 0.1 * k)
    # frozen since poll 0: 1.1 s at poll 11
    assert dead.tolist() == [False, False, True, False]
    assert tracker.counts(dead) == {"a": 1, "b": 0}


def test_an_idle_region_or_one_that_moved_only_briefly_has_no_dead_taxel() -> None:
    tracker = DeadTaxelTracker(np.array([0, 0, 0, 1, 1, 1], dtype=np.intp), ("a", "b"), dead_after_s=1.0)
    state = tracker.initial_state(6)
    for k in range(100):
        # region a: all still (an idle region); region b: taxel 3 moves in the first 10 polls only
        moving = k if k < 10 else 10
        values = np.array([0, 0, 0, moving, 5, 5], dtype=np.float64)
        state, dead = tracker.update(state, values, 100.0 + 0.1 * k)
    # 10 s on: a's taxels are all frozen (nothing moved); b's 4 and 5 saw 9 moving polls of 100
    assert not dead.any()


# ------------------------------------------------------------------ on the virtual bus
async def test_a_dead_taxel_is_flagged_in_its_time_and_left_out_of_the_totals() -> None:
    cfg = config(device="dead_after_s = 1.5")
    dev = VirtualDevice()
    poller, clock = poller_for(cfg, dev)
    seen_dead_at = None
    for k in range(40):
        wobble = k % 2
        # tip taxel 1 frozen at 2 N; the others wobble by 1 mN around 1 N; the pad idle at 0
        dev.set_holding(0, [1000 + wobble, 2000, 1000 - wobble, 1000 + wobble])
        dev.set_holding(10, [0, 0, 0])
        clock.now_s = 100.0 + 0.1 * k
        snap = await poll(poller)
        if snap.status[1] == ChannelStatus.ERROR and seen_dead_at is None:
            seen_dead_at = k
            assert np.isnan(snap.force_n[1])
            # the live taxels alone: 3 x ~1 N, the dead one's 2 N left out, area 3 cells
            assert snap.total_force_n == pytest.approx(3.0 + wobble * 0.001, abs=2e-3)
            assert snap.channels_in_contact == 3
            assert snap.dead_by_region == (("tip", 1), ("pad", 0))
    # frozen since poll 0 (t = 100 s): dead at the first poll 1.5 s on, poll 15
    assert seen_dead_at == 15
    # the idle pad (all at 0, none moving) is not dead
    assert snap.status[4:].tolist() == [ChannelStatus.NO_CONTACT] * 3


def test_dead_after_s_is_checked_and_defaults_by_kind_of_device() -> None:
    assert config().buses[0].devices[0].dead_after_s == 10.0
    assert config(device="dead_after_s = 0").buses[0].devices[0].dead_after_s == 0.0
    with pytest.raises(
        ConfigError, match=r"dead_after_s: -1 is out of range; allowed: \[0, 86400\] s \(0: off\)"
    ):
        config(device="dead_after_s = -1")


async def test_the_metric_counts_dead_taxels_by_region() -> None:
    cfg = config(device="dead_after_s = 0.5")
    dev = VirtualDevice()
    poller, clock = poller_for(cfg, dev)
    for k in range(8):
        dev.set_holding(0, [1000 + k % 2, 2000, 1000, 1000])
        dev.set_holding(10, [k % 2, 0, 7])
        clock.now_s = 100.0 + 0.1 * k
        await poll(poller)
    text = render(poller.snapshot())
    # tip: only taxel 0 moves, so 1, 2, 3 are frozen under a moving region; pad: 1 and 2
    assert 'tactile_dead_taxels{device="hand",region="tip"} 3.0' in text
    assert 'tactile_dead_taxels{device="hand",region="pad"} 2.0' in text
