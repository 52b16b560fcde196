"""Devices and snapshots for the Foxglove tests: a two-region device (a 2 x 3 tip, row-major,
unturned; a 3 x 2 pad, column-major from the bottom-left, turned 90 degrees) and a snapshot
whose channel k reads 0.5 + k N."""

from __future__ import annotations

import numpy as np

from gateway.config import GatewayConfig, parse_config
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot

HEAD = """
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = 502

[[bus.device]]
name = "hand"
device_id = 1

[bus.device.frame]
quantity = "counts"
table = "holding"

[bus.device.front_end]
kind = "high_side"
supply_v = 5.0
reference_ohm = 10000.0
adc_bits = 16

[[bus.device.region]]
name = "tip"
group = "index"
address = 0
rows = 2
columns = 3
pitch_x_mm = 2.0
pitch_y_mm = 3.0
x_mm = 10.0
y_mm = 20.0

[[bus.device.region]]
name = "pad"
group = "index"
address = 6
rows = 3
columns = 2
order = "column-major"
origin = "bottom-left"
pitch_mm = 2.5
x_mm = 0.0
y_mm = 40.0
rotation_deg = 90
"""


def hand_config(extra: str = "") -> GatewayConfig:
    return parse_config(HEAD + extra)


def hand_snapshot(
    n: int = 12, missing: tuple[int, ...] = (), stale: tuple[int, ...] = (), t_s: float = 1_700_000_000.25
) -> DeviceSnapshot:
    """Channel k reads 0.5 + k N, status ok; ``missing`` channels are not in the snapshot (disabled),
    ``stale`` ones carry NaN."""
    index = np.array([k for k in range(n) if k not in missing])
    force = np.array([np.nan if k in stale else 0.5 + k for k in index])
    status = np.array([ChannelStatus.STALE if k in stale else ChannelStatus.OK for k in index], dtype=np.int8)
    m = len(index)
    return DeviceSnapshot(
        device="hand",
        bus="line",
        channel_index=index,
        channel_names=tuple(f"c{k}" for k in index),
        x_mm=np.zeros(m),
        y_mm=np.zeros(m),
        resistance_ohm=np.full(m, 1000.0),
        force_n=force,
        static_estimate=None,
        reference_force_n=np.full(m, np.nan),
        status=status,
        up=True,
        timestamp_s=t_s,
        last_success_timestamp_s=t_s,
        device_time_s=None,
        poll_interval_s=0.05,
        total_force_n=float(np.nansum(force)),
        channels_in_contact=int(np.count_nonzero(np.isfinite(force))),
    )


#: the tip's grid: row-major, 2 x 3, channels 0..5
TIP_N = [[0.5, 1.5, 2.5], [3.5, 4.5, 5.5]]
#: the pad's grid: channel 6 + k at k // 3 columns along, rows counted up from the bottom
#: (k = 0 -> row 2, col 0; k = 2 -> row 0, col 0; k = 3 -> row 2, col 1)
PAD_N = [[8.5, 11.5], [7.5, 10.5], [6.5, 9.5]]
