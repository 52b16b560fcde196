"""The optional ``[mqtt]`` section: publish every poll to an MQTT broker (``docs/mqtt.md``).

Off unless the section is present. Keys: ``host`` (required), ``port`` (1883, or 8883 with
TLS), ``tls`` (``{ ca_file, cert_file, key_file, verify = true }``), ``username`` and
``password_file`` (refused if others can read it), ``client_id``, ``topic_prefix`` (MQTT topic
levels without wildcards), ``gateway`` (this gateway's topic level, default the host name),
``qos`` (0 or 1), ``max_rate_hz`` (0: every poll; else at most that many frames per second per
device), ``encoding`` (``json`` or ``binary``), ``protocol`` (``5`` or ``3.1.1``) and
``queue_frames`` (the bounded queue between polling and the broker; the oldest frames are
dropped and counted when it is full), ``max_batch_frames`` (at most that many waiting polls of
a device in one message; 1: one message per poll) and ``batch_interval_s`` (while frames keep
coming, messages leave at most this often, so that the frames polled meanwhile share one).
"""

from __future__ import annotations

import re
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from ..errors import ConfigError
from ..model.params import Interval
from .tables import Context, Table, check_exists, check_private

__all__ = ["MQTT_ENCODINGS", "MQTT_PROTOCOLS", "MqttConfig", "MqttTls", "check_topic_level", "parse_mqtt"]

MQTT_ENCODINGS: Final = ("json", "binary")
MQTT_PROTOCOLS: Final = ("5", "3.1.1")
_KEYS: Final = (
    "host",
    "port",
    "tls",
    "username",
    "password_file",
    "client_id",
    "topic_prefix",
    "gateway",
    "qos",
    "max_rate_hz",
    "encoding",
    "protocol",
    "queue_frames",
    "max_batch_frames",
    "batch_interval_s",
)
_TLS_KEYS: Final = ("ca_file", "cert_file", "key_file", "verify")
_CLIENT_ID_RE: Final = re.compile(r"[A-Za-z0-9_.-]{1,64}")
_RATE: Final = Interval(0.0, 10_000.0, low_inclusive=True)
#: frames in one message at most: a 64-channel JSON frame is about 4.8 kB, so 1000 are about
#: 5 MB, well inside a broker's default message limit (mosquitto: 256 MB)
MAX_BATCH_FRAMES: Final = 1000
#: defaults measured with ``python -m bench mqtt`` (docs/scaling.md, section 5)
DEFAULT_MAX_BATCH_FRAMES: Final = 50
DEFAULT_BATCH_INTERVAL_S: Final = 0.01
_BATCH_INTERVAL: Final = Interval(0.0, 1.0, low_inclusive=True, high_inclusive=True)


@dataclass(frozen=True)
class MqttTls:
    ca_file: Path | None
    cert_file: Path | None
    key_file: Path | None
    verify: bool = True


@dataclass(frozen=True)
class MqttConfig:
    """Where and how frames are published; see the module docstring."""

    host: str
    port: int
    tls: MqttTls | None
    username: str | None
    password_file: Path | None
    client_id: str
    topic_prefix: str
    gateway: str
    qos: int = 1
    max_rate_hz: float = 0.0
    encoding: str = "json"
    protocol: str = "5"
    queue_frames: int = 1000
    max_batch_frames: int = DEFAULT_MAX_BATCH_FRAMES
    batch_interval_s: float = DEFAULT_BATCH_INTERVAL_S

    def __post_init__(self) -> None:
        check_topic_level("mqtt: topic_prefix", self.topic_prefix, allow_slash=True)
        check_topic_level("mqtt: gateway", self.gateway, allow_slash=False)
        if self.qos not in (0, 1):
            raise ConfigError(f"mqtt: qos: {self.qos!r} is not allowed; allowed: 0, 1")
        if not 1 <= self.max_batch_frames <= MAX_BATCH_FRAMES:
            raise ConfigError(
                f"mqtt: max_batch_frames: {self.max_batch_frames!r} is out of range; "
                f"allowed: 1..{MAX_BATCH_FRAMES}"
            )
        if not _BATCH_INTERVAL.contains(self.batch_interval_s):
            raise ConfigError(
                f"mqtt: batch_interval_s: {self.batch_interval_s!r} is out of range; "
                f"allowed: {_BATCH_INTERVAL.describe()} s"
            )

    def topic(self, *levels: str) -> str:
        """``<prefix>/<gateway>/<levels...>``."""
        return "/".join((self.topic_prefix, self.gateway, *levels))


