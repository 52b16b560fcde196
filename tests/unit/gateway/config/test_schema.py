"""The schema's dataclasses check their own values, so a configuration built in code is held
to the same rules as one read from a file; the messages state the allowed range."""

from __future__ import annotations

import dataclasses
import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.config.layout import GridLayout
from gateway.config.schema import BusConfig, ChannelConfig, DeviceConfig, MetricsConfig
from gateway.errors import ConfigError
from gateway.model import PAPER_EFFECTS, SensorParams

DEVICE = device_config_for("arr", 1, [SensorParams()] * 4, 2, 2.5)
BUS = bus_config_for("line", "tcp", [DEVICE], host="127.0.0.1", port=502)
CHANNEL = DEVICE.channels[0]


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: dataclasses.replace(BUS, timeout_s=0.0),
            "bus 'line': timeout_s: 0.0 is out of range; allowed: (0, 60] s",
        ),
        (
            lambda: dataclasses.replace(BUS, retries=11),
            "bus 'line': retries: 11 is out of range; allowed: 0..10",
        ),
        (lambda: dataclasses.replace(BUS, port=0), "bus 'line': port: 0 is out of range; allowed: 1..65535"),
        (
            lambda: dataclasses.replace(BUS, kind="can"),
            "bus 'line': kind: 'can' is not allowed; allowed: 'tcp', 'rtu'",
        ),
        (
            lambda: dataclasses.replace(BUS, backoff_initial_s=5.0, backoff_max_s=1.0),
            "backoff_max_s: 1.0 is out of range; allowed: [5, 3600] s (>= backoff_initial_s)",
        ),
        (lambda: dataclasses.replace(BUS, devices=(DEVICE, DEVICE)), "duplicate device_id"),
        (lambda: dataclasses.replace(BUS, tls=None, kind="tls"), "kind 'tls' needs TLS settings"),
        (
            lambda: dataclasses.replace(DEVICE, device_id=0),
            "device 'arr': device_id: 0 is out of range; allowed: 1..247",
        ),
        (
            lambda: dataclasses.replace(DEVICE.layout, columns=5),
            "columns: 5 is out of range; allowed: 1..4 (at most channels = 4)",
        ),
        (
            lambda: dataclasses.replace(DEVICE, layout=GridLayout(5, 2, 1.0, 1.0)),
            "layout: expected a GridLayout of 4 channels",
        ),
        (
            lambda: dataclasses.replace(DEVICE.layout, origin="centre"),
            "origin: 'centre' is not allowed; allowed: top-left, top-right, bottom-left, bottom-right",
        ),
        (
            lambda: dataclasses.replace(DEVICE, encoding="int16"),
            "encoding: 'int16' is not allowed; allowed: 'adc', 'float32'",
        ),
        (
            lambda: dataclasses.replace(DEVICE, channels=DEVICE.channels[:3]),
            "3 channel entries for channels = 4",
        ),
        (
            lambda: dataclasses.replace(CHANNEL, x_mm=2e4),
            "channel 'ch00': x_mm: 20000.0 is out of range; allowed: [-10000, 10000] mm",
        ),
        (lambda: dataclasses.replace(CHANNEL, effects=("creep", "tunneling")), "must be in canonical order"),
        (lambda: dataclasses.replace(CHANNEL, effects=("tunneling", "creeep")), "unknown effect 'creeep'"),
        (lambda: MetricsConfig(port=70000), "metrics: port: 70000 is out of range; allowed: 1..65535"),
        (lambda: gateway_config_for([BUS, BUS]), "duplicate bus name"),
    ],
)
def test_out_of_range_values_are_refused_with_the_allowed_range(build: object, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        build()  # type: ignore[operator]


@settings(max_examples=60, deadline=None)
@given(st.floats(allow_nan=True, allow_infinity=True))
def test_a_timeout_is_accepted_exactly_inside_zero_to_sixty_seconds(timeout_s: float) -> None:
    if 0.0 < timeout_s <= 60.0:
        assert dataclasses.replace(BUS, timeout_s=timeout_s).timeout_s == timeout_s
    else:
        with pytest.raises(ConfigError, match="timeout_s"):
            dataclasses.replace(BUS, timeout_s=timeout_s)


@settings(max_examples=60, deadline=None)
@given(st.integers(min_value=-1000, max_value=1000))
def test_a_device_id_is_accepted_exactly_in_1_to_247(device_id: int) -> None:
    if 1 <= device_id <= 247:
        assert dataclasses.replace(DEVICE, device_id=device_id).device_id == device_id
    else:
        with pytest.raises(ConfigError, match="device_id"):
            dataclasses.replace(DEVICE, device_id=device_id)


@settings(max_examples=60, deadline=None)
@given(st.floats(min_value=-2e4, max_value=2e4))
def test_a_position_is_accepted_exactly_within_ten_metres(x_mm: float) -> None:
    if -1e4 <= x_mm <= 1e4:
        assert dataclasses.replace(CHANNEL, x_mm=x_mm).x_mm == x_mm
    else:
        with pytest.raises(ConfigError, match="x_mm"):
            dataclasses.replace(CHANNEL, x_mm=x_mm)


def test_a_valid_configuration_built_from_the_dataclasses_directly() -> None:
    channels = tuple(
        ChannelConfig(i, f"c{i}", float(i), 0.0, True, PAPER_EFFECTS, SensorParams()) for i in range(2)
    )
    layout = GridLayout(2, 2, 1.0, 1.0)
    device = DeviceConfig("d", 3, "adc", 2, DEVICE.registers, DEVICE.front_end, channels, False, layout, None)
    bus = dataclasses.replace(BUS, devices=(device,))
    assert bus.devices[0].channel("c1").x_mm == 1.0
    assert isinstance(bus, BusConfig)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"word_order": "middle"}, "word_order: 'middle' is not allowed; allowed: 'big', 'little'"),
        ({"adc_address": 65536}, "adc_address: 65536 is out of range; allowed: 0..65535"),
        ({"status_address": -1}, "status_address: -1 is out of range; allowed: 0..65535"),
    ],
)
def test_a_register_map_checks_its_own_addresses(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        dataclasses.replace(DEVICE.registers, **changes)  # type: ignore[arg-type]
    assert dataclasses.replace(DEVICE.registers, status_address=None).status_address is None
