"""The gateway's history and export buffer (issue 35 items 4 and 5): the hub keeps compact
per-poll summaries for ``history_s`` and per-channel readings for ``export_s``, both bounded
whatever the poll rate, driven here with hand-built snapshots and a synchronous loop."""

from __future__ import annotations

from dataclasses import replace

import pytest
from web_snapshots import device, gateway

from gateway.runtime.snapshot import RoiQuantities
from gateway.web.history import EXPORT_MAX_VALUES, HISTORY_MAX_POINTS, DeviceHistory
from gateway.web.hub import FrameHub


def attached(history_s: float, export_s: float) -> FrameHub:
    hub = FrameHub(history_s=history_s, export_s=export_s)
    hub.attach(lambda fn: fn())  # drain at once, in this thread
    return hub


def test_the_hub_keeps_the_last_history_s_of_summaries() -> None:
    hub = attached(history_s=10.0, export_s=5.0)
    heel = RoiQuantities("heel", (1, 3), 1.75, 1.5, 12.5, (1.25, 0.5))
    for k in range(40):  # 2 polls a second for 20 s
        snap = replace(device(t=1000.0 + 0.5 * k), rois=(heel,))
        hub.on_snapshot(gateway(snap, polls=k + 1))
    history = hub.history("arr")
    assert history is not None
    points = history.points(seconds=10.0)
    # the newest poll at 1019.5; kept: 1009.5 .. 1019.5 (21 polls)
    assert [p.t for p in points] == [1009.5 + 0.5 * k for k in range(21)]
    assert [p.t for p in history.points(seconds=2.0)] == [1017.5, 1018.0, 1018.5, 1019.0, 1019.5]
    p = points[-1]
    assert (p.force_n, p.peak_n, p.area_mm2, p.cop_mm) == (1.75, 1.5, 12.5, (2.5, 0.357142857142857))
    assert p.rois == (heel,)
    assert history.json_point(p) == {
        "t": 1019.5, "force_n": 1.75, "peak_n": 1.5, "area_mm2": 12.5, "cop_x_mm": 2.5,
        "cop_y_mm": 0.357143,
        "rois": {"heel": {"force_n": 1.75, "peak_n": 1.5, "area_mm2": 12.5, "cop_x_mm": 1.25,
                          "cop_y_mm": 0.5}},
    }  # fmt: skip
    # the export buffer: the last 5 s of readings (11 polls), each with its own values
    kept = history.export(1000.0, 2000.0)
    assert [s.timestamp_s for s in kept] == [1014.5 + 0.5 * k for k in range(11)]
    assert [s.timestamp_s for s in history.export(1015.2, 1016.0)] == [1015.5, 1016.0]
    snaps = history.snapshots(kept)  # as the recorder reads them: slim, each poll's own values
    assert [s.timestamp_s for s in snaps] == [r.timestamp_s for r in kept]
    assert snaps[0].static_estimate is None and snaps[0].rois == () and snaps[0].up
    assert snaps[0].channel_names == ("ch00", "ch01", "ch02", "ch03")


def test_a_failed_poll_is_not_a_point_and_nothing_is_kept_when_off() -> None:
    hub = attached(history_s=10.0, export_s=0.0)
    hub.on_snapshot(gateway(device(t=1000.0)))
    hub.on_snapshot(gateway(device(t=1001.0, up=False)))
    history = hub.history("arr")
    assert history is not None
    assert [p.t for p in history.points(10.0)] == [1000.0]
    assert history.export(0.0, 2000.0) == []
    off = attached(history_s=0.0, export_s=0.0)
    off.on_snapshot(gateway(device(t=1000.0)))
    assert off.history("arr") is None


def test_history_memory_is_bounded_whatever_the_poll_rate() -> None:
    """At most ``HISTORY_MAX_POINTS`` summaries over ``history_s`` (polls closer than
    history_s / HISTORY_MAX_POINTS are thinned) and ``EXPORT_MAX_VALUES`` channel readings."""
    h = DeviceHistory(history_s=1.0, export_s=1.0)
    snap = device(t=0.0)
    n = 3 * HISTORY_MAX_POINTS  # three times the bound within one history_s
    for k in range(n):
        h.add(replace(snap, timestamp_s=k / n))
    # thinned to the bound, not far below it
    assert HISTORY_MAX_POINTS // 2 <= len(h.points(1.0)) <= HISTORY_MAX_POINTS + 1
    assert h.export_frames() * snap.n_channels <= EXPORT_MAX_VALUES
    gaps = [b.t - a.t for a, b in zip(h.points(1.0), h.points(1.0)[1:], strict=False)]
    assert min(gaps) >= 1.0 / HISTORY_MAX_POINTS - 1e-12


@pytest.mark.parametrize(("history_s", "export_s"), [(-1.0, 0.0), (0.0, 601.0), (3601.0, 0.0)])
def test_spans_out_of_range_are_refused(history_s: float, export_s: float) -> None:
    with pytest.raises(ValueError, match="allowed"):
        DeviceHistory(history_s, export_s)


def test_a_device_a_reload_removes_takes_its_past_with_it() -> None:
    hub = attached(history_s=10.0, export_s=5.0)
    hub.on_snapshot(gateway(device("arr", t=1000.0), device("other", t=1000.0)))
    assert set(hub._history) == {"arr", "other"}
    hub.on_snapshot(gateway(device("arr", t=1001.0)))  # "other" is gone, never asked for
    assert set(hub._history) == {"arr"}
    assert hub.history("other") is None
    past = hub.history("arr")
    assert past is not None and [p.t for p in past.points(10.0)] == [1000.0, 1001.0]
