"""Publishing frames to a real Mosquitto broker (Debian's ``mosquitto``, an ephemeral loopback
port, TLS and a password file) from a gateway polling the simulated array."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
import pytest
from broker import Broker, make_tls_files
from netutil import free_port
from paho.mqtt.enums import CallbackAPIVersion, MQTTProtocolVersion

from gateway.config import load_config
from gateway.mqtt.publisher import MqttPublisher
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import GatewaySnapshot
from sim_device import ArrayConfig, SimArray
from sim_device.modbus_server import serve_tcp

BIN = Path(sys.executable).parent
PASSWORD = "s3cret-pw"


class Subscriber:
    """A paho client in its own network thread collecting the messages of ``topics``."""

    def __init__(self, port: int, topics: list[str], *, client_id: str = "", persistent: bool = False,
                 tls: dict[str, Path] | None = None) -> None:  # fmt: skip
        self.messages: list[tuple[str, bytes, bool]] = []
        self.lock = threading.Lock()
        self.client = mqtt.Client(
            callback_api_version=CallbackAPIVersion.VERSION2,
            client_id=client_id,
            protocol=MQTTProtocolVersion.MQTTv311,
            clean_session=not persistent,
        )
        self.client.username_pw_set("reader", PASSWORD)
        if tls is not None:
            self.client.tls_set(ca_certs=str(tls["ca.crt"]))
        self.topics = topics
        self.subscribed = threading.Event()
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *a: self.subscribed.set()
        self.client.on_message = self._on_message
        self.client.reconnect_delay_set(0.1, 0.5)
        self.client.connect("127.0.0.1", port, keepalive=10)
        self.client.loop_start()
        assert self.subscribed.wait(10.0), "the test subscriber could not subscribe"

    def _on_connect(self, client: mqtt.Client, *args: Any) -> None:
        client.subscribe([(t, 1) for t in self.topics])

    def _on_message(self, client: mqtt.Client, userdata: Any, msg: mqtt.MQTTMessage) -> None:
        with self.lock:
            self.messages.append((msg.topic, bytes(msg.payload), bool(msg.retain)))

    def of(self, suffix: str) -> list[bytes]:
        with self.lock:
            return [p for t, p, _ in self.messages if t.endswith(suffix)]

    def frames(self) -> list[dict[str, Any]]:
        """The JSON frames received, in order: a batch (``{"frames": [...]}``, docs/mqtt.md)
        is its frames."""
        out: list[dict[str, Any]] = []
        for payload in self.of("/frame"):
            obj = json.loads(payload)
            out += obj.get("frames", [obj])
        return out

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    b = Broker(tmp_path / "broker", users={"gw": PASSWORD, "reader": PASSWORD})
    b.start()
    try:
        yield b
    finally:
        b.stop()


def _config(
    tmp_path: Path, sim_port: int, broker_port: int, extra: str = "", password: str = PASSWORD
) -> Path:
    secret = tmp_path / "mqtt.pw"
    secret.write_text(password + "\n")
    secret.chmod(0o600)
    path = tmp_path / "gateway.toml"
    path.write_text(
        f'[metrics]\naddress = "127.0.0.1:{free_port()}"\n\n'
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker_port}\nusername = "gw"\npassword_file = "{secret}"\n'
        f'gateway = "gw1"\ntopic_prefix = "lab/tactile"\n{extra}\n'
        f'[[bus]]\nname = "sim"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {sim_port}\n'
        "poll_interval_s = 0.05\n\n"
        '[[bus.device]]\nname = "arr"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 4\ncolumns = 2\n'
    )
    path.chmod(0o600)
    return path


async def until(cond: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.02)
    return True


def _array() -> SimArray:
    return SimArray(ArrayConfig(channels=4, columns=2, scenario="indentation", speed=5.0, seed=2))


class Exported:
    """The gateway's own snapshots of a device, numbered like the publisher numbers frames."""

    def __init__(self) -> None:
        self.by_seq: dict[int, Any] = {}
        self._last: object = None

    def __call__(self, snapshot: GatewaySnapshot) -> None:
        dev = snapshot.devices.get("arr")
        if dev is not None and dev is not self._last and getattr(dev, "polled", True):
            self._last = dev
            self.by_seq[len(self.by_seq) + 1] = dev


