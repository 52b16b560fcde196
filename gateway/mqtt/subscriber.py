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
The session is persistent (MQTT 5: a fixed client id, clean start off, a session expiry,
QoS 1 subscriptions): the broker queues the frames published while the subscriber is away
(a lost connection, a broker restart with persistence, a killed subscriber) and delivers
them when it comes back. A deliberate end (``should_stop``) ends the session, so the next
run does not start with an old backlog.
Every failure to connect (refused, unknown host, TLS, credentials, no answer) is a
``SubscribeError`` with a one-line message.

The pieces live apart: ``subscribe_settings`` (broker, password file, topics),
``frame_stream`` (messages into frames, sequence bookkeeping) and ``frame_rows`` (a frame's
contacts, clock and record rows); this module is the paho client loop and re-exports them.
"""

from __future__ import annotations

import random
import socket
import ssl
import time
from collections.abc import Callable
from typing import Any, Final

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTProtocolVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from ..errors import GatewayError
from .frame_rows import frame_clock_s, in_contact, recordable
from .frame_stream import PENDING_BYTES_LIMIT as PENDING_BYTES_LIMIT
from .frame_stream import PENDING_LIMIT as PENDING_LIMIT
from .frame_stream import Frame, FrameStream, SequenceTracker, StreamStats
from .frame_stream import decode_json_frame as decode_json_frame
from .subscribe_settings import SubscribeSettings, parse_broker, read_password_file

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

CONNECT_TIMEOUT_S: Final = 10.0
LOOP_TIMEOUT_S: Final = 0.05
BACKOFF_INITIAL_S: Final = 0.5
BACKOFF_MAX_S: Final = 10.0


class SubscribeError(GatewayError):
    """The subscriber cannot (or can no longer) receive: the message is one line."""


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
        self.session_present = False
        self.disconnect_reason: str | None = None

    def connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if getattr(reason, "is_failure", False):
            self.connack = _reason_text(reason)
            return
        self.connack = ""
        self.session_present = bool(getattr(flags, "session_present", False))
        # subscribed again even on a resumed session: harmless (the same filters, QoS 1), and
        # it brings the retained meta messages again
        client.subscribe([(t, 1) for t in self.settings.topics()])

    def disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        self.disconnect_reason = _reason_text(reason) if getattr(reason, "is_failure", False) else None

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
        protocol=MQTTProtocolVersion.MQTTv5,
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
    client.on_disconnect = session.disconnect
    return client


def _session_expiry(seconds: int, packet: int) -> Properties:
    props = Properties(packet)
    props.SessionExpiryInterval = seconds
    return props


def _establish(client: mqtt.Client, session: _Session, should_stop: Callable[[], bool]) -> bool:
    """Connect and subscribe; False if told to stop first. ``SubscribeError`` on failure."""
    settings = session.settings
    session.connack, session.subscribed, session.suback_error = None, False, None
    session.session_present, session.disconnect_reason = False, None
    try:
        client.connect(
            settings.host,
            settings.port,
            keepalive=30,
            clean_start=False,
            properties=_session_expiry(settings.session_expiry_s, PacketTypes.CONNECT),
        )
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


def _wait(seconds: float, should_stop: Callable[[], bool]) -> bool:
    """Sleep ``seconds`` in short steps; True as soon as ``should_stop()`` (Ctrl-C during a
    back-off of up to ``BACKOFF_MAX_S`` ends the subscriber at once)."""
    deadline = time.monotonic() + seconds
    while not should_stop():
        left = deadline - time.monotonic()
        if left <= 0.0:
            return False
        time.sleep(min(0.1, left))
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
    later is re-established (``notice`` says so). The broker keeps the session meanwhile and
    delivers what was published while the subscriber was away; where it kept none (a restart
    without persistence, an expired session) ``notice`` says so and the frames in between
    show as a gap. Another client taking over the session (the same client id) is a
    ``SubscribeError``: two subscribers would otherwise throw each other out for ever."""
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
            if session.disconnect_reason == "Session taken over":
                raise SubscribeError(
                    f"another client connected to {settings.where()} with the client id "
                    f"{settings.client_id!r} and took over its session: "
                    "give each subscriber its own client id"
                )
            notice(f"lost the connection to {settings.where()} ({mqtt.error_string(rc)}); reconnecting")
            while not should_stop():
                if _wait(rng.uniform(0.0, backoff), should_stop):
                    break
                try:
                    if _establish(client, session, should_stop):
                        notice(f"reconnected to {settings.where()}")
                        if not session.session_present:
                            notice(
                                f"the broker kept no session for {settings.client_id!r} (restarted without "
                                "persistence, or the session expired): frames published meanwhile are lost"
                            )
                        backoff = BACKOFF_INITIAL_S
                    break
                except SubscribeError as exc:
                    if session.connack:  # refused after a restart: the credentials changed
                        raise
                    backoff = min(BACKOFF_MAX_S, 2.0 * backoff)
                    notice(f"{exc}; retrying")
    finally:
        if session.connack == "":
            # a deliberate end ends the session (expiry 0); an error keeps it for the next run
            ending = should_stop()
            client.disconnect(properties=_session_expiry(0, PacketTypes.DISCONNECT) if ending else None)
            for _ in range(20):  # write the DISCONNECT packet; loop() fails once the socket is closed
                if client.loop(timeout=LOOP_TIMEOUT_S) != mqtt.MQTT_ERR_SUCCESS:
                    break
