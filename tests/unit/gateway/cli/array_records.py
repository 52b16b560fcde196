"""Records of simulated arrays for the tests of ``calibrate --jobs`` and ``discrepancy --jobs``."""

from __future__ import annotations

from pathlib import Path

from sim_device import ArrayConfig, record_offline


def array_record(path: Path, channels: int, seed: int) -> Path:
    """A simulated array (sim_device, the independent witness) under load ramps: 190 s at one
    row per second per channel, channels named taxel0... (a device config cannot name '0')."""
    config = ArrayConfig(
        channels=channels, columns=channels, seed=seed, scenario="ramps", sensor_noise_rel=0.01
    )
    record = record_offline(config, record_period_s=1.0)
    record.channel = [f"taxel{c}" for c in record.channel]
    record.write_csv(path)
    return path
