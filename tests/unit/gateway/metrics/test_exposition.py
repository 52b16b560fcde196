"""The two writers of the table of families agree: the directly written exposition equals, byte
for byte, what the client library makes of the collector, for snapshots with every kind of value,
every family of the table is in both with the same samples, and ``promtool`` accepts it. (The
values themselves are checked against known numbers in ``test_families.py``.)"""

from __future__ import annotations

import math
import re
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families

from gateway.config import device_config_for
from gateway.metrics.collector import make_registry
from gateway.metrics.exposition import SnapshotExposition, render
from gateway.metrics.families import FAMILIES
from gateway.modbus.image import RawSample
from gateway.model import SensorParams
from gateway.runtime.counters import Tally
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot


def _reference(snap: GatewaySnapshot) -> bytes:
    return generate_latest(make_registry(lambda: snap, CollectorRegistry(auto_describe=False)))


def _snapshot(seed: int, n_devices: int, names: list[str]) -> GatewaySnapshot:
    rng = np.random.default_rng(seed)
    devices = {}
    counters = {}
    for d in range(n_devices):
        n = int(rng.integers(1, 9))
        dev = device_config_for(names[d % len(names)] + str(d), 1, [SensorParams()] * n, min(3, n), 2.5)
        # some channels calibrated on 0.5-2 N: the forces they read outside it are extrapolated
        ranged = rng.random(n) < 0.5
        dev = replace(
            dev,
            channels=tuple(
                replace(c, calibrated_range_n=(0.5, 2.0) if ranged[k] else None)
                for k, c in enumerate(dev.channels)
            ),
        )
        proc = DeviceProcessor(dev, "bus", 0.05)
        counts = rng.integers(0, 65536, n).astype(np.uint16)  # rails included: open, short
        reference = np.where(rng.random(n) < 0.5, rng.normal(2.0, 1.0, n), np.nan)
        raw = RawSample(
            counts=counts,
            device_time_s=float(rng.random() * 100) if rng.random() < 0.5 else None,
            reference_force_n=reference,
        )
        snap, state = proc.process(proc.initial_state(), raw, 1.7e9 + d, float(d))
        if rng.random() < 0.3:
            snap, _ = proc.stale(state, 1.7e9 + d + 1, "timeout")
        devices[dev.name] = snap
        if rng.random() < 0.8:
            tally = Tally()
            for _ in range(int(rng.integers(0, 5))):
                tally.read()
                tally.poll(float(rng.random() * 0.01))
            tally.error("timeout")
            counters[dev.name] = tally.freeze()
    return GatewaySnapshot.build(devices, counters, seed)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_devices=st.integers(0, 4),
    names=st.lists(st.from_regex(r"[a-z0-9_-]{1,8}", fullmatch=True), min_size=1, max_size=3),
)
def test_the_bytes_equal_the_client_library_s(seed: int, n_devices: int, names: list[str]) -> None:
    snap = _snapshot(seed, n_devices, names)
    assert render(snap).encode() == _reference(snap)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_devices=st.integers(0, 4))
def test_every_family_of_the_table_is_in_both_with_the_same_samples(seed: int, n_devices: int) -> None:
    snap = _snapshot(seed, n_devices, ["arr"])
    direct = {f.name: f for f in text_string_to_metric_families(render(snap))}
    library = {f.name: f for f in text_string_to_metric_families(_reference(snap).decode())}
    assert list(direct) == list(library) == [f.family_name for f in FAMILIES]
    for family in FAMILIES:
        mine, theirs = direct[family.family_name], library[family.family_name]
        assert (
            (mine.type, mine.documentation)
            == (theirs.type, theirs.documentation)
            == (family.type, family.help)
        )
        assert mine.samples == theirs.samples, family.name
        for sample in mine.samples:
            assert set(sample.labels) - {"le"} == set(family.labels), (family.name, sample)
            assert math.isfinite(sample.value), (family.name, sample)


def test_an_empty_gateway_and_the_cache() -> None:
    snap = GatewaySnapshot()
    assert render(snap).encode() == _reference(snap)
    calls = []

    def source() -> GatewaySnapshot:
        calls.append(1)
        return current

    current = _snapshot(1, 2, ["a"])
    exposition = SnapshotExposition(source)
    first = exposition()
    assert exposition() is first  # the same snapshot: the cached bytes
    current = _snapshot(2, 2, ["a"])
    assert exposition() is not first and exposition() == _reference(current)


@pytest.mark.parametrize("seed", [3, 4])
def test_promtool_accepts_it(tmp_path: Path, seed: int) -> None:
    promtool = shutil.which("promtool")
    assert promtool is not None, "promtool (Debian prometheus) is installed by the Makefile"
    path = tmp_path / "metrics.txt"
    text = render(_snapshot(seed, 3, ["arr"]))
    # the snapshots carry the extrapolated status (a force outside a calibrated range)
    assert re.search(r'tactile_channel_status\{[^}]*status="extrapolated"\} 1\.0\n', text), text
    assert "stale, error, extrapolated, no_zero, uncalibrated\n" in text  # the HELP text lists them
    path.write_text(text)
    with path.open("rb") as f:
        result = subprocess.run(
            [promtool, "check", "metrics"], stdin=f, capture_output=True, text=True, timeout=60
        )
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_registry_renders_what_the_client_library_makes_of_it() -> None:
    """The server sends ``SnapshotRegistry.render()``: the snapshot's families written
    directly, then any other collector (here the MQTT counters) through the client library."""
    from gateway.metrics.exposition import SnapshotRegistry
    from gateway.mqtt.link import MqttLink

    snap = _snapshot(7, 3, ["arr"])
    registry = SnapshotRegistry(lambda: snap)
    assert registry.render() == generate_latest(registry)
    link = MqttLink(registry)
    body = registry.render()
    assert body == generate_latest(registry) and b"tactile_mqtt_connected 0.0" in body
    registry.unregister(link)
    assert registry.render() == generate_latest(registry) == _reference(snap)
