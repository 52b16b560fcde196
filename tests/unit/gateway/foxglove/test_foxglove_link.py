"""The running gateway's Foxglove side: the server follows the configuration on reload
(kept when nothing it serves changed, restarted when it did, stopped when the section goes),
and the dexhand-1062 profile is served as its 17 regions."""

from __future__ import annotations

import dataclasses

import numpy as np
from foxglove_helpers import hand_config, hand_snapshot

from gateway.config import parse_config
from gateway.config.foxglove import FoxgloveConfig
from gateway.foxglove.grids import region_grids
from gateway.foxglove.link import FoxgloveLink


def test_reload_keeps_restarts_or_stops_the_server() -> None:
    base = hand_config()
    on = dataclasses.replace(base, foxglove=FoxgloveConfig(port=0))
    link = FoxgloveLink()
    try:
        link.apply(base)
        assert link.port is None
        link.apply(on)
        first = link._publisher
        assert first is not None and link.port is not None
        link.apply(dataclasses.replace(on))  # a reload that changes nothing it serves
        assert link._publisher is first
        link.apply(dataclasses.replace(on, foxglove=FoxgloveConfig(port=0, queue_frames=5)))
        assert link._publisher is not first and link._publisher is not None
        assert link._publisher.settings.queue_frames == 5
        link.apply(base)
        assert link._publisher is None and link.port is None
    finally:
        link.stop()


def test_the_hand_profile_is_served_as_its_17_regions_each_taxel_once() -> None:
    text = """
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
    device = parse_config(text).buses[0].devices[0]
    grids = region_grids(hand_snapshot(n=1062), device)
    shapes = sorted((rows, cols) for _, rows, cols, _ in grids)
    # four fingers: tip 3x3, nail 12x8, pad 10x8; the thumb: tip 3x3, nail 12x8, middle 3x3,
    # pad 12x8; the palm 14x8 (issue 34)
    expected = sorted([(3, 3), (12, 8), (10, 8)] * 4 + [(3, 3), (12, 8), (3, 3), (12, 8), (14, 8)])
    assert shapes == expected
    values = np.concatenate([g.ravel() for _, _, _, g in grids])
    # channel k reads 0.5 + k: every taxel exactly once over the 17 grids
    np.testing.assert_array_equal(np.sort(values), 0.5 + np.arange(1062, dtype=np.float32))
