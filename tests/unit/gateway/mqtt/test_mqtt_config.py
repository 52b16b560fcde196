"""The ``[mqtt]`` section and topic levels: what is refused at load, with which message."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from gateway.config import parse_config
from gateway.config.mqtt import MqttConfig, check_topic_level
from gateway.errors import ConfigError

BASE = """\
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 4
"""


def parse(mqtt: str, folder: Path) -> MqttConfig | None:
    return parse_config(BASE + "\n[mqtt]\n" + mqtt + "\n", source=folder / "gateway.toml").mqtt


def secret(folder: Path, name: str = "pw", mode: int = 0o600) -> Path:
    path = folder / name
    path.write_text("pw\n")
    path.chmod(mode)
    return path


@pytest.mark.parametrize("level", ["tactile", "plant/line3/tactile", "a-b_c.d", "ünï"])
def test_usable_topic_prefixes(level: str) -> None:
    check_topic_level("prefix", level, allow_slash=True)


@pytest.mark.parametrize(
    ("value", "allow_slash", "fragment"),
    [
        ("", True, "is empty"),
        ("plant/+/x", True, "wildcard"),
        ("plant/#", True, "wildcard"),
        ("a\0b", True, "NUL"),
        ("/plant", True, "empty topic level"),
        ("plant/", True, "empty topic level"),
        ("plant//x", True, "empty topic level"),
        ("$SYS", True, "reserved"),
        ("$share/g", True, "reserved"),
        ("a/b", False, "one topic level"),
        ("x" * 1025, True, "longer than 1024 bytes"),
    ],
)
def test_unusable_topic_levels(value: str, allow_slash: bool, fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment) as info:
        check_topic_level("mqtt: topic_prefix", value, allow_slash=allow_slash)
    assert str(info.value).startswith("mqtt: topic_prefix: ")


def test_absent_section_is_off_and_defaults_are_filled(tmp_path: Path) -> None:
    assert parse_config(BASE).mqtt is None
    cfg = parse('host = "broker"\ngateway = "gw1"', tmp_path)
    assert cfg is not None
    assert (cfg.port, cfg.qos, cfg.encoding, cfg.protocol, cfg.topic_prefix) == (
        1883,
        1,
        "json",
        "5",
        "tactile",
    )
    assert cfg.client_id == "tactile-gateway-gw1" and cfg.topic("arr", "frame") == "tactile/gw1/arr/frame"


def test_tls_changes_the_default_port(tmp_path: Path) -> None:
    ca = tmp_path / "ca.crt"
    ca.write_text("x")
    cfg = parse(f'host = "broker"\ntls = {{ ca_file = "{ca}" }}', tmp_path)
    assert cfg is not None and cfg.port == 8883 and cfg.tls is not None and cfg.tls.verify


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        ("port = 1883", ("host",)),
        ("host = 5", ("host",)),
        ('host = "a b"', ("not a host name",)),
        ('host = "b"\nport = "1883"', ("port",)),
        ('host = "b"\nport = 70000', ("port", "65535")),
        ('host = "b"\nqos = 2', ("qos", "2")),
        ('host = "b"\nqos = "1"', ("qos",)),
        ('host = "b"\nencoding = "xml"', ("encoding", "xml")),
        ('host = "b"\nprotocol = "3"', ("protocol",)),
        ('host = "b"\nmax_rate_hz = -1', ("max_rate_hz",)),
        ('host = "b"\nqueue_frames = 0', ("queue_frames",)),
        ('host = "b"\ntopic_prefix = "a/+/b"', ("topic_prefix", "wildcard")),
        ('host = "b"\ntopic_prefix = "$SYS"', ("topic_prefix", "reserved")),
        ('host = "b"\nclient_id = "c"\ngateway = "a/b"', ("gateway", "one topic level")),
        ('host = "b"\nclient_id = "c"\ngateway = "g+"', ("gateway", "wildcard")),
        ('host = "b"\nclient_id = "has space"', ("client_id",)),
        ('host = "b"\nunknown = 1', ("unknown",)),
        ('host = "b"\ntls = { verify = "yes" }', ("verify",)),
        ('host = "b"\ntls = { ca_file = "/nonexistent/ca.crt" }', ("ca_file", "does not exist")),
    ],
)
def test_bad_values_are_refused_naming_the_key(tmp_path: Path, text: str, fragments: tuple[str, ...]) -> None:
    with pytest.raises(ConfigError) as info:
        parse(text, tmp_path)
    message = str(info.value)
    assert "mqtt" in message, message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_a_password_file_others_can_read_is_refused(tmp_path: Path) -> None:
    pw = secret(tmp_path, mode=0o644)
    with pytest.raises(ConfigError, match="accessible to other users") as info:
        parse(f'host = "b"\nusername = "gw"\npassword_file = "{pw}"', tmp_path)
    assert "chmod 600" in str(info.value) and "password_file" in str(info.value)
    pw.chmod(0o640)
    with pytest.raises(ConfigError, match="0640"):
        parse(f'host = "b"\nusername = "gw"\npassword_file = "{pw}"', tmp_path)
    pw.chmod(0o600)
    cfg = parse(f'host = "b"\nusername = "gw"\npassword_file = "{pw}"', tmp_path)
    assert cfg is not None and cfg.password_file == pw


def test_a_password_file_needs_a_user_and_must_exist(tmp_path: Path) -> None:
    pw = secret(tmp_path)
    with pytest.raises(ConfigError, match="needs username"):
        parse(f'host = "b"\npassword_file = "{pw}"', tmp_path)
    with pytest.raises(ConfigError, match="does not exist"):
        parse(f'host = "b"\nusername = "gw"\npassword_file = "{tmp_path / "nope"}"', tmp_path)


def test_a_key_file_needs_its_certificate_and_must_be_private(tmp_path: Path) -> None:
    key = secret(tmp_path, "client.key")
    with pytest.raises(ConfigError, match="needs cert_file"):
        parse(f'host = "b"\ntls = {{ key_file = "{key}" }}', tmp_path)
    cert = tmp_path / "client.crt"
    cert.write_text("x")
    key.chmod(0o604)
    with pytest.raises(ConfigError, match="accessible to other users"):
        parse(f'host = "b"\ntls = {{ cert_file = "{cert}", key_file = "{key}" }}', tmp_path)
    key.chmod(0o600)
    cfg = parse(f'host = "b"\ntls = {{ cert_file = "{cert}", key_file = "{key}" }}', tmp_path)
    assert cfg is not None and cfg.tls is not None and cfg.tls.key_file == key


def test_relative_secret_paths_are_anchored_at_the_config_file(tmp_path: Path) -> None:
    secret(tmp_path)
    cfg = parse('host = "b"\nusername = "gw"\npassword_file = "pw"', tmp_path)
    assert cfg is not None and cfg.password_file == tmp_path / "pw"
    assert os.path.isabs(cfg.password_file)


def test_the_dataclass_refuses_qos_2_and_bad_levels_itself() -> None:
    with pytest.raises(ConfigError, match="qos"):
        MqttConfig("b", 1883, None, None, None, "c", "tactile", "gw", qos=2)
    with pytest.raises(ConfigError, match="gateway"):
        MqttConfig("b", 1883, None, None, None, "c", "tactile", "g+w")
