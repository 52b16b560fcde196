"""An uncalibrated ``ratio`` channel reads no made-up force (issue 33 §16).

A ``ratio`` front end reads r / R_ref of a divider whose reference resistor is unknown; the
default sensor parameters are in ohm, so on those readings (about 1 R_ref) they gave 10 N
``saturated`` on every channel, 600 N on a 60-channel board. Such a channel reads
``uncalibrated``: its reading (in units of R_ref) is kept and recorded, it has no force and
counts in no array quantity; a channel with a calibration reads its force as before, and
check-config/poll-once name the channels and the way to calibrate them.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from gateway.analysis.recorder import LiveRecorder
from gateway.config import DeviceConfig, GatewayConfig, parse_config
from gateway.modbus.image import RawSample
from gateway.mqtt.frame_rows import recordable
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus, GatewaySnapshot
from gateway.runtime.summary import device_summary

N_CHANNELS = 60
FS = 4095  # 12-bit full scale
#: the line of channel c0's calibration: relative conductance C = m F + n (1/R_ref per N, 1/R_ref)
M_PER_N, N_REL = 0.5, 0.0


def _config(tmp_path: Path, calibration: str | None = None) -> GatewayConfig:
    cal = ""
    if calibration is not None:
        (tmp_path / "cal.toml").write_text(calibration)
        cal = f'calibration = "{tmp_path / "cal.toml"}"'
    return parse_config(
        f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "board"
device_id = 1
profile = "generic-adc"
channels = {N_CHANNELS}
registers.adc_address = 0
{cal}
[bus.device.front_end]
kind = "ratio"
adc_bits = 12
""",
        tmp_path / "gateway.toml",
    )


def _device(config: GatewayConfig) -> DeviceConfig:
    return config.buses[0].devices[0]


def _read(device: DeviceConfig, counts: np.ndarray) -> tuple[DeviceProcessor, object]:
    proc = DeviceProcessor(device, "bench", 0.1)
    snap, _ = proc.process(proc.initial_state(), RawSample(counts=counts), 1000.0, 0.0)
    return proc, snap


def test_uncalibrated_ratio_channels_read_no_force(tmp_path: Path) -> None:
    device = _device(_config(tmp_path))
    counts = np.full(N_CHANNELS, 2048, dtype=np.uint16)
    counts[1] = 0  # rising with load: code 0 is an open sensor
    counts[2] = FS  # ... and full scale a short
    _, snap = _read(device, counts)
    status = snap.status.tolist()  # type: ignore[attr-defined]
    assert status[1] == ChannelStatus.OPEN and status[2] == ChannelStatus.SHORT
    rest = [s for k, s in enumerate(status) if k not in (1, 2)]
    assert rest == [ChannelStatus.UNCALIBRATED] * (N_CHANNELS - 2)
    assert np.isnan(snap.force_n).all()  # type: ignore[attr-defined]
    assert snap.total_force_n == 0.0  # type: ignore[attr-defined]
    assert snap.channels_in_contact == 0  # type: ignore[attr-defined]
    assert snap.peak_channel is None  # type: ignore[attr-defined]
    # the reading is kept: r / R_ref = FS / code - 1 = 4095 / 2048 - 1
    assert math.isclose(float(snap.resistance_ohm[0]), 4095 / 2048 - 1, rel_tol=1e-12)  # type: ignore[attr-defined]
    assert snap.channels()[0].force_n is None  # type: ignore[attr-defined]


def test_a_calibrated_ratio_channel_reads_its_force(tmp_path: Path) -> None:
    device = _device(
        _config(tmp_path, f"[line.ch00]\nslope_s_per_n = {M_PER_N!r}\nintercept_s = {N_REL!r}\n")
    )
    _, snap = _read(device, np.full(N_CHANNELS, 2048, dtype=np.uint16))
    # C = 1 / (4095 / 2048 - 1) = 2048 / 2047; F = (C - n) / m
    expected_n = (2048 / 2047 - N_REL) / M_PER_N
    assert snap.status[0] == ChannelStatus.OK  # type: ignore[attr-defined]
    assert math.isclose(float(snap.force_n[0]), expected_n, rel_tol=1e-9)  # type: ignore[attr-defined]
    assert (snap.status[1:] == ChannelStatus.UNCALIBRATED).all()  # type: ignore[attr-defined]
    assert math.isclose(snap.total_force_n, expected_n, rel_tol=1e-9)  # type: ignore[attr-defined]


def test_uncalibrated_readings_are_recorded_for_calibrate(tmp_path: Path) -> None:
    config = _config(tmp_path)
    _, snap = _read(_device(config), np.full(N_CHANNELS, 1000, dtype=np.uint16))
    out = io.StringIO()
    recorder = LiveRecorder(out, config)
    recorder(GatewaySnapshot.build({"board": snap}, {}, 1))  # type: ignore[dict-item]
    assert recorder.stats.rows == N_CHANNELS and recorder.stats.skipped_rows == 0
    frame = {"channels": ["ch00"], "status": ["uncalibrated"], "resistance_ohm": [3.095], "up": True}
    assert recordable(frame) == ([("ch00", 3.095)], 0)


def test_check_config_names_the_uncalibrated_channels_and_how(tmp_path: Path) -> None:
    text = "\n".join(device_summary(_device(_config(tmp_path))))
    assert f"{N_CHANNELS} channels read `uncalibrated` (no force: " in text
    assert "tactile-gateway record" in text and "tactile-gateway calibrate" in text
