"""Batches through a real Mosquitto (issue 33 §13): a gateway polling the simulated array back to
back publishes several polls per message; ``tactile-gateway subscribe``, a separate process,
records them, and every frame is there, in order, with its own sequence number and the values
the gateway exported for that poll."""

from __future__ import annotations

import asyncio
import json
import math
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from broker import Broker
from netutil import free_port
from waiting import until

from gateway.analysis.records import read_record
from gateway.config import load_config
from gateway.mqtt.publisher import MqttPublisher
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import STATUS_LABELS, GatewaySnapshot
from sim_device import ArrayConfig, SimArray
from sim_device.modbus_server import serve_tcp

pytestmark = [pytest.mark.broker, pytest.mark.slow]

BIN = Path(sys.executable).parent
FRAMES = 200
WITH_VALUE = {"ok", "no_contact", "saturated", "extrapolated", "no_zero"}


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    b = Broker(tmp_path / "broker", persistence=False)
    b.start()
    try:
        yield b
    finally:
        b.stop()


def _config(tmp_path: Path, sim_port: int, broker_port: int, encoding: str) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(
        f'[metrics]\naddress = "127.0.0.1:{free_port()}"\n\n'
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker_port}\ngateway = "gw1"\ntopic_prefix = "lab/tactile"\n'
        f'encoding = "{encoding}"\nmax_batch_frames = 10\nbatch_interval_s = 0.1\n\n'
        f'[[bus]]\nname = "sim"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {sim_port}\n'
        "poll_interval_s = 0\n\n"  # back to back: frames wait (up to 0.1 s), and go out in batches
        '[[bus.device]]\nname = "arr"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 4\ncolumns = 2\n'
    )
    return path


class Exported:
    """The gateway's own snapshots of the device, numbered as the publisher numbers frames."""

    def __init__(self) -> None:
        self.by_seq: dict[int, Any] = {}
        self._last: object = None

    def __call__(self, snapshot: GatewaySnapshot) -> None:
        dev = snapshot.devices.get("arr")
        if dev is not None and dev is not self._last and getattr(dev, "polled", True):
            self._last = dev
            self.by_seq[len(self.by_seq) + 1] = dev


def _published(value: float, encoding: str) -> float:
    """A resistance as the subscriber reads it: rounded to 6 decimals; in binary also carried
    as float32 and read back as the shortest decimal of that float32, rounded again."""
    v = round(float(value), 6)
    if encoding == "binary" and math.isfinite(v):
        v = round(float(str(np.float32(v))), 6)
    return v


def _rows(snap: Any, encoding: str) -> dict[str, float]:
    """The record rows of one poll (``docs/record-format.md``): a resistance per channel with a
    value, ``inf`` for an open channel, none for the rest."""
    out: dict[str, float] = {}
    for k, name in enumerate(snap.channel_names):
        status = STATUS_LABELS[int(snap.status[k])]
        r = (
            _published(snap.resistance_ohm[k], encoding)
            if math.isfinite(snap.resistance_ohm[k])
            else math.inf
        )
        if status == "open" or (status in WITH_VALUE and not math.isfinite(r)):
            out[name] = math.inf
        elif status in WITH_VALUE and r > 0.0:
            out[name] = r
    return out


@pytest.mark.parametrize("encoding", ["json", "binary"])
async def test_batched_frames_reach_the_record_each_with_its_sequence(
    tmp_path: Path, broker: Broker, encoding: str
) -> None:
    array = SimArray(ArrayConfig(channels=4, columns=2, scenario="indentation", speed=5.0, seed=3))
    out = tmp_path / "rec.csv"
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        config = load_config(_config(tmp_path, server.port, broker.port, encoding))
        holder = SnapshotHolder()
        exported = Exported()
        holder.subscribe(exported)
        publisher = MqttPublisher(config)
        holder.subscribe(publisher.on_snapshot)
        publisher.start()
        try:
            async with Poller(config, holder):
                # the retained meta message is on the broker before the subscriber comes
                await until(
                    lambda: publisher.stats().published.get("arr", 0) >= 5, 20.0, "5 frames published"
                )
                cmd = [
                    str(BIN / "tactile-gateway"), "subscribe", "--broker", f"127.0.0.1:{broker.port}",
                    "--prefix", "lab/tactile", "--gateway", "gw1", "--device", "arr",
                    "--out", str(out), "--count", str(FRAMES), "--json",
                ]  # fmt: skip
                proc = await asyncio.create_subprocess_exec(
                    *cmd, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
                )
                try:
                    stdout, stderr = await asyncio.wait_for(proc.communicate(), 60.0)
                except TimeoutError:
                    proc.kill()
                    await proc.wait()
                    raise
        finally:
            publisher.stop()
    assert proc.returncode == 0, stderr.decode()
    stats = publisher.stats()
    frames_published = stats.published.get("arr", 0)
    assert stats.messages < frames_published, "frames waited and went out in batches"
    frames = [json.loads(line) for line in stdout.decode().splitlines()]
    seqs = [f["sequence"] for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + FRAMES)), "every frame, in order, with its sequence"
    assert "0 missing in 0 gap(s)" in stderr.decode() and "Traceback" not in stderr.decode()

    record = read_record(out)
    snaps = [exported.by_seq[s] for s in seqs]
    t0 = snaps[0].device_time_s
    assert t0 is not None, "the simulated array has a device clock"
    for name in ["ch00", "ch01", "ch02", "ch03"]:
        rows = [
            (round(s.device_time_s - t0, 6), _rows(s, encoding)[name])
            for s in snaps
            if name in _rows(s, encoding)
        ]
        if not rows:
            assert name not in record.channels
            continue
        ch = record.channel(name)
        assert ch.n_samples == len(rows), name
        np.testing.assert_allclose(ch.time_s, [t for t, _ in rows], rtol=0, atol=1e-6)
        assert ch.resistance_ohm.tolist() == [r for _, r in rows], name
