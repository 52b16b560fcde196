"""The shipped hand profile (``dexhand-1062``): 17 regions, 1,062 taxels at their public byte
addresses, the read plan hand-counted in both readings of those addresses, and
``check-config`` listing the regions and how many requests a frame takes."""

from __future__ import annotations

import math
from pathlib import Path

from click.testing import CliRunner

from gateway.cli import main
from gateway.config import parse_config
from gateway.modbus.plan import MERGE_GAP, device_plan

HAND = """
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = 6000

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
{extra}
"""


def test_the_profile_holds_17_regions_and_1062_taxels_at_the_public_addresses() -> None:
    dev = parse_config(HAND.format(extra="")).buses[0].devices[0]
    assert (dev.n_channels, len(dev.regions)) == (1062, 17)
    sizes = {r.name: r.n_channels for r in dev.regions}
    for finger in ("little", "ring", "middle", "index"):
        assert sum(n for name, n in sizes.items() if name.startswith(finger)) == 185
    assert sum(n for name, n in sizes.items() if name.startswith("thumb")) == 210
    assert sizes["palm"] == 112
    # the block starts, bytes / 2
    starts = {r.group: r.address for r in reversed(dev.regions)}
    assert starts == {
        "little": 1500,
        "ring": 1685,
        "middle": 1870,
        "index": 2055,
        "thumb": 2240,
        "palm": 2450,
    }
    groups = sorted({r.group for r in dev.regions})
    assert groups == ["index", "little", "middle", "palm", "ring", "thumb"]


def test_a_frame_of_the_hand_takes_9_requests_as_bytes_and_17_as_strided_registers() -> None:
    as_bytes = parse_config(HAND.format(extra="")).buses[0].devices[0]
    # 1062 back-to-back registers from 1500: ceil(1062 / 125) = 9 reads
    plan = device_plan(as_bytes, 125, MERGE_GAP, clock=True)
    assert len(plan) == math.ceil(1062 / 125) == 9
    # the other reading: the same numbers as registers, one value every two: 63 values a read
    as_registers = (
        parse_config(HAND.format(extra='address_unit = "register"\nvalue_stride = 2')).buses[0].devices[0]
    )
    assert [r.address for r in as_registers.regions][:2] == [3000, 3018]
    plan = device_plan(as_registers, 125, MERGE_GAP, clock=True)
    assert len(plan) == math.ceil(1062 / 63) == 17


def test_check_config_lists_the_regions_and_the_requests_a_frame_takes(tmp_path: Path) -> None:
    path = tmp_path / "hand.toml"
    path.write_text(HAND.format(extra=""))
    result = CliRunner().invoke(main, ["check-config", "-c", str(path)])
    assert result.exit_code == 0, result.output
    assert "a frame takes 9 requests" in result.output
    assert "17 regions" in result.output
    assert "palm (palm): 14 x 8 at register 2450, channels 950..1061" in result.output
    assert "off the grid" not in result.output
    assert (
        "dead taxels: one frozen for 10 s while its region moves reads error "
        "(`poll-once --for 20` lists them by region)" in result.output
    )
