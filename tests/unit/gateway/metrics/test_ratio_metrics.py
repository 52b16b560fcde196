"""A ``ratio`` front end's readings are r / R_ref, dimensionless: ``/metrics`` exports them as
``tactile_resistance_ratio``, never as ``tactile_resistance_ohms`` (issue 33 §16), while a
device whose front end reads ohm keeps its ohms. Both writers agree and ``promtool`` accepts it."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
from prometheus_client import CollectorRegistry, generate_latest

from gateway.config import parse_config
from gateway.metrics.collector import make_registry
from gateway.metrics.exposition import render
from gateway.modbus.image import RawSample
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot

CODE = 2048  # every channel's 12-bit code


def _snapshot(tmp_path: Path) -> GatewaySnapshot:
    config = parse_config(
        """
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "rel"
device_id = 1
profile = "generic-adc"
channels = 2
registers.adc_address = 0
[bus.device.front_end]
kind = "ratio"
adc_bits = 12
[[bus.device]]
name = "ohm"
device_id = 2
profile = "generic-adc"
channels = 2
registers.adc_address = 0
""",
        tmp_path / "gateway.toml",
    )
    devices = {}
    for device in config.buses[0].devices:
        proc = DeviceProcessor(device, "bench", 0.1)
        raw = RawSample(counts=np.full(2, CODE, dtype=np.uint16))
        devices[device.name], _ = proc.process(proc.initial_state(), raw, 1.7e9, 0.0)
    return GatewaySnapshot.build(devices, {}, 1)


def _value(text: str, family: str, device: str, channel: str) -> float | None:
    m = re.search(rf'^{family}\{{channel="{channel}",device="{device}"\}} (\S+)$', text, re.MULTILINE)
    return None if m is None else float(m.group(1))


def test_ratio_readings_are_exported_as_a_ratio_not_ohm(tmp_path: Path) -> None:
    snap = _snapshot(tmp_path)
    text = render(snap)
    assert text.encode() == generate_latest(
        make_registry(lambda: snap, CollectorRegistry(auto_describe=False))
    )
    # rising with load: r / R_ref = FS / code - 1 = 4095 / 2048 - 1 = 2047 / 2048
    for channel in ("ch00", "ch01"):
        assert _value(text, "tactile_resistance_ratio", "rel", channel) == 2047 / 2048
        assert _value(text, "tactile_resistance_ohms", "rel", channel) is None
    # the generic-adc profile's high-side divider, 3.3 V, 10 kohm: r = 10k (4095 / 2048 - 1)
    assert _value(text, "tactile_resistance_ohms", "ohm", "ch00") == 10000.0 * 2047 / 2048
    assert _value(text, "tactile_resistance_ratio", "ohm", "ch00") is None
    assert "# TYPE tactile_resistance_ratio gauge\n" in text
    assert re.search(r"# HELP tactile_resistance_ratio [^\n]*r / R_ref[^\n]*dimensionless", text), text


def test_promtool_accepts_the_ratio_family(tmp_path: Path) -> None:
    promtool = shutil.which("promtool")
    assert promtool is not None, "promtool (Debian prometheus) is installed by the Makefile"
    path = tmp_path / "metrics.txt"
    path.write_text(render(_snapshot(tmp_path)))
    with path.open("rb") as f:
        result = subprocess.run(
            [promtool, "check", "metrics"], stdin=f, capture_output=True, text=True, timeout=60
        )
    assert result.returncode == 0, result.stdout + result.stderr
