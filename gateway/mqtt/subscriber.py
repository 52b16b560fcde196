"""Receiving frames: what ``tactile-gateway subscribe`` runs (``docs/mqtt.md``).

The protocol side is pure and tested without a broker: ``SubscribeSettings`` names the
topics (the retained ``meta`` of each device, then its ``frame`` topic; the frames
optionally through a shared subscription ``$share/<group>/...``), ``FrameStream`` turns
messages into ``Frame`` objects (JSON frames as they are; binary frames decoded with the
channel names and encoding of the device's retained meta message, held back until that
message has arrived) and ``SequenceTracker`` notices gaps, duplicates and restarts in the
per-device sequence numbers. ``recordable`` and ``frame_clock_s`` give a frame's record
rows (``docs/record-format.md``; the CLI owns the writer).

``run_subscriber`` drives a paho client in the calling thread (no network thread to leak):
it connects, waits for the broker's answer, subscribes, and passes every message to a
callback until told to stop; a connection lost later is re-established with back-off.
Every failure to connect (refused, unknown host, TLS, credentials, no answer) is a
``SubscribeError`` with a one-line message.
"""

from __future__ import annotations

import json
import math
import random
import socket
import ssl
import stat
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTProtocolVersion

from ..config.mqtt import check_topic_level
from ..errors import ConfigError, GatewayError
from .payload import BINARY_MAGIC, FrameDecodeError, decode_binary

__all__ = [
    "Frame",
    "FrameStream",
    "SequenceTracker",
    "StreamStats",
    "SubscribeError",
    "SubscribeSettings",
    "frame_clock_s",
    "in_contact",
    "parse_broker",
    "read_password_file",
    "recordable",
    "run_subscriber",
]

#: Frames of a device kept while its retained meta message has not arrived (binary frames
#: need its channel names); beyond that the oldest are decoded with index names.
PENDING_LIMIT: Final = 2000
CONNECT_TIMEOUT_S: Final = 10.0
LOOP_TIMEOUT_S: Final = 0.05
BACKOFF_INITIAL_S: Final = 0.5
BACKOFF_MAX_S: Final = 10.0
_WITH_VALUE: Final = frozenset({"ok", "no_contact", "saturated"})
_CONTACT: Final = frozenset({"ok", "saturated"})


class SubscribeError(GatewayError):
    """The subscriber cannot (or can no longer) receive: the message is one line."""


# ---------------------------------------------------------------------------------- settings


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
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"--password-file: {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--password-file: cannot read {path}: {exc}") from None
    return text.splitlines()[0] if text else ""


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
    client_id: str = ""

    def __post_init__(self) -> None:
        check_topic_level("--prefix", self.prefix, allow_slash=True)
        _filter_level("--gateway", self.gateway)
        _filter_level("--device", self.device)
        if self.share_group is not None:
            check_topic_level("--share", self.share_group, allow_slash=False)

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


# ---------------------------------------------------------------------------------- frames


@dataclass(frozen=True)
class Frame:
    """One received frame: the fields of ``payload.frame_dict`` and where it came from.
    ``missing_before`` counts the frames of this device lost just before it (a gap);
    ``restarted`` says its sequence started again (a restarted gateway or publisher)."""

    gateway: str
    device: str
    fields: dict[str, Any]
    missing_before: int = 0
    restarted: bool = False

    @property
    def sequence(self) -> int:
        return int(self.fields["sequence"])

    @property
    def key(self) -> tuple[str, str]:
        return self.gateway, self.device

    def as_json(self) -> dict[str, Any]:
        return {"gateway": self.gateway, **self.fields}


def in_contact(fields: dict[str, Any]) -> list[str]:
    """Channel names in contact: status ok or saturated with a force above 0 (as the gateway
    counts ``channels_in_contact``)."""
    out = []
    for name, status, force in zip(fields["channels"], fields["status"], fields["force_n"], strict=False):
        if status in _CONTACT and force is not None and force > 0.0:
            out.append(str(name))
    return out


def frame_clock_s(fields: dict[str, Any]) -> float:
    """The frame's time for a record: the device clock when the frame has one, else the host's."""
    device_time = fields.get("device_time_s")
    return float(device_time) if device_time is not None else float(fields["host_time_s"])


