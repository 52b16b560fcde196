"""``poll-once``'s table and JSON, and the demo's view, with an extrapolated channel: its
force is shown beside its status, the table's columns stay aligned."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from gateway.cli.run_cmd import render_view, snapshot_json, snapshot_table
from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.model.conversion import line_conversion
from gateway.mqtt.payload import frame_dict
from gateway.runtime import frame
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot

M, N = 2e-5, 1e-6
LINE = line_conversion(M, N, 0.5, 5.0)  # calibrated on 0.5-5 N


def _snapshot() -> GatewaySnapshot:
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", 2.5 * k, 0.0, True, PAPER_EFFECTS, SensorParams(), None, LINE)
        for k in range(4)
    )
    dev = DeviceConfig(
        "arr", 1, "float32", 4, RegisterMap(), Divider(), channels, False, GridLayout(4, 4, 2.5, 2.5), None
    )
    forces = np.array([0.3, 2.0, 8.0, 0.0])
    proc = DeviceProcessor(dev, "bench", 0.1)
    snap, _ = proc.process(proc.initial_state(), RawSample(resistance_ohm=1.0 / (M * forces + N)), 1e9, 0.0)
    return GatewaySnapshot.build({"arr": snap}, {}, 1)


def test_the_table_shows_the_extrapolated_force_aligned() -> None:
    lines = snapshot_table(_snapshot()).splitlines()
    header, rows = lines[1], lines[2:6]
    assert [r.split()[1] for r in rows] == ["extrapolated", "ok", "extrapolated", "no_contact"]
    assert [float(r.split()[3]) for r in rows] == [0.3, 2.0, 8.0, 0.0]
    # every row's resistance column ends where the header's does
    end = header.index("resistance_ohm") + len("resistance_ohm")
    for row in rows:
        assert row[end - 1] != " " and row[end] == " ", row
    assert "total 10.300 N" in lines[6] and "3 in contact" in lines[6]


def test_the_json_and_the_demo_view_carry_it() -> None:
    snap = _snapshot()
    (dev,) = snapshot_json(snap)["devices"]
    assert [(c["status"], c["force_n"]) for c in dev["channels"]] == [
        ("extrapolated", 0.3),
        ("ok", 2.0),
        ("extrapolated", 8.0),
        ("no_contact", 0.0),
    ]
    view = render_view(snap.devices["arr"], 4, "http://127.0.0.1:9830/metrics", color=False)
    assert "  8.00" in view and "  0.30" in view and "extrap" not in view


def test_the_json_is_the_published_frame() -> None:
    # one owner of rounding and of "absent": the frame MQTT publishes (runtime.frame)
    snap = _snapshot()
    (dev,) = snapshot_json(snap)["devices"]
    published: dict[str, Any] = dict(frame_dict(snap.devices["arr"], 0))
    for key in ("total_force_n", "contact_area_mm2", "channels_in_contact", "up", "center_of_pressure_mm"):
        assert dev[key] == published[key], key
    for key in ("force_n", "force_static_n", "resistance_ohm", "status"):
        assert [c[key] for c in dev["channels"]] == published[key], key
    # 1 / (M F + N) ohm: 1 / (2e-5 x 0.3 + 1e-6) = 142857.142857... ohm, six decimals
    assert dev["channels"][0]["resistance_ohm"] == 142857.142857


def test_the_json_rounds_as_the_frame_does(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(frame, "DECIMALS", 2)
    (dev,) = snapshot_json(_snapshot())["devices"]
    assert dev["channels"][0]["resistance_ohm"] == 142857.14


def test_the_json_carries_each_channels_reference_force() -> None:
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", 2.5 * k, 0.0, True, PAPER_EFFECTS, SensorParams(), None, LINE)
        for k in range(2)
    )
    dev = DeviceConfig(
        "arr", 1, "float32", 2, RegisterMap(), Divider(), channels, False, GridLayout(2, 2, 2.5, 2.5), None
    )
    proc = DeviceProcessor(dev, "bench", 0.1)
    raw = RawSample(
        resistance_ohm=1.0 / (M * np.array([2.0, 0.0]) + N), reference_force_n=np.array([1.75, np.nan])
    )
    snap, _ = proc.process(proc.initial_state(), raw, 1e9, 0.0)
    (out,) = snapshot_json(GatewaySnapshot.build({"arr": snap}, {}, 1))["devices"]
    assert [c["reference_force_n"] for c in out["channels"]] == [1.75, None]