def check_topic_level(where: str, value: str, *, allow_slash: bool) -> None:
    """``ConfigError`` unless ``value`` is usable in a topic name: not empty, no wildcards
    (``+``, ``#``), no NUL, no empty level, no leading or trailing ``/``, at most 1024 bytes
    (and no ``/`` at all where it is one level)."""
    reason = None
    if not value:
        reason = "is empty"
    elif any(c in value for c in "+#\0"):
        reason = "contains a wildcard (+ or #) or NUL; topic names may not"
    elif not allow_slash and "/" in value:
        reason = "contains '/'; it is one topic level"
    elif value.startswith("/") or value.endswith("/") or "//" in value:
        reason = "has an empty topic level (a leading, trailing or doubled '/')"
    elif value.startswith("$"):
        reason = "starts with '$' (reserved for the broker's own topics)"
    elif len(value.encode("utf-8")) > 1024:
        reason = "is longer than 1024 bytes"
    if reason is not None:
        raise ConfigError(f"{where}: {value!r} {reason}")


def default_gateway_name() -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname().split(".")[0]) or "gateway"
    return name[:64]


def parse_mqtt(ctx: Context, root: Table) -> MqttConfig | None:
    """The ``[mqtt]`` table, or None when absent."""
    if not root.has("mqtt"):
        return None
    table = root.table("mqtt", _KEYS, "[mqtt]")
    host = table.required_string("host", "the broker's host name or IP address")
    if not host or any(c.isspace() for c in host):
        raise table.error("host", f"{host!r} is not a host name or IP address")
    tls = None
    if table.has("tls"):
        t = table.table("tls", _TLS_KEYS, "[mqtt.tls]")
        tls = MqttTls(
            t.path_value("ca_file"),
            t.path_value("cert_file"),
            t.path_value("key_file"),
            t.boolean("verify", True),
        )
        if tls.ca_file is not None:
            check_exists(ctx, t.at("ca_file"), tls.ca_file, "CA certificates")
        if tls.cert_file is not None:
            check_exists(ctx, t.at("cert_file"), tls.cert_file, "client certificate")
        if tls.key_file is not None:
            if tls.cert_file is None:
                raise t.error("key_file", "needs cert_file as well (the certificate the key belongs to)")
            check_private(ctx, t.at("key_file"), tls.key_file, "the MQTT client key")
    port = table.integer("port", 8883 if tls is not None else 1883, 1, 65535)
    username = table.string("username", None, "a user name")
    password_file = table.path_value("password_file")
    if password_file is not None:
        if username is None:
            raise table.error("password_file", "needs username as well")
        check_private(ctx, table.at("password_file"), password_file, "the MQTT password")
    gateway = table.string("gateway", None, "this gateway's topic level") or default_gateway_name()
    prefix = table.string("topic_prefix", "tactile", "topic levels such as 'plant/a/tactile'") or "tactile"
    for key, value, slash in (("gateway", gateway, False), ("topic_prefix", prefix, True)):
        try:
            check_topic_level(key, value, allow_slash=slash)
        except ConfigError as exc:
            raise table.error(key, str(exc).split(": ", 1)[1]) from None
    client_id = table.string("client_id", None, "an MQTT client id") or f"tactile-gateway-{gateway}"[:64]
    if not _CLIENT_ID_RE.fullmatch(client_id):
        raise table.error("client_id", f"{client_id!r} is not allowed; allowed: [A-Za-z0-9_.-]{{1,64}}")
    prefix = (
        table.string("topic_prefix", "tactile", "topic levels such as 'plant/line3/tactile'") or "tactile"
    )
    data: dict[str, Any] = {
        "qos": table.integer("qos", 1, 0, 1),
        "max_rate_hz": table.number("max_rate_hz", 0.0, _RATE, " frames/s per device (0: every poll)"),
        "encoding": table.choice("encoding", "json", MQTT_ENCODINGS),
        "protocol": table.choice("protocol", "5", MQTT_PROTOCOLS),
        "queue_frames": table.integer("queue_frames", 1000, 1, 1_000_000),
        "max_batch_frames": table.integer(
            "max_batch_frames", DEFAULT_MAX_BATCH_FRAMES, 1, MAX_BATCH_FRAMES, " frames per message"
        ),
        "batch_interval_s": table.number(
            "batch_interval_s", DEFAULT_BATCH_INTERVAL_S, _BATCH_INTERVAL, " s (0: never wait)"
        ),
    }
    return MqttConfig(host, port, tls, username, password_file, client_id, prefix, gateway, **data)