def recordable(fields: dict[str, Any]) -> tuple[list[tuple[str, float]], int]:
    """A frame's record rows (channel, resistance in ohm) and how many channels have none.

    As ``tactile-gateway record``: an open channel is ``inf``; a channel whose status carries
    a value (ok, no_contact, saturated) records its resistance, ``inf`` when not finite; a
    short, stale or error channel has no row (counted). A frame of a device that was not
    polled successfully (``up`` false) has no rows at all.
    """
    if not fields.get("up", True):
        return [], len(fields["channels"])
    rows: list[tuple[str, float]] = []
    skipped = 0
    for name, status, r in zip(fields["channels"], fields["status"], fields["resistance_ohm"], strict=True):
        value = math.inf if r is None else float(r)
        if status == "open" or (status in _WITH_VALUE and not math.isfinite(value)):
            rows.append((str(name), math.inf))
        elif status in _WITH_VALUE and value > 0.0:
            rows.append((str(name), value))
        else:
            skipped += 1
    return rows, skipped


_FRAME_KEYS: Final = ("sequence", "host_time_s", "channels", "force_n", "resistance_ohm", "status")


def decode_json_frame(data: bytes, device: str) -> dict[str, Any]:
    """A JSON frame, checked for the fields a subscriber uses (``FrameDecodeError`` if not)."""
    try:
        fields = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FrameDecodeError(f"not a JSON frame: {exc}") from None
    if not isinstance(fields, dict):
        raise FrameDecodeError("not a JSON frame: not an object")
    missing = [k for k in _FRAME_KEYS if k not in fields]
    if missing:
        raise FrameDecodeError(f"a JSON frame without {', '.join(missing)}")
    seq = fields["sequence"]
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
        raise FrameDecodeError(f"a JSON frame with sequence {seq!r}")
    n = len(fields["channels"])
    if any(len(fields[k]) != n for k in ("force_n", "resistance_ohm", "status")):
        raise FrameDecodeError("a JSON frame whose channel lists differ in length")
    fields.setdefault("device", device)
    return fields


class SequenceTracker:
    """Per stream (gateway, device): the last sequence number, and what a new one means.

    The next number is in order; a larger one follows a gap of the numbers in between; 1
    after a larger number is a restart (the publisher counts from 1); any other smaller or
    equal number is a duplicate (QoS 1 may deliver twice) or late, and is dropped.
    """

    def __init__(self) -> None:
        self.last: dict[tuple[str, str], int] = {}
        self.missing = 0
        self.gaps = 0
        self.duplicates = 0
        self.restarts = 0

    def observe(self, key: tuple[str, str], seq: int) -> tuple[bool, int, bool]:
        """(accept, missing before it, restarted)."""
        last = self.last.get(key)
        if last is None or seq == last + 1:
            self.last[key] = seq
            return True, 0, False
        if seq > last + 1:
            missing = seq - last - 1
            self.missing += missing
            self.gaps += 1
            self.last[key] = seq
            return True, missing, False
        if seq == 1:
            self.restarts += 1
            self.last[key] = seq
            return True, 0, True
        self.duplicates += 1
        return False, 0, False


@dataclass
class StreamStats:
    frames: int = 0
    undecodable: int = 0
    meta: int = 0
    devices: set[tuple[str, str]] = field(default_factory=set)
    last_error: str | None = None


