"""The gateway's Foxglove server, read with a protocol client of our own (``wsclient``): each
region's forces arrive as a ``foxglove.Grid`` equal to the hand-built grid, posed where the
page draws the region, with the poll's timestamp; the layout arrives on subscribing; the
summary carries the totals per group. Ephemeral loopback port; the server is stopped."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator

import aiohttp
import numpy as np
import pytest
from foxglove_helpers import PAD_N, TIP_N, hand_config, hand_snapshot
from foxglove_wsclient import FoxgloveClient, connect, decode_grid

from gateway.config.foxglove import FoxgloveConfig
from gateway.foxglove.publisher import FoxglovePublisher
from gateway.runtime.snapshot import GatewaySnapshot

TOPICS = ["/tactile/hand/tip", "/tactile/hand/pad", "/tactile/hand/summary", "/tactile/hand/layout"]


@pytest.fixture
def publisher() -> Iterator[FoxglovePublisher]:
    config = dataclasses.replace(hand_config(), foxglove=FoxgloveConfig(host="127.0.0.1", port=0))
    pub = FoxglovePublisher(config).start()
    try:
        yield pub
    finally:
        pub.stop()


async def test_a_client_receives_each_regions_forces_and_the_layout(publisher: FoxglovePublisher) -> None:
    t_s = 1_700_000_000.25
    snaps = [hand_snapshot(t_s=t_s)]

    def poke() -> None:  # a new poll of the same forces, until the subscriptions are in place
        snaps.append(dataclasses.replace(snaps[-1]))
        publisher.on_snapshot(GatewaySnapshot.build({"hand": snaps[-1]}, {}, len(snaps)))

    async with aiohttp.ClientSession() as session, connect(session, publisher.port) as ws:
        client = FoxgloveClient(ws)
        await client.advertised(set(TOPICS))
        assert client.channels["/tactile/hand/tip"]["schemaName"] == "foxglove.Grid"
        assert client.channels["/tactile/hand/tip"]["encoding"] == "protobuf"
        assert client.channels["/tactile/hand/layout"]["encoding"] == "json"
        await client.subscribe(TOPICS)
        got = await client.collect(set(TOPICS), timeout_s=20.0, poke=poke)

    tip, pad = decode_grid(got["/tactile/hand/tip"][1]), decode_grid(got["/tactile/hand/pad"][1])
    np.testing.assert_array_equal(tip.values, np.array(TIP_N, dtype=np.float32))
    np.testing.assert_array_equal(pad.values, np.array(PAD_N, dtype=np.float32))
    for grid in (tip, pad):
        assert (grid.sec, grid.nsec) == (1_700_000_000, 250_000_000)
        assert grid.frame_id == "hand"
        assert grid.field_names == ["force_n"] and grid.field_types == [7]  # FLOAT32
        assert (grid.cell_stride, grid.row_stride) == (4, 4 * grid.column_count)
    assert got["/tactile/hand/tip"][0] == 1_700_000_000_250_000_000
    # the tip: unturned, cell (0, 0) centred at (10, 20) mm with a 2 x 3 mm pitch: corner (9, 18.5) mm
    assert tip.position_m == pytest.approx((0.009, 0.0185, 0.0))
    assert tip.orientation == pytest.approx((0.0, 0.0, 0.0, 1.0))
    assert tip.cell_size_m == pytest.approx((0.002, 0.003))
    # the pad: turned 90 degrees about z; its cell (0, 0) is drawn at the top right
    # (x = 0 + 2 x 2.5, y = 40): corner = centre - R(90) (1.25, 1.25) = (5 + 1.25, 40 - 1.25)
    s = math.sqrt(0.5)
    assert pad.orientation == pytest.approx((0.0, 0.0, s, s))
    assert pad.position_m == pytest.approx((0.00625, 0.03875, 0.0))

    layout = json.loads(got["/tactile/hand/layout"][1])
    assert layout["frame_id"] == "hand"
    assert [(r["name"], r["group"], r["rows"], r["columns"]) for r in layout["regions"]] == [
        ("tip", "index", 2, 3),
        ("pad", "index", 3, 2),
    ]
    assert layout["regions"][0]["channels"][1] == ["tip-r1c0", "tip-r1c1", "tip-r1c2"]
    assert (layout["regions"][1]["pitch_x_mm"], layout["regions"][1]["rotation_deg"]) == (2.5, 90)

    summary = json.loads(got["/tactile/hand/summary"][1])
    total = sum(0.5 + k for k in range(12))  # 72 N, all in contact
    assert summary["group_force_n"] == {"index": pytest.approx(total)}
    assert summary["up"] is True and summary["status_counts"]["ok"] == 12


async def test_a_second_client_gets_the_layout_when_it_subscribes(publisher: FoxglovePublisher) -> None:
    async with aiohttp.ClientSession() as session:
        for _ in range(2):
            async with connect(session, publisher.port) as ws:
                client = FoxgloveClient(ws)
                await client.advertised({"/tactile/hand/layout"})
                await client.subscribe(["/tactile/hand/layout"])
                topic, _, payload = await client.message(timeout_s=10.0)
                assert topic == "/tactile/hand/layout"
                assert json.loads(payload)["device"] == "hand"


def test_a_full_queue_drops_the_oldest_frames_and_counts_them() -> None:
    config = dataclasses.replace(hand_config(), foxglove=FoxgloveConfig(port=0, queue_frames=2))
    pub = FoxglovePublisher(config)
    pub._devices = {"hand": object()}  # type: ignore[dict-item]  # served, never started: nothing drains
    for k in range(5):
        pub.on_snapshot(GatewaySnapshot.build({"hand": hand_snapshot()}, {}, k))
    stats = pub.stats()
    assert (stats.queued, stats.dropped) == (2, {"hand": 3})


def test_a_taken_port_is_an_oserror() -> None:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        config = dataclasses.replace(hand_config(), foxglove=FoxgloveConfig(port=port))
        with pytest.raises(OSError):
            FoxglovePublisher(config).start()


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
"""


