"""Which broker and which frames ``tactile-gateway subscribe`` receives: the broker address,
the password file, the topic filters and the session (a fixed client id and how long the
broker keeps the session of a lost subscriber; ``docs/mqtt.md``). Pure: no network.
"""

from __future__ import annotations

import hashlib
import re
import socket
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from ..config.mqtt import check_topic_level
from ..config.tables import read_text_file
from ..errors import ConfigError


def parse_broker(text: str, tls: bool) -> tuple[str, int]:
    """``HOST``, ``HOST:PORT`` or ``[V6]:PORT`` into host and port (1883, or 8883 with TLS)."""
    spec = text.strip()
    default = 8883 if tls else 1883
    host, port_text = spec, ""
    if spec.startswith("["):
        end = spec.find("]")
        if end < 0:
            raise ConfigError(f"--broker: {text!r} has '[' without ']'")
        host, rest = spec[1:end], spec[end + 1 :]
        if rest and not rest.startswith(":"):
            raise ConfigError(f"--broker: {text!r} is not [HOST]:PORT")
        port_text = rest[1:]
    elif spec.count(":") == 1:
        host, port_text = spec.split(":")
    if not host or any(c.isspace() for c in host):
        raise ConfigError(f"--broker: {text!r} has no host name or IP address")
    if not port_text:
        return host, default
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ConfigError(f"--broker: port {port_text!r} is not in 1..65535")
    return host, int(port_text)


def read_password_file(path: Path) -> str:
    """The first line of a password file; refused if other users may read it (as in ``[mqtt]``)."""
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
        if not path.is_file():
            raise ConfigError(f"--password-file: {path} is not a regular file")
        if mode & 0o077:
            raise ConfigError(
                f"--password-file: {path} holds a secret but is accessible to other users "
                f"(mode {mode:04o}): run `chmod 600 {path}`"
            )
        text = read_text_file(path, "password file")
    except FileNotFoundError:
        raise ConfigError(f"--password-file: {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--password-file: cannot read {path}: {exc}") from None
    return text.splitlines()[0] if text else ""


SESSION_EXPIRY_S: Final = 3600
CLIENT_ID_MAX: Final = 64


def default_client_id(prefix: str, gateway: str, device: str, share_group: str | None, host: str = "") -> str:
    """A client id fixed for this host and these topic filters, so a restarted ``subscribe``
    (or the same one after a lost connection) finds its session again:
    ``tactile-sub-<host>-<8 hex of the filters>``."""
    host = re.sub(r"[^A-Za-z0-9-]", "-", host or socket.gethostname())[:32] or "host"
    filters = "\0".join([prefix, gateway, device, share_group or ""])
    return f"tactile-sub-{host}-{hashlib.sha256(filters.encode()).hexdigest()[:8]}"


def _filter_level(where: str, value: str) -> str:
    if value == "+":
        return value
    check_topic_level(where, value, allow_slash=False)
    return value


@dataclass(frozen=True)
class SubscribeSettings:
    """Which broker and which frames: ``gateway``/``device`` are one topic level or ``+``."""

    host: str
    port: int
    tls_ca: Path | None = None
    username: str | None = None
    password: str | None = None
    prefix: str = "tactile"
    gateway: str = "+"
    device: str = "+"
    share_group: str | None = None
    client_id: str = ""  # "" : ``default_client_id`` of the filters and this host
    session_expiry_s: int = SESSION_EXPIRY_S  # how long the broker keeps the session of a lost client

    def __post_init__(self) -> None:
        check_topic_level("--prefix", self.prefix, allow_slash=True)
        _filter_level("--gateway", self.gateway)
        _filter_level("--device", self.device)
        if self.share_group is not None:
            check_topic_level("--share", self.share_group, allow_slash=False)
        if not self.client_id:
            cid = default_client_id(self.prefix, self.gateway, self.device, self.share_group)
            object.__setattr__(self, "client_id", cid)
        elif len(self.client_id) > CLIENT_ID_MAX or not self.client_id.isprintable():
            raise ConfigError(
                f"--client-id: {self.client_id!r} is not 1..{CLIENT_ID_MAX} printable characters"
            )
        if not 0 <= self.session_expiry_s <= 0xFFFFFFFF:
            raise ConfigError(f"--session-expiry: {self.session_expiry_s} s is not in 0..4294967295")

    def topics(self) -> list[str]:
        """The topic filters, meta first: the broker sends retained messages on subscribing.
        A shared subscription gets no retained messages, so meta is never shared."""
        base = f"{self.prefix}/{self.gateway}/{self.device}"
        frames = f"{base}/frame"
        if self.share_group is not None:
            frames = f"$share/{self.share_group}/{frames}"
        return [f"{base}/meta", frames]

    def where(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"