class FrameStream:
    """Messages in, frames out, in the order of each device's sequence numbers."""

    def __init__(self, prefix: str, pending_limit: int = PENDING_LIMIT) -> None:
        self.prefix_levels = prefix.split("/")
        self.pending_limit = pending_limit
        self.meta: dict[tuple[str, str], dict[str, Any]] = {}
        self.pending: dict[tuple[str, str], list[bytes]] = {}
        self.sequences = SequenceTracker()
        self.stats = StreamStats()

    def split_topic(self, topic: str) -> tuple[str, str, str] | None:
        """(gateway, device, kind) of ``<prefix>/<gateway>/<device>/<kind>``, else None."""
        levels = topic.split("/")
        n = len(self.prefix_levels)
        if len(levels) != n + 3 or levels[:n] != self.prefix_levels:
            return None
        gateway, device, kind = levels[n:]
        return (gateway, device, kind) if kind in ("frame", "meta") else None

    def feed(self, topic: str, payload: bytes) -> tuple[list[Frame], list[str]]:
        """The frames a message completes (none, one, or those held for a meta message) and
        notices for the user (a frame that could not be decoded)."""
        parts = self.split_topic(topic)
        if parts is None:
            return [], []
        gateway, device, kind = parts
        key = (gateway, device)
        if kind == "meta":
            return self._meta(key, payload)
        meta = self.meta.get(key)
        if meta is None and payload[:4] == BINARY_MAGIC:
            held = self.pending.setdefault(key, [])
            held.append(payload)
            if len(held) <= self.pending_limit:
                return [], []
            return self._decode(key, [held.pop(0)], None)
        return self._decode(key, [payload], meta)

    def flush(self) -> tuple[list[Frame], list[str]]:
        """Frames still held for a meta message that never came (index names as channels)."""
        frames: list[Frame] = []
        notices: list[str] = []
        for key, held in sorted(self.pending.items()):
            if held:
                notices.append(
                    f"{key[0]}/{key[1]}: no meta message arrived; {len(held)} binary frame(s) decoded "
                    "with channel numbers as names"
                )
            f, n = self._decode(key, held, None)
            frames += f
            notices += n
        self.pending.clear()
        return frames, notices

    def _meta(self, key: tuple[str, str], payload: bytes) -> tuple[list[Frame], list[str]]:
        if not payload:
            self.meta.pop(key, None)  # a retained message cleared
            return [], []
        try:
            meta = json.loads(payload)
            names = [str(c["name"]) for c in meta["channels"]]
            encoding = str(meta.get("encoding", "json"))
        except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as exc:
            self.stats.undecodable += 1
            return [], [f"{key[0]}/{key[1]}: an unreadable meta message ({exc!r})"]
        self.stats.meta += 1
        self.meta[key] = {"channels": names, "encoding": encoding}
        held = self.pending.pop(key, [])
        return self._decode(key, held, self.meta[key]) if held else ([], [])

    def _decode(
        self, key: tuple[str, str], payloads: list[bytes], meta: dict[str, Any] | None
    ) -> tuple[list[Frame], list[str]]:
        frames: list[Frame] = []
        notices: list[str] = []
        for payload in payloads:
            try:
                fields = self._fields(key, payload, meta)
            except FrameDecodeError as exc:
                self.stats.undecodable += 1
                self.stats.last_error = str(exc)
                notices.append(f"{key[0]}/{key[1]}: a frame could not be decoded: {exc}")
                continue
            accept, missing, restarted = self.sequences.observe(key, int(fields["sequence"]))
            if not accept:
                continue
            self.stats.frames += 1
            self.stats.devices.add(key)
            frames.append(Frame(key[0], key[1], fields, missing, restarted))
        return frames, notices

    @staticmethod
    def _fields(key: tuple[str, str], payload: bytes, meta: dict[str, Any] | None) -> dict[str, Any]:
        binary = payload[:4] == BINARY_MAGIC if meta is None else meta["encoding"] == "binary"
        if not binary:
            return decode_json_frame(payload, key[1])
        names = None if meta is None else list(meta["channels"])
        fields = decode_binary(payload, key[1], names)
        if names is not None and len(fields["force_n"]) != len(names):
            raise FrameDecodeError(
                f"the frame has {len(fields['force_n'])} channels, its meta message names {len(names)}"
            )
        return fields


# ---------------------------------------------------------------------------------- the client


def _reason_text(reason: Any) -> str:
    return str(getattr(reason, "getName", lambda: reason)())


def _connect_error(settings: SubscribeSettings, exc: BaseException) -> SubscribeError:
    where = settings.where()
    if isinstance(exc, ssl.SSLCertVerificationError):
        detail = exc.verify_message or exc.reason or str(exc)
        return SubscribeError(
            f"TLS: the certificate of {where} is not trusted (certificate verify failed: {detail})"
        )
    if isinstance(exc, ssl.SSLError):
        return SubscribeError(f"TLS handshake with {where} failed: {exc.reason or exc}")
    if isinstance(exc, ConnectionRefusedError):
        return SubscribeError(f"cannot connect to {where}: connection refused (is the broker running?)")
    if isinstance(exc, socket.gaierror):
        return SubscribeError(f"cannot connect to {where}: unknown host ({exc.strerror or exc})")
    if isinstance(exc, TimeoutError | socket.timeout):
        return SubscribeError(f"cannot connect to {where}: timed out")
    if isinstance(exc, OSError):
        return SubscribeError(f"cannot connect to {where}: {exc.strerror or exc}")
    return SubscribeError(f"cannot connect to {where}: {exc}")


class _Session:
    """The paho callbacks' state, for one client."""

    def __init__(self, settings: SubscribeSettings, on_message: Callable[[str, bytes], None]) -> None:
        self.settings = settings
        self.on_message = on_message
        self.connack: str | None = None  # None: no answer yet; "" accepted; else the refusal
        self.subscribed = False
        self.suback_error: str | None = None

    def connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if getattr(reason, "is_failure", False):
            self.connack = _reason_text(reason)
            return
        self.connack = ""
        client.subscribe([(t, 1) for t in self.settings.topics()])

    def subscribe(self, client: mqtt.Client, userdata: Any, mid: int, codes: Any, props: Any) -> None:
        refused = [c for c in codes if getattr(c, "is_failure", False)]
        if refused:
            self.suback_error = _reason_text(refused[0])
        self.subscribed = True

    def message(self, client: mqtt.Client, userdata: Any, msg: mqtt.MQTTMessage) -> None:
        self.on_message(msg.topic, bytes(msg.payload))


