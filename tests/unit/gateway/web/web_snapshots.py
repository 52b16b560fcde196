"""Hand-built device snapshots for the web tests (no model, no poller)."""

from __future__ import annotations

import numpy as np

from gateway.runtime.counters import DeviceCounters
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot, GatewaySnapshot


def device(name: str = "arr", forces: tuple[float, ...] = (0.0, 1.5, float("nan"), 0.25), up: bool = True,
           t: float = 1000.0) -> DeviceSnapshot:  # fmt: skip
    n = len(forces)
    status = [ChannelStatus.OK if f > 0 else ChannelStatus.NO_CONTACT for f in forces]
    status = [ChannelStatus.OPEN if np.isnan(f) else s for f, s in zip(forces, status, strict=True)]
    if not up:
        status = [ChannelStatus.STALE] * n
    return DeviceSnapshot(
        device=name,
        bus="sim",
        channel_index=np.arange(n, dtype=np.int64),
        channel_names=tuple(f"ch{i:02d}" for i in range(n)),
        x_mm=np.array([(i % 2) * 2.5 for i in range(n)]),
        y_mm=np.array([(i // 2) * 2.5 for i in range(n)]),
        resistance_ohm=np.full(n, 1e4),
        force_n=np.array(forces, dtype=np.float64),
        static_estimate=None,
        reference_force_n=np.full(n, np.nan),
        status=np.array(status, dtype=np.int8),
        up=up,
        timestamp_s=t,
        last_success_timestamp_s=t if up else t - 5.0,
        device_time_s=12.5 if up else None,
        poll_interval_s=0.05,
        total_force_n=1.75,
        center_of_pressure_mm=(2.5, 0.357142857142857),
        channels_in_contact=2,
        contact_area_mm2=12.5,
        peak_channel="ch01",
        peak_force_n=1.5,
        error=None if up else "timeout",
    )


def gateway(*devs: DeviceSnapshot, polls: int = 7) -> GatewaySnapshot:
    counters = {d.device: DeviceCounters(reads_total=polls, polls_total=polls) for d in devs}
    return GatewaySnapshot.build({d.device: d for d in devs}, counters, polls)