async def test_every_frame_arrives_in_order_with_the_exported_values(tmp_path: Path, broker: Broker) -> None:
    array = _array()
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        config = load_config(_config(tmp_path, server.port, broker.port))
        sub = Subscriber(broker.port, ["lab/tactile/gw1/#"])
        holder = SnapshotHolder()
        exported = Exported()
        holder.subscribe(exported)
        publisher = MqttPublisher(config)
        holder.subscribe(publisher.on_snapshot)
        publisher.start()
        try:
            async with Poller(config, holder):
                # a 30 s run at 20 polls/s
                assert await until(lambda: len(exported.by_seq) >= 600, 60.0)
        finally:
            publisher.stop()
        stats = publisher.stats()
        assert await until(lambda: len(sub.frames()) >= stats.published.get("arr", 0), 10.0)
        sub.close()
    frames = sub.frames()
    seqs = [f["sequence"] for f in frames]
    assert seqs == list(range(1, len(exported.by_seq) + 1)), "every poll, in order, once"
    assert stats.dropped.get("arr", 0) == 0 and stats.published["arr"] == len(frames)
    for f in frames:
        snap = exported.by_seq[f["sequence"]]
        # published rounded to 6 decimals (docs/mqtt.md), exactly those values
        expected = [None if not np.isfinite(v) else round(float(v), 6) for v in snap.force_n]
        assert f["force_n"] == expected and f["device_time_s"] == round(snap.device_time_s, 6)
        assert f["channels"] == list(snap.channel_names)
    assert sub.of("/status")[-1] == b"offline"  # said on a clean stop
    meta = json.loads(sub.of("/arr/meta")[0])
    assert [c["name"] for c in meta["channels"]] == ["ch00", "ch01", "ch02", "ch03"]
    assert meta["units"]["force"] == "N" and meta["profile"] == "profile 'tactile-sim'"


async def _first_frames(tmp_path: Path, broker: Broker, sim_port: int, n: int) -> list[dict[str, Any]]:
    """The first ``n`` frames of device "arr" as a subscriber connected before the gateway
    started sees them."""
    config = load_config(_config(tmp_path, sim_port, broker.port))
    sub = Subscriber(broker.port, ["lab/tactile/gw1/arr/frame"])
    holder = SnapshotHolder()
    publisher = MqttPublisher(config)
    holder.subscribe(publisher.on_snapshot)
    publisher.start()
    try:
        async with Poller(config, holder):
            assert await until(lambda: len(sub.frames()) >= n, 20.0)
    finally:
        publisher.stop()
        sub.close()
    return sub.frames()[:n]


async def test_the_first_frame_is_the_first_poll_not_a_fake_outage(tmp_path: Path, broker: Broker) -> None:
    async with serve_tcp([_array()], host="127.0.0.1", port=0) as server:
        frames = await _first_frames(tmp_path, broker, server.port, 3)
    assert [f["sequence"] for f in frames] == [1, 2, 3]
    for f in frames:  # nothing is published before the first poll completes
        assert f["up"] is True and "stale" not in f["status"], f


async def test_a_device_that_fails_its_first_poll_is_published_down(tmp_path: Path, broker: Broker) -> None:
    frames = await _first_frames(tmp_path, broker, free_port(), 1)  # nothing listens there
    assert frames[0]["sequence"] == 1
    assert frames[0]["up"] is False and set(frames[0]["status"]) == {"stale"}


async def test_a_broker_restart_loses_only_the_counted_frames(tmp_path: Path, broker: Broker) -> None:
    array = _array()
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        config = load_config(_config(tmp_path, server.port, broker.port, "queue_frames = 20"))
        sub = Subscriber(broker.port, ["lab/tactile/gw1/arr/frame"], client_id="keeper", persistent=True)
        holder = SnapshotHolder()
        exported = Exported()
        holder.subscribe(exported)
        publisher = MqttPublisher(config)
        holder.subscribe(publisher.on_snapshot)
        publisher.start()
        try:
            async with Poller(config, holder):
                assert await until(lambda: len(sub.of("/frame")) >= 20, 20.0)
                # the subscriber's session must be on disk for a killed broker to bring it back
                db = broker.folder / "mosquitto.db"
                assert await until(db.exists, 10.0), "mosquitto never saved its database"
                # the poll rate with the broker up (publishing) ...
                start, t0 = len(exported.by_seq), time.monotonic()
                assert await until(lambda: len(exported.by_seq) >= start + 40, 20.0)
                rate_up = (len(exported.by_seq) - start) / (time.monotonic() - t0)
                broker.kill()
                # ... and with it gone (the publisher in its back-off): the same schedule
                before, t0 = len(exported.by_seq), time.monotonic()
                assert await until(lambda: len(exported.by_seq) >= before + 60, 20.0), "polling stalled"
                rate_down = (len(exported.by_seq) - before) / (time.monotonic() - t0)
                assert rate_down >= 0.95 * rate_up, (rate_down, rate_up)
                assert publisher.stats().dropped.get("arr", 0) > 0, "a 20-frame queue must overflow"
                broker.start()
                assert await until(lambda: publisher.stats().connected, 30.0), "no reconnect"
                after = len(exported.by_seq)
                assert await until(lambda: len(exported.by_seq) >= after + 20, 20.0)
        finally:
            publisher.stop()
        stats = publisher.stats()
        total = len(exported.by_seq)
        dropped = stats.dropped.get("arr", 0)
        try:
            await until(lambda: len({f["sequence"] for f in sub.frames()}) >= total - dropped, 20.0)
        finally:
            sub.close()
    received = {f["sequence"] for f in sub.frames()}
    assert len(received) + dropped == total, (len(received), dropped, total)
    assert received <= set(range(1, total + 1))


