"""The collector: metric names, labels, units in HELP, values from the snapshot, nothing absent."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path

import bcrypt
import numpy as np
import pytest
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families
from prometheus_client.samples import Sample

from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.errors import ConfigError
from gateway.metrics.collector import SnapshotCollector, make_registry
from gateway.metrics.web_config import BasicAuth, load_web_config
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorModel, SensorParams
from gateway.runtime.counters import Tally
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus, GatewaySnapshot

METRICS = {
    "tactile_force_newtons": "gauge",
    "tactile_force_static_newtons": "gauge",
    "tactile_resistance_ohms": "gauge",
    "tactile_channel_status": "gauge",
    "tactile_channel_position_mm": "gauge",
    "tactile_device_up": "gauge",
    "tactile_last_poll_success_timestamp_seconds": "gauge",
    "tactile_poll_duration_seconds": "histogram",
    "tactile_poll_interval_seconds": "gauge",
    "tactile_reads": "counter",
    "tactile_read_errors": "counter",
    "tactile_array_total_force_newtons": "gauge",
    "tactile_array_center_of_pressure_mm": "gauge",
    "tactile_array_contact_area_square_mm": "gauge",
    "tactile_array_channels_in_contact": "gauge",
    "tactile_device_clock_fallback": "gauge",
    "tactile_device_clock_faults": "counter",
}
UNIT_WORDS = re.compile(r"\((N|ohms|mm|mm\^2|s|count|dimensionless)\)|\bohms\b")


def _device(name: str, n: int = 4) -> DeviceConfig:
    # ch01 was calibrated on 0.5-2 N: the 3 N it reads is a force flagged extrapolated
    channels = tuple(
        ChannelConfig(
            i,
            f"ch{i:02d}",
            (i % 2) * 2.5,
            (i // 2) * 2.5,
            True,
            PAPER_EFFECTS,
            SensorParams(),
            calibrated_range_n=(0.5, 2.0) if i == 1 else None,
        )
        for i in range(n)
    )
    layout = GridLayout(n, 2, 2.5, 2.5)
    return DeviceConfig(name, 1, "adc", n, RegisterMap(), Divider(), channels, False, layout, None)


def _snapshot() -> GatewaySnapshot:
    div = Divider()
    dev = _device("left")
    proc = DeviceProcessor(dev, "bus0", 0.05)
    r = SensorModel(PAPER_EFFECTS, [SensorParams()] * 4).resistance(np.array([1.0, 3.0, 1.0, 1.0]))
    counts = div.counts(div.output_voltage(r))
    counts[2] = 0  # open
    counts[3] = 3  # no contact
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts), 1_700_000_000.0, 0.0)
    other = DeviceProcessor(_device("right", 2), "bus1", 0.2)
    stale, _ = other.stale(other.initial_state(), 1_700_000_001.0, "timeout")
    tally = Tally()
    for _ in range(10):
        tally.read()
    tally.error("timeout")
    tally.error("decode")
    tally.poll(0.004)
    counters = tally.freeze()
    return GatewaySnapshot.build({"left": snap, "right": stale}, {"left": counters}, 7)


def _scrape(snapshot: GatewaySnapshot) -> dict[str, object]:
    registry = CollectorRegistry()
    make_registry(lambda: snapshot, registry)
    text = generate_latest(registry).decode()
    return {f.name: f for f in text_string_to_metric_families(text)}


def _samples(families: dict[str, object], name: str) -> Iterator[Sample]:
    fam = families[name]
    yield from fam.samples  # type: ignore[attr-defined]


def _value(families: dict[str, object], name: str, **labels: str) -> float:
    family = re.sub(r"_(total|count|sum|bucket)$", "", name)
    matches = [s.value for s in _samples(families, family) if s.name == name and s.labels == labels]
    assert len(matches) == 1, (name, labels, matches)
    return float(matches[0])


def test_every_metric_is_present_with_its_type_and_units_in_help() -> None:
    families = _scrape(_snapshot())
    for name, kind in METRICS.items():
        assert name in families, name
        fam = families[name]
        assert fam.type == kind, name  # type: ignore[attr-defined]
        doc = fam.documentation  # type: ignore[attr-defined]
        assert UNIT_WORDS.search(doc), f"{name}: no unit in HELP {doc!r}"
    for name in METRICS:
        if name not in ("tactile_channel_position_mm", "tactile_poll_interval_seconds", "tactile_reads"):
            doc = families[name].documentation  # type: ignore[attr-defined]
            if name.startswith(("tactile_force", "tactile_resistance", "tactile_array", "tactile_channel_s")):
                assert "from the last poll" in doc, name


def test_values_come_from_the_snapshot() -> None:
    snap = _snapshot()
    families = _scrape(snap)
    left = snap.devices["left"]
    assert _value(families, "tactile_force_newtons", device="left", channel="ch01") == pytest.approx(
        float(left.force_n[1])
    )
    assert _value(families, "tactile_force_newtons", device="left", channel="ch01") == pytest.approx(
        3.0, rel=0.01
    )
    assert _value(families, "tactile_resistance_ohms", device="left", channel="ch00") == pytest.approx(
        float(left.resistance_ohm[0])
    )
    assert _value(families, "tactile_force_newtons", device="left", channel="ch03") == 0.0
    assert _value(families, "tactile_device_up", device="left") == 1.0
    assert _value(families, "tactile_device_up", device="right") == 0.0
    # the map names a clock (registers 2-5) but the sample carried none: the host clock times it
    assert _value(families, "tactile_device_clock_fallback", device="left") == 1.0
    assert _value(families, "tactile_device_clock_faults_total", device="left", kind="stuck") == 0.0
    assert _value(families, "tactile_last_poll_success_timestamp_seconds", device="left") == 1_700_000_000.0
    assert _value(families, "tactile_poll_interval_seconds", device="right") == 0.2
    assert _value(families, "tactile_reads_total", device="left") == 10.0
    assert _value(families, "tactile_read_errors_total", device="left", reason="timeout") == 1.0
    assert _value(families, "tactile_read_errors_total", device="left", reason="decode") == 1.0
    assert _value(families, "tactile_read_errors_total", device="left", reason="exception") == 0.0
    assert _value(families, "tactile_read_errors_total", device="left", reason="connection") == 0.0
    assert _value(families, "tactile_array_total_force_newtons", device="left") == pytest.approx(
        left.total_force_n
    )
    assert _value(families, "tactile_array_channels_in_contact", device="left") == 2.0
    assert _value(families, "tactile_array_contact_area_square_mm", device="left") == pytest.approx(12.5)
    cop = left.center_of_pressure_mm
    assert cop is not None
    assert _value(families, "tactile_array_center_of_pressure_mm", device="left", axis="x") == pytest.approx(
        cop[0]
    )
    assert _value(families, "tactile_array_center_of_pressure_mm", device="left", axis="y") == 0.0
    assert _value(families, "tactile_channel_position_mm", device="left", channel="ch03", axis="y") == 2.5
    assert _value(families, "tactile_poll_duration_seconds_count", device="left") == 1.0
    assert _value(families, "tactile_poll_duration_seconds_bucket", device="left", le="0.005") == 1.0
    assert _value(families, "tactile_poll_duration_seconds_bucket", device="left", le="0.0025") == 0.0


def test_status_has_one_series_per_status_and_one_is_set() -> None:
    families = _scrape(_snapshot())
    for device, channel, expected in [
        ("left", "ch00", "ok"),
        ("left", "ch01", "extrapolated"),
        ("left", "ch02", "open"),
        ("left", "ch03", "no_contact"),
        ("right", "ch01", "stale"),
    ]:
        series = {
            s.labels["status"]: s.value
            for s in _samples(families, "tactile_channel_status")
            if s.labels["device"] == device and s.labels["channel"] == channel
        }
        assert set(series) == {s.label for s in ChannelStatus}
        assert [k for k, v in series.items() if v == 1.0] == [expected]
    # the HELP text lists every status label, the new one last (its code is 7)
    doc = families["tactile_channel_status"].documentation  # type: ignore[attr-defined]
    assert doc.endswith(
        "ok, no_contact, saturated, open, short, stale, error, extrapolated, no_zero, uncalibrated"
    ), doc


def test_absent_values_are_left_out_never_nan() -> None:
    families = _scrape(_snapshot())
    for fam in families.values():
        for s in fam.samples:  # type: ignore[attr-defined]
            assert math.isfinite(s.value), s
            assert s.timestamp is None
    force_channels = {
        (s.labels["device"], s.labels["channel"]) for s in _samples(families, "tactile_force_newtons")
    }
    assert ("left", "ch02") not in force_channels  # open
    assert not any(d == "right" for d, _ in force_channels)  # never polled
    cop_devices = {s.labels["device"] for s in _samples(families, "tactile_array_center_of_pressure_mm")}
    assert cop_devices == {"left"}
    assert not any(
        s.labels["device"] == "right"
        for s in _samples(families, "tactile_last_poll_success_timestamp_seconds")
    )


def test_each_scrape_reads_the_latest_snapshot() -> None:
    holder = {"snap": GatewaySnapshot()}
    registry = CollectorRegistry()
    registry.register(SnapshotCollector(lambda: holder["snap"]))
    assert b"tactile_device_up{" not in generate_latest(registry)
    holder["snap"] = _snapshot()
    assert b'tactile_device_up{device="left"} 1.0' in generate_latest(registry)


def test_basic_auth_checks_bcrypt_hashes() -> None:
    hashed = bcrypt.hashpw(b"s3cret", bcrypt.gensalt(rounds=4))
    auth = BasicAuth({"prom": hashed.replace(b"$2b$", b"$2y$")})
    import base64

    def header(user: str, pw: str) -> str:
        return "Basic " + base64.b64encode(f"{user}:{pw}".encode()).decode()

    assert auth.check(header("prom", "s3cret"))
    assert auth.check(header("prom", "s3cret"))  # cached path
    assert not auth.check(header("prom", "wrong"))
    assert not auth.check(header("other", "s3cret"))
    assert not auth.check(None)
    assert not auth.check("Basic !!!notbase64")
    assert not auth.check("Bearer abc")


def test_web_config_validation(tmp_path: Path) -> None:
    bad = tmp_path / "web.yml"
    bad.write_text("tls_server_config:\n  cert_file: missing.crt\n  key_file: missing.key\n")
    with pytest.raises(ConfigError, match=r"tls_server_config\.cert_file.*does not exist"):
        load_web_config(bad)
    bad.write_text("basic_auth_users:\n  prom: plaintext\n")
    with pytest.raises(ConfigError, match="bcrypt"):
        load_web_config(bad)
    bad.write_text("basic_auth_user: {}\n")
    with pytest.raises(ConfigError, match="unknown key"):
        load_web_config(bad)
    good = tmp_path / "ok.yml"
    good.write_text(
        "basic_auth_users:\n  prom: '$2b$04$abcdefghijklmnopqrstuu5x5U1jL3S0sqk5v1h3Zk3CqZkS0Q5eW'\n"
    )
    cfg = load_web_config(good)
    assert set(cfg.basic_auth_users) == {"prom"} and not cfg.tls
