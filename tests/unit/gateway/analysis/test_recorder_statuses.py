"""The live recorder keeps the row of every channel whose status carries a value, an
extrapolated one (a force outside the calibrated range) too."""

from __future__ import annotations

import io

import numpy as np

from gateway.analysis.recorder import LiveRecorder
from gateway.config import ChannelConfig, DeviceConfig, RegisterMap, bus_config_for, gateway_config_for
from gateway.config.layout import GridLayout
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.model.conversion import line_conversion
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus, GatewaySnapshot

M, N = 2e-5, 1e-6


def test_extrapolated_rows_are_recorded() -> None:
    line = line_conversion(M, N, 0.5, 5.0)
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", 2.5 * k, 0.0, True, PAPER_EFFECTS, SensorParams(), None, line)
        for k in range(4)
    )
    dev = DeviceConfig(
        "arr", 1, "float32", 4, RegisterMap(), Divider(), channels, False, GridLayout(4, 4, 2.5, 2.5), None
    )
    config = gateway_config_for([bus_config_for("bench", "tcp", [dev], host="127.0.0.1", port=5020)])
    r = 1.0 / (M * np.array([0.3, 2.0, 8.0, 0.0]) + N)
    proc = DeviceProcessor(dev, "bench", 0.1)
    snap, _ = proc.process(proc.initial_state(), RawSample(resistance_ohm=r, device_time_s=1.0), 1e9, 0.0)
    assert [ChannelStatus(int(s)).label for s in snap.status] == [
        "extrapolated",
        "ok",
        "extrapolated",
        "no_contact",
    ]
    out = io.StringIO()
    recorder = LiveRecorder(out, config)
    recorder(GatewaySnapshot.build({"arr": snap}, {}, 1))
    assert recorder.stats.rows == 4 and recorder.stats.skipped_rows == 0
    rows = [line.split(",") for line in out.getvalue().splitlines() if line and not line.startswith("#")][1:]
    assert [(name, float(value)) for _, name, value in rows] == [
        (f"ch{k:02d}", float(r[k])) for k in range(4)
    ]
