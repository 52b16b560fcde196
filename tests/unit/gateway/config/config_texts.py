"""Configuration texts and helpers shared by the config tests."""

from __future__ import annotations

from pathlib import Path

from gateway.config import GatewayConfig, parse_config

REPO = Path(__file__).resolve().parents[4]
SOURCE = Path("/cfg/gateway.toml")

BASE = """\
[metrics]
address = "127.0.0.1:9830"

[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 16
"""

RTU = """\
[[bus]]
name = "line"
kind = "rtu"
serial_port = "/dev/ttyUSB0"

[[bus.device]]
name = "rtu1"
device_id = 1
profile = "tactile-sim"
channels = 4
"""


def with_bus(extra: str) -> str:
    """BASE with ``extra`` keys in the [[bus]] table."""
    return BASE.replace("port = 5020\n", f"port = 5020\n{extra}\n")


def with_device(extra: str) -> str:
    """BASE with ``extra`` keys (or sub-tables) at the end of the [[bus.device]] table."""
    return BASE + extra + "\n"


def replaced(old: str, new: str, text: str = BASE) -> str:
    assert old in text, old
    return text.replace(old, new)


def parse(text: str, source: Path | None = SOURCE) -> GatewayConfig:
    return parse_config(text, source=source)
