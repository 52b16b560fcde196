"""The ``[foxglove]`` table: its defaults, and precise refusals that state what is allowed."""

from __future__ import annotations

import pytest
from foxglove_helpers import hand_config

from gateway.config.foxglove import DEFAULT_FOXGLOVE_PORT, FoxgloveConfig
from gateway.errors import ConfigError


def test_absent_is_off_and_an_empty_table_serves_every_device_on_loopback() -> None:
    assert hand_config().foxglove is None
    settings = hand_config("\n[foxglove]\n").foxglove
    assert settings == FoxgloveConfig("127.0.0.1", DEFAULT_FOXGLOVE_PORT, None, 100)
    assert DEFAULT_FOXGLOVE_PORT == 8765  # Foxglove's own default
    assert settings.serves("hand") and settings.serves("other")


def test_keys_are_read() -> None:
    text = '\n[foxglove]\nhost = "0.0.0.0"\nport = 9000\ndevices = ["hand"]\nqueue_frames = 7\n'
    settings = hand_config(text).foxglove
    assert settings == FoxgloveConfig("0.0.0.0", 9000, ("hand",), 7)
    assert not settings.serves("other")


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("port = 70000", "foxglove.port: 70000 is out of range; allowed: 0..65535 (0: any free port)"),
        ("port = -1", "foxglove.port: -1 is out of range; allowed: 0..65535"),
        ('port = "8765"', "foxglove.port: expected an integer in 0..65535"),
        ('host = ""', "foxglove.host: '' is not a host name or IP address"),
        ('host = "a b"', "foxglove.host: 'a b' is not a host name or IP address"),
        ('devices = ["palm"]', "foxglove.devices: no device called 'palm'; allowed: 'hand'"),
        ("devices = []", "foxglove.devices: expected a non-empty list of device names"),
        ('devices = "hand"', "foxglove.devices: expected a non-empty list of device names"),
        ('devices = ["hand", "hand"]', "foxglove.devices: a device is named twice"),
        ("queue_frames = 0", "foxglove.queue_frames: 0 is out of range; allowed: 1..100000 frames"),
        ("colour = 1", "foxglove.colour"),
    ],
)
def test_bad_values_are_refused_with_what_is_allowed(body: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        hand_config(f"\n[foxglove]\n{body}\n")
    assert message in str(info.value)


def test_the_dataclass_checks_its_ranges_too() -> None:
    with pytest.raises(ConfigError, match=r"foxglove: port: 65536 is out of range; allowed: 0..65535"):
        FoxgloveConfig(port=65536)
    with pytest.raises(ConfigError, match=r"queue_frames: 0 is out of range; allowed: 1..100000"):
        FoxgloveConfig(queue_frames=0)