def _make_client(
    settings: SubscribeSettings, session: _Session, factory: Callable[..., mqtt.Client]
) -> mqtt.Client:
    client = factory(
        callback_api_version=CallbackAPIVersion.VERSION2,
        client_id=settings.client_id,
        protocol=MQTTProtocolVersion.MQTTv311,
        clean_session=True,
        reconnect_on_failure=False,
    )
    if settings.username is not None:
        client.username_pw_set(settings.username, settings.password)
    if settings.tls_ca is not None:
        try:
            client.tls_set(ca_certs=str(settings.tls_ca), cert_reqs=ssl.CERT_REQUIRED)
        except (OSError, ssl.SSLError) as exc:
            raise SubscribeError(f"--tls-ca: cannot use {settings.tls_ca}: {exc}") from None
    client.on_connect = session.connect
    client.on_subscribe = session.subscribe
    client.on_message = session.message
    return client


def _establish(client: mqtt.Client, session: _Session, should_stop: Callable[[], bool]) -> bool:
    """Connect and subscribe; False if told to stop first. ``SubscribeError`` on failure."""
    settings = session.settings
    session.connack, session.subscribed, session.suback_error = None, False, None
    try:
        client.connect(settings.host, settings.port, keepalive=30)
    except (OSError, ValueError, ssl.SSLError) as exc:
        raise _connect_error(settings, exc) from None
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    while not session.subscribed:
        if should_stop():
            return False
        if session.connack:
            raise SubscribeError(f"the broker {settings.where()} refused the connection: {session.connack}")
        if time.monotonic() > deadline:
            what = "the connection" if session.connack is None else "the subscription"
            raise SubscribeError(f"no answer from {settings.where()} to {what} in {CONNECT_TIMEOUT_S:g} s")
        rc = client.loop(timeout=LOOP_TIMEOUT_S)
        if rc != mqtt.MQTT_ERR_SUCCESS and not session.connack:
            raise SubscribeError(
                f"the broker {settings.where()} closed the connection ({mqtt.error_string(rc)}); "
                "wrong port, or TLS expected?"
            )
    if session.suback_error is not None:
        raise SubscribeError(
            f"the broker {settings.where()} refused the subscription to "
            f"{', '.join(settings.topics())}: {session.suback_error}"
        )
    return True


def run_subscriber(
    settings: SubscribeSettings,
    on_message: Callable[[str, bytes], None],
    should_stop: Callable[[], bool],
    notice: Callable[[str], None],
    *,
    client_factory: Callable[..., mqtt.Client] = mqtt.Client,
    rng: random.Random | None = None,
) -> None:
    """Receive until ``should_stop()``; messages go to ``on_message(topic, payload)`` in this
    thread. A failure to connect the first time is a ``SubscribeError``; a connection lost
    later is re-established (``notice`` says so; the frames in between show as a gap)."""
    session = _Session(settings, on_message)
    client = _make_client(settings, session, client_factory)
    rng = rng or random.Random()
    try:
        if not _establish(client, session, should_stop):
            return
        backoff = BACKOFF_INITIAL_S
        while not should_stop():
            rc = client.loop(timeout=LOOP_TIMEOUT_S)
            if rc == mqtt.MQTT_ERR_SUCCESS:
                continue
            notice(f"lost the connection to {settings.where()} ({mqtt.error_string(rc)}); reconnecting")
            while not should_stop():
                time.sleep(rng.uniform(0.0, backoff))
                try:
                    if _establish(client, session, should_stop):
                        notice(f"reconnected to {settings.where()}")
                        backoff = BACKOFF_INITIAL_S
                    break
                except SubscribeError as exc:
                    if session.connack:  # refused after a restart: the credentials changed
                        raise
                    backoff = min(BACKOFF_MAX_S, 2.0 * backoff)
                    notice(f"{exc}; retrying")
    finally:
        if session.connack == "":
            client.disconnect()
            for _ in range(20):  # write the DISCONNECT packet; loop() fails once the socket is closed
                if client.loop(timeout=LOOP_TIMEOUT_S) != mqtt.MQTT_ERR_SUCCESS:
                    break