async def test_a_wrong_password_is_said_once_and_polling_carries_on(
    tmp_path: Path, broker: Broker, caplog: pytest.LogCaptureFixture
) -> None:
    array = _array()
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        config = load_config(_config(tmp_path, server.port, broker.port, password="wrong"))
        holder = SnapshotHolder()
        exported = Exported()
        holder.subscribe(exported)
        publisher = MqttPublisher(config)
        holder.subscribe(publisher.on_snapshot)
        with caplog.at_level(logging.WARNING, logger="gateway.mqtt"):
            publisher.start()
            try:
                async with Poller(config, holder):
                    assert await until(lambda: len(exported.by_seq) >= 40, 20.0), "polling must carry on"
            finally:
                publisher.stop()
    refused = [r.getMessage() for r in caplog.records if "refused the connection" in r.getMessage()]
    assert refused and ("Not authorized" in refused[0] or "Bad user name or password" in refused[0]), refused
    assert len(set(refused)) == 1
    assert not publisher.stats().connected and publisher.stats().published.get("arr", 0) == 0


async def test_tls_to_an_untrusted_broker_is_refused_and_a_trusted_one_works(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    files = make_tls_files(tmp_path / "tls")
    broker = Broker(tmp_path / "broker", users={"gw": PASSWORD, "reader": PASSWORD}, tls=files)
    broker.start()
    try:
        array = _array()
        async with serve_tcp([array], host="127.0.0.1", port=0) as server:
            for ca, works in ((files["other.crt"], False), (files["ca.crt"], True)):
                config = load_config(
                    _config(tmp_path, server.port, broker.port, f'tls = {{ ca_file = "{ca}" }}')
                )
                holder = SnapshotHolder()
                publisher = MqttPublisher(config)
                holder.subscribe(publisher.on_snapshot)
                caplog.clear()
                with caplog.at_level(logging.WARNING, logger="gateway.mqtt"):
                    publisher.start()
                    try:
                        async with Poller(config, holder):
                            ok = await until(
                                lambda p=publisher: p.stats().published.get("arr", 0) >= 10,
                                8.0 if works else 2.0,
                            )
                    finally:
                        publisher.stop()
                assert ok == works
                if not works:
                    messages = " ".join(r.getMessage() for r in caplog.records)
                    assert "certificate verify failed" in messages, messages
    finally:
        broker.stop()


def test_the_last_will_says_offline_when_the_gateway_is_killed(tmp_path: Path, broker: Broker) -> None:
    sim_port = free_port()
    sim = subprocess.Popen(
        [str(BIN / "tactile-sim"), "run", "--tcp", f"127.0.0.1:{sim_port}", "--channels", "4"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    sub = Subscriber(broker.port, ["lab/tactile/gw1/status", "lab/tactile/gw1/arr/frame"])
    gateway = None
    try:
        config = _config(tmp_path, sim_port, broker.port)
        gateway = subprocess.Popen(
            [str(BIN / "tactile-gateway"), "run", "-c", str(config)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        deadline = time.monotonic() + 20.0
        while len(sub.of("/frame")) < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(sub.of("/frame")) >= 5 and sub.of("/status")[-1] == b"online"
        os.kill(gateway.pid, signal.SIGKILL)
        gateway.wait(timeout=10)
        deadline = time.monotonic() + 10.0
        while sub.of("/status")[-1] != b"offline" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert sub.of("/status")[-1] == b"offline", "the broker published the last will"
    finally:
        sub.close()
        if gateway is not None and gateway.poll() is None:
            gateway.kill()
            gateway.wait(timeout=10)
        sim.terminate()
        sim.wait(timeout=10)


def test_a_sighup_moves_the_frames_to_a_new_topic_prefix(tmp_path: Path, broker: Broker) -> None:
    """The [mqtt] section is reloaded on SIGHUP: new broker settings restart the publisher."""
    sim_port = free_port()
    sim = subprocess.Popen(
        [str(BIN / "tactile-sim"), "run", "--tcp", f"127.0.0.1:{sim_port}", "--channels", "4"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    sub = Subscriber(broker.port, ["lab/tactile/gw1/arr/frame", "site/b/gw1/arr/frame", "site/b/gw1/status"])
    gateway = None
    try:
        config = _config(tmp_path, sim_port, broker.port)
        gateway = subprocess.Popen(
            [str(BIN / "tactile-gateway"), "run", "-c", str(config)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        deadline = time.monotonic() + 20.0
        while len(sub.of("lab/tactile/gw1/arr/frame")) < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(sub.of("lab/tactile/gw1/arr/frame")) >= 5
        config.write_text(
            config.read_text().replace('topic_prefix = "lab/tactile"', 'topic_prefix = "site/b"')
        )
        gateway.send_signal(signal.SIGHUP)
        deadline = time.monotonic() + 20.0
        while len(sub.of("site/b/gw1/arr/frame")) < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(sub.of("site/b/gw1/arr/frame")) >= 5, "no frames under the new prefix"
        assert b"online" in sub.of("site/b/gw1/status")
        assert gateway.poll() is None, "the gateway kept running"
    finally:
        sub.close()
        if gateway is not None and gateway.poll() is None:
            gateway.terminate()
            gateway.wait(timeout=20)
        sim.terminate()
        sim.wait(timeout=10)