async def test_the_1062_taxel_hand_arrives_as_17_grids_each_taxel_once() -> None:
    from gateway.config import parse_config

    config = dataclasses.replace(parse_config(HAND), foxglove=FoxgloveConfig(port=0))
    regions = [r.name for r in config.buses[0].devices[0].regions]
    topics = [f"/tactile/hand/{name}" for name in regions]
    pub = FoxglovePublisher(config).start()
    snaps = [hand_snapshot(n=1062)]

    def poke() -> None:
        snaps.append(dataclasses.replace(snaps[-1]))
        pub.on_snapshot(GatewaySnapshot.build({"hand": snaps[-1]}, {}, len(snaps)))

    try:
        async with aiohttp.ClientSession() as session, connect(session, pub.port) as ws:
            client = FoxgloveClient(ws)
            await client.advertised({*topics, "/tactile/hand/summary"})
            await client.subscribe([*topics, "/tactile/hand/summary"])
            got = await client.collect({*topics, "/tactile/hand/summary"}, timeout_s=20.0, poke=poke)
    finally:
        pub.stop()
    assert len(regions) == 17
    values = np.concatenate([decode_grid(got[t][1]).values.ravel() for t in topics])
    np.testing.assert_array_equal(np.sort(values), 0.5 + np.arange(1062, dtype=np.float32))
    summary = json.loads(got["/tactile/hand/summary"][1])
    assert sum(summary["group_force_n"].values()) == pytest.approx(sum(0.5 + k for k in range(1062)))


def test_drops_are_said_at_once_then_at_most_every_10_s_and_at_stop(caplog: pytest.LogCaptureFixture) -> None:
    config = dataclasses.replace(hand_config(), foxglove=FoxgloveConfig(port=0, queue_frames=1))
    pub = FoxglovePublisher(config)
    pub._devices = {"hand": object()}  # type: ignore[dict-item]  # served, never started: nothing drains
    feed = lambda k: pub.on_snapshot(GatewaySnapshot.build({"hand": hand_snapshot()}, {}, k))  # noqa: E731
    feed(1)
    feed(2)
    pub._report_drops(100.0)
    feed(3)
    pub._report_drops(105.0)  # 5 s later: not yet
    pub._report_drops(110.5)  # 10.5 s after the first report
    feed(4)
    pub._report_drops(111.0, at_stop=True)
    said = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert [s.split(" (")[0] for s in said] == [
        "foxglove: 1 frame(s) dropped",
        "foxglove: 1 frame(s) dropped",
        "foxglove: 1 frame(s) dropped",
    ]
    assert "3 in all" in said[-1]
