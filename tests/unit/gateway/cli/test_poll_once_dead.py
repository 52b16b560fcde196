"""``poll-once --for S`` polls a while and lists the dead taxels by region; a plain
``poll-once`` says how many requests a frame takes and that one poll finds none."""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from gateway.cli import main, run_cmd
from gateway.config import GatewayConfig
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.poller import Poller

CONFIG = """
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = 502
timeout_s = 0.2
retries = 0
poll_interval_s = 0.02

[[bus.device]]
name = "hand"
device_id = 1
dead_after_s = 0.1

[bus.device.frame]
quantity = "force"
unit = "mN"
table = "holding"

[[bus.device.region]]
name = "tip"
address = 0
rows = 1
columns = 3

[[bus.device.region]]
name = "pad"
address = 10
rows = 1
columns = 2
"""


class Wobbling(dict[int, int]):
    """Holding registers whose register 0 reads one more at every read: a live taxel."""

    def __getitem__(self, address: int) -> int:
        value = super().__getitem__(address)
        if address == 0:
            super().__setitem__(0, value + 1)
        return value


@pytest.fixture
def virtual_poller(monkeypatch: pytest.MonkeyPatch) -> None:
    device = VirtualDevice()
    device.holding = Wobbling({0: 100, 1: 500, 2: 0, 10: 0, 11: 0})
    transport = VirtualTransport("line", {1: device}, timeout_s=0.2)

    def make(config: GatewayConfig, **_: Any) -> Poller:
        return Poller(config, transport_factory=lambda _bus: transport, rng=random.Random(1))

    monkeypatch.setattr(run_cmd, "Poller", make)


def test_poll_once_for_a_while_lists_the_dead_taxels_by_region(tmp_path: Path, virtual_poller: None) -> None:
    path = tmp_path / "hand.toml"
    path.write_text(CONFIG)
    result = CliRunner().invoke(main, ["poll-once", "-c", str(path), "--for", "0.4"])
    assert result.exit_code == 0, result.output
    # tip-r0c1 and tip-r0c2 frozen while tip-r0c0 moved; the pad is idle (nothing moved)
    assert "dead taxels of hand (frozen for 0.1 s while their region moved): 2" in result.output
    assert "  tip: tip-r0c1, tip-r0c2" in result.output
    assert "  pad: none" in result.output
    assert "a frame of 2 regions takes 1 request" in result.output


def test_one_poll_finds_no_dead_taxel_and_says_how_long_to_watch(
    tmp_path: Path, virtual_poller: None
) -> None:
    path = tmp_path / "hand.toml"
    path.write_text(CONFIG)
    result = CliRunner().invoke(main, ["poll-once", "-c", str(path)])
    assert result.exit_code == 0, result.output
    assert (
        "dead taxels of hand: a taxel is dead after 0.1 s frozen; watch with --for 0.2 or more"
        in result.output
    )
