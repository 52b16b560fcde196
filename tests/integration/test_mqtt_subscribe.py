"""``tactile-gateway subscribe`` against a real Mosquitto (TLS, a password file): a gateway polling
the simulated array publishes binary frames; the subscriber, a separate process, records them
in the record format, and the record reads back with the values the gateway exported."""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from broker import Broker, make_tls_files
from netutil import free_port

from gateway.analysis.records import Record, read_record
from gateway.config import load_config
from gateway.mqtt.publisher import MqttPublisher
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import STATUS_LABELS, GatewaySnapshot
from sim_device import ArrayConfig, SimArray
from sim_device.modbus_server import serve_tcp

BIN = Path(sys.executable).parent
PASSWORD = "s3cret-pw"
WITH_VALUE = {"ok", "no_contact", "saturated", "extrapolated", "no_zero"}


@pytest.fixture(scope="module")
def tls_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return make_tls_files(tmp_path_factory.mktemp("tls"))


def _broker(folder: Path, tls_files: dict[str, Path], persistence: bool) -> Iterator[Broker]:
    b = Broker(folder, users={"gw": PASSWORD, "reader": PASSWORD}, tls=tls_files, persistence=persistence)
    b.start()
    try:
        yield b
    finally:
        b.stop()


@pytest.fixture
def broker(tmp_path: Path, tls_files: dict[str, Path]) -> Iterator[Broker]:
    """With persistence in the test's folder: a restart keeps sessions and queued messages."""
    yield from _broker(tmp_path / "broker", tls_files, persistence=True)


@pytest.fixture
def volatile_broker(tmp_path: Path, tls_files: dict[str, Path]) -> Iterator[Broker]:
    """Without persistence: a restart forgets every session."""
    yield from _broker(tmp_path / "broker", tls_files, persistence=False)


def _secret(path: Path, text: str) -> Path:
    path.write_text(text + "\n")
    path.chmod(0o600)
    return path


def _gateway_config(tmp_path: Path, sim_port: int, broker_port: int, ca: Path, extra: str = "") -> Path:
    secret = _secret(tmp_path / "gw.pw", PASSWORD)
    path = tmp_path / "gateway.toml"
    path.write_text(
        f'[metrics]\naddress = "127.0.0.1:{free_port()}"\n\n'
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker_port}\nusername = "gw"\npassword_file = "{secret}"\n'
        f'gateway = "gw1"\ntopic_prefix = "lab/tactile"\nencoding = "binary"\n'
        f'tls = {{ ca_file = "{ca}" }}\n{extra}\n'
        f'[[bus]]\nname = "sim"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {sim_port}\n'
        "poll_interval_s = 0.05\n\n"
        '[[bus.device]]\nname = "arr"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 4\ncolumns = 2\n'
    )
    path.chmod(0o600)
    return path


def _subscribe_cmd(
    broker: Broker, tmp_path: Path, ca: Path, *extra: str, password: str = PASSWORD
) -> list[str]:
    secret = _secret(tmp_path / f"reader-{password}.pw", password)
    return [
        str(BIN / "tactile-gateway"), "subscribe", "--broker", f"127.0.0.1:{broker.port}",
        "--tls-ca", str(ca), "--username", "reader", "--password-file", str(secret),
        "--prefix", "lab/tactile", *extra,
    ]  # fmt: skip


async def until(cond: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.02)
    return True


class Exported:
    """The gateway's own snapshots of the device, numbered as the publisher numbers frames."""

    def __init__(self) -> None:
        self.by_seq: dict[int, Any] = {}
        self._last: object = None

    def __call__(self, snapshot: GatewaySnapshot) -> None:
        dev = snapshot.devices.get("arr")
        # nothing is published for a device before its first poll completes
        if dev is not None and dev is not self._last and getattr(dev, "polled", True):
            self._last = dev
            self.by_seq[len(self.by_seq) + 1] = dev


def _f32(value: float) -> float:
    """A published value as a subscriber reads it from a binary frame: rounded to 6 decimals,
    carried as float32, read as the shortest decimal of that float32, rounded to 6 decimals."""
    v = float(value)
    if not math.isfinite(v):
        return v
    return round(float(str(np.float32(round(v, 6)))), 6)


def _expected_rows(snap: Any) -> dict[str, float]:
    """What the record format allows for one poll: resistance per channel (as a subscriber
    reads it from the binary frame: ``_f32``), ``inf`` for an open channel,
    nothing for the rest."""
    out: dict[str, float] = {}
    for k, name in enumerate(snap.channel_names):
        status = STATUS_LABELS[int(snap.status[k])]
        r = _f32(snap.resistance_ohm[k])
        if status == "open" or (status in WITH_VALUE and not math.isfinite(r)):
            out[name] = math.inf
        elif status in WITH_VALUE and r > 0.0:
            out[name] = r
    return out


def _assert_record_has_the_rows_of(record: Record, snaps: list[Any]) -> None:
    """The record holds exactly the rows of these polls (the frames received), in order."""
    t0 = snaps[0].device_time_s
    assert t0 is not None, "the simulated array has a device clock"
    for name in ["ch00", "ch01", "ch02", "ch03"]:
        rows = [
            (round(s.device_time_s - t0, 6), _expected_rows(s)[name])
            for s in snaps
            if name in _expected_rows(s)
        ]
        ch = record.channel(name) if rows else None
        if ch is None:
            assert name not in record.channels
            continue
        assert ch.n_samples == len(rows)
        np.testing.assert_allclose(ch.time_s, [t for t, _ in rows], rtol=0, atol=1e-6)
        assert ch.resistance_ohm.tolist() == [r for _, r in rows], name


async def test_subscribe_records_50_binary_frames_that_read_back_as_published(
    tmp_path: Path, broker: Broker, tls_files: dict[str, Path]
) -> None:
    ca = tls_files["ca.crt"]
    array = SimArray(ArrayConfig(channels=4, columns=2, scenario="indentation", speed=5.0, seed=2))
    out = tmp_path / "rec.csv"
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        config = load_config(_gateway_config(tmp_path, server.port, broker.port, ca))
        holder = SnapshotHolder()
        exported = Exported()
        holder.subscribe(exported)
        publisher = MqttPublisher(config)
        holder.subscribe(publisher.on_snapshot)
        publisher.start()
        try:
            async with Poller(config, holder):
                # the retained meta message is on the broker before the subscriber comes
                assert await until(lambda: publisher.stats().published.get("arr", 0) >= 5, 20.0)
                cmd = _subscribe_cmd(
                    broker, tmp_path, ca, "--gateway", "gw1", "--device", "arr",
                    "--out", str(out), "--count", "50", "--json",
                )  # fmt: skip
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
    frames = [json.loads(line) for line in stdout.decode().splitlines()]
    assert len(frames) == 50
    seqs = [f["sequence"] for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + 50)), "50 consecutive frames, in order"
    assert "0 missing in 0 gap(s)" in stderr.decode() and "Traceback" not in stderr.decode()
    assert {f["gateway"] for f in frames} == {"gw1"} and {f["device"] for f in frames} == {"arr"}
    assert frames[0]["channels"] == ["ch00", "ch01", "ch02", "ch03"], "names from the retained meta"

    record = read_record(out)
    assert record.metadata["source"] == "tactile-gateway subscribe"
    assert "force_n" not in out.read_text().splitlines()[len(record.metadata)], "no reference force"
    assert sum(c.n_samples for c in record.channels.values()) >= 150, "rows for (nearly) every channel"
    snaps = [exported.by_seq[s] for s in seqs]
    _assert_record_has_the_rows_of(record, snaps)
    # the frame's own values agree with the gateway's export at the same sequence number
    for f, s in zip(frames, snaps, strict=True):
        assert f["device_time_s"] == round(s.device_time_s, 6)
        assert f["total_force_n"] == round(s.total_force_n, 6)
        assert f["force_n"] == [None if not np.isfinite(v) else _f32(v) for v in s.force_n]


class _Lines:
    """A child's output stream, read line by line as it comes (the child never blocks on it)."""

    def __init__(self, stream: asyncio.StreamReader | None) -> None:
        assert stream is not None
        self.lines: list[str] = []
        self.task = asyncio.create_task(self._read(stream))

    async def _read(self, stream: asyncio.StreamReader) -> None:
        while line := await stream.readline():
            self.lines.append(line.decode().rstrip("\n"))


SUMMARY = re.compile(r"(\d+) frame\(s\) from 1 device\(s\); (\d+) missing in (\d+) gap\(s\)(.*)")
GAP = re.compile(r"gw1/arr: gap: (\d+) frame\(s\) missing before sequence (\d+)")


async def test_subscribe_rides_out_a_broker_restart_and_counts_the_frames_lost_in_it(
    tmp_path: Path, volatile_broker: Broker, tls_files: dict[str, Path]
) -> None:
    """A broker without persistence forgets the subscriber's session in a restart: the
    subscriber says so, subscribes again itself, and the frames published while it was away
    are lost to it; its summary must count exactly those."""
    broker = volatile_broker
    ca = tls_files["ca.crt"]
    where = f"127.0.0.1:{broker.port}"
    array = SimArray(ArrayConfig(channels=4, columns=2, scenario="indentation", speed=5.0, seed=2))
    out = tmp_path / "rec.csv"
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        # a 20-frame queue at the gateway: an outage of more than a second must lose frames
        path = _gateway_config(tmp_path, server.port, broker.port, ca, "queue_frames = 20\n")
        config = load_config(path)
        holder = SnapshotHolder()
        exported = Exported()
        holder.subscribe(exported)
        publisher = MqttPublisher(config)
        holder.subscribe(publisher.on_snapshot)
        publisher.start()
        proc: asyncio.subprocess.Process | None = None
        readers: list[_Lines] = []
        try:
            async with Poller(config, holder):
                assert await until(lambda: publisher.stats().published.get("arr", 0) >= 5, 20.0)
                cmd = _subscribe_cmd(
                    broker, tmp_path, ca, "--gateway", "gw1", "--device", "arr",
                    "--out", str(out), "--json",
                )  # fmt: skip
                proc = await asyncio.create_subprocess_exec(
                    *cmd, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
                )
                stdout, stderr = _Lines(proc.stdout), _Lines(proc.stderr)
                readers = [stdout, stderr]
                running = proc

                def seqs() -> list[int]:
                    return [json.loads(line)["sequence"] for line in stdout.lines]

                def said(text: str) -> list[str]:
                    return [line for line in stderr.lines if text in line]

                async def wait(cond: Callable[[], object], timeout_s: float, what: str) -> None:
                    await until(lambda: bool(cond()) or running.returncode is not None, timeout_s)
                    assert running.returncode is None, (
                        f"the subscriber exited ({running.returncode}) waiting for {what}: {stderr.lines}"
                    )
                    assert cond(), f"no {what} in {timeout_s:g} s: {stderr.lines}"

                await wait(lambda: len(stdout.lines) >= 20, 30.0, "20 frames")
                n_before = len(stdout.lines)
                dropped_before = publisher.stats().dropped.get("arr", 0)
                broker.kill()
                await wait(lambda: said("lost the connection"), 20.0, "notice of the lost connection")
                # the gateway's queue overflows: frames that can never reach the subscriber
                await wait(lambda: publisher.stats().dropped.get("arr", 0) > dropped_before, 20.0, "drops")
                await asyncio.to_thread(broker.start)
                await wait(
                    lambda: said("reconnected to") and publisher.stats().connected, 60.0, "reconnection"
                )
                # both are connected and subscribed: every frame polled from now on is delivered
                both_up = len(exported.by_seq)
                dropped_up = publisher.stats().dropped.get("arr", 0)
                await wait(lambda: seqs() and seqs()[-1] >= both_up + 20, 30.0, "frames after the restart")
                proc.send_signal(signal.SIGINT)
                await asyncio.wait_for(proc.wait(), 30.0)
                dropped_end = publisher.stats().dropped.get("arr", 0)
                await asyncio.wait_for(asyncio.gather(*(r.task for r in readers)), 10.0)
        finally:
            publisher.stop()
            if proc is not None and proc.returncode is None:
                proc.kill()
                await proc.wait()
            for r in readers:
                r.task.cancel()
            await asyncio.gather(*(r.task for r in readers), return_exceptions=True)
    err = "\n".join(stderr.lines)
    assert proc.returncode == 0, err
    assert "Traceback" not in err

    # stderr: the outage said once each way, with retries in between, then the gaps and the summary
    lost_at = [i for i, s in enumerate(stderr.lines) if s.startswith(f"lost the connection to {where} (")]
    back_at = [i for i, s in enumerate(stderr.lines) if s == f"reconnected to {where}"]
    assert len(lost_at) == 1 and len(back_at) == 1 and lost_at[0] < back_at[0], err
    no_session = stderr.lines[back_at[0] + 1]
    assert no_session.startswith("the broker kept no session for 'tactile-sub-"), err
    assert no_session.endswith("frames published meanwhile are lost"), err
    assert stderr.lines[lost_at[0]].endswith("; reconnecting"), err
    retries = [s for s in stderr.lines[lost_at[0] + 1 : back_at[0]] if s.endswith("; retrying")]
    assert all(line.startswith(f"cannot connect to {where}") for line in retries), err
    gap_lines = [GAP.fullmatch(line) for line in stderr.lines]
    summary = SUMMARY.fullmatch(stderr.lines[-1])
    assert summary is not None, err
    unexpected = [
        line
        for k, line in enumerate(stderr.lines[:-1])
        if k not in [*lost_at, *back_at, back_at[0] + 1] and line not in retries and gap_lines[k] is None
    ]
    assert unexpected == [], err
    delivered, missing, gaps, extras = summary.groups()
    assert "restart" not in extras and "undecodable" not in extras and "backwards" not in extras, err

    # stdout: each frame once, in order; the gaps are the sequence numbers not received
    frames = [json.loads(line) for line in stdout.lines]
    got = [f["sequence"] for f in frames]
    assert int(delivered) == len(got)
    assert all(a < b for a, b in itertools.pairwise(got)), "strictly increasing, no repeats"
    holes = [(b - a - 1, b) for a, b in itertools.pairwise(got) if b > a + 1]
    assert [(int(m[1]), int(m[2])) for m in gap_lines if m is not None] == holes, err
    assert int(gaps) == len(holes) >= 1
    lost = sorted(set(range(got[0], got[-1] + 1)) - set(got))
    assert int(missing) == sum(n for n, _ in holes) == len(lost)
    # ... and they are those of the outage: none before the kill; at least those the gateway
    # dropped in it (its 20-frame queue overflowed); once both were back only what the
    # gateway may have dropped since (its client's queue is 20 messages too)
    assert lost[0] > got[n_before - 1], (lost, n_before)
    assert len([s for s in lost if s <= both_up]) >= dropped_up - dropped_before > 0, (lost, both_up)
    assert len([s for s in lost if s > both_up]) <= dropped_end - dropped_up, (lost, both_up)
    assert got[-1] >= both_up + 20

    # the record: rows from before and after the outage, exactly those of the frames received
    record = read_record(out)
    assert record.metadata["source"] == "tactile-gateway subscribe"
    snaps = [exported.by_seq[s] for s in got]
    _assert_record_has_the_rows_of(record, snaps)
    t0 = snaps[0].device_time_s
    times = np.concatenate([c.time_s for c in record.channels.values()])
    last_before = round(snaps[n_before - 1].device_time_s - t0, 6)
    first_after = round(exported.by_seq[both_up + 1].device_time_s - t0, 6)
    assert (times <= last_before + 1e-3).any() and (times >= first_after - 1e-3).any()
    assert f"{sum(c.n_samples for c in record.channels.values())} rows to {out}" in extras


async def test_a_persistent_session_gets_the_frames_published_while_subscribe_was_away(
    tmp_path: Path, broker: Broker, tls_files: dict[str, Path]
) -> None:
    """Item 11 of issue 24: the broker restarts (persistence on) and the gateway flushes its
    queue to it before the subscriber is back. The subscriber is held (SIGSTOP) until the
    gateway has published 40 frames more to the restarted broker; its persistent session
    (fixed client id, clean start off, QoS 1) makes the broker queue them, and they all
    arrive after it reconnects: not one sequence number missing, none twice."""
    ca = tls_files["ca.crt"]
    where = f"127.0.0.1:{broker.port}"
    array = SimArray(ArrayConfig(channels=4, columns=2, scenario="indentation", speed=5.0, seed=2))
    out = tmp_path / "rec.csv"
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        # a queue at the gateway that holds the whole outage: the gateway drops nothing
        path = _gateway_config(tmp_path, server.port, broker.port, ca, "queue_frames = 10000\n")
        config = load_config(path)
        holder = SnapshotHolder()
        exported = Exported()
        holder.subscribe(exported)
        publisher = MqttPublisher(config)
        holder.subscribe(publisher.on_snapshot)
        publisher.start()
        proc: asyncio.subprocess.Process | None = None
        readers: list[_Lines] = []
        stopped = False
        try:
            async with Poller(config, holder):
                assert await until(lambda: publisher.stats().published.get("arr", 0) >= 5, 20.0)
                cmd = _subscribe_cmd(
                    broker, tmp_path, ca, "--gateway", "gw1", "--device", "arr",
                    "--out", str(out), "--json",
                )  # fmt: skip
                proc = await asyncio.create_subprocess_exec(
                    *cmd, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
                )
                stdout, stderr = _Lines(proc.stdout), _Lines(proc.stderr)
                readers = [stdout, stderr]
                running = proc

                def seqs() -> list[int]:
                    return [json.loads(line)["sequence"] for line in stdout.lines]

                def said(text: str) -> list[str]:
                    return [line for line in stderr.lines if text in line]

                def published() -> int:
                    return publisher.stats().published.get("arr", 0)

                async def wait(cond: Callable[[], object], timeout_s: float, what: str) -> None:
                    await until(lambda: bool(cond()) or running.returncode is not None, timeout_s)
                    assert running.returncode is None, (
                        f"the subscriber exited ({running.returncode}) waiting for {what}: {stderr.lines}"
                    )
                    assert cond(), f"no {what} in {timeout_s:g} s: {stderr.lines}"

                await wait(lambda: len(stdout.lines) >= 20, 30.0, "20 frames")
                # a clean restart: mosquitto saves its sessions and queued messages on the way down
                await asyncio.to_thread(broker.stop)
                await wait(lambda: said("lost the connection"), 20.0, "notice of the lost connection")
                last_before = seqs()[-1]
                proc.send_signal(signal.SIGSTOP)
                stopped = True
                n_stopped = len(stdout.lines)
                # frames are acknowledged in order and none is dropped, so the count published
                # is the last sequence number the broker acknowledged; the subscriber may have
                # received a frame whose acknowledgement was still on its way to the gateway
                # when the broker stopped, so the 40 frames count from the later of the two
                published_down = max(published(), last_before)
                await asyncio.to_thread(broker.start)
                # the gateway is back and flushes its queue; 40 frames more reach the broker
                # while the subscriber cannot be connected
                await wait(
                    lambda: publisher.stats().connected and published() >= published_down + 40,
                    60.0,
                    "the gateway publishing to the restarted broker",
                )
                published_away = published()
                proc.send_signal(signal.SIGCONT)
                stopped = False
                await wait(lambda: said("reconnected to"), 60.0, "reconnection")
                await wait(
                    lambda: seqs() and seqs()[-1] >= published_away + 20, 30.0, "frames after the restart"
                )
                proc.send_signal(signal.SIGINT)
                await asyncio.wait_for(proc.wait(), 30.0)
                dropped = publisher.stats().dropped.get("arr", 0)
                await asyncio.wait_for(asyncio.gather(*(r.task for r in readers)), 10.0)
        finally:
            publisher.stop()
            if proc is not None and proc.returncode is None:
                if stopped:
                    proc.send_signal(signal.SIGCONT)
                proc.kill()
                await proc.wait()
            for r in readers:
                r.task.cancel()
            await asyncio.gather(*(r.task for r in readers), return_exceptions=True)
    err = "\n".join(stderr.lines)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "kept no session" not in err, err
    assert not any(GAP.fullmatch(line) for line in stderr.lines), err
    assert len(said(f"lost the connection to {where}")) == 1 and said(f"reconnected to {where}"), err
    assert dropped == 0, "the gateway kept every frame"

    got = seqs()
    assert got == list(range(got[0], got[-1] + 1)), "every frame once, in order, none missing"
    summary = SUMMARY.fullmatch(stderr.lines[-1])
    assert summary is not None, err
    assert summary.group(1) == str(len(got)) and summary.group(2, 3) == ("0", "0"), err
    # QoS 1 is at least once: a frame in flight when the broker went down may come twice;
    # the subscriber drops it by its sequence number (and says so in the summary)
    assert "backwards" not in summary.group(4) and "restart" not in summary.group(4), err
    # the frames published while the subscriber was away, counted: those after the last it
    # had when the broker went down, up to the last the restarted broker acknowledged while
    # the subscriber was held; each of them delivered after the reconnection
    away = list(range(last_before + 1, published_away + 1))
    assert len(away) >= 40
    after = got[n_stopped:]
    assert after[: len(away)] == away, (last_before, published_away, after[:5])
    snaps = [exported.by_seq[s] for s in got]
    _assert_record_has_the_rows_of(read_record(out), snaps)


def _run(cmd: list[str], timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)


def test_wrong_password_untrusted_ca_and_refused_connection_are_one_line_errors(
    tmp_path: Path, broker: Broker, tls_files: dict[str, Path]
) -> None:
    cases = [
        (_subscribe_cmd(broker, tmp_path, tls_files["ca.crt"], "--count", "1", password="wrong"),
         ("Not authorized", "Bad user name or password")),
        (_subscribe_cmd(broker, tmp_path, tls_files["other.crt"], "--count", "1"),
         ("certificate verify failed",)),
        ([str(BIN / "tactile-gateway"), "subscribe", "--broker", f"127.0.0.1:{free_port()}", "--count", "1"],
         ("connection refused",)),
    ]  # fmt: skip
    for cmd, expected in cases:
        result = _run(cmd)
        lines = result.stderr.strip().splitlines()
        assert result.returncode == 1, result
        assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
        assert any(e in lines[0] for e in expected), lines[0]
        assert result.stdout == ""


def test_a_password_file_others_can_read_is_refused(
    tmp_path: Path, broker: Broker, tls_files: dict[str, Path]
) -> None:
    cmd = _subscribe_cmd(broker, tmp_path, tls_files["ca.crt"], "--count", "1")
    (tmp_path / f"reader-{PASSWORD}.pw").chmod(0o644)
    result = _run(cmd)
    assert result.returncode == 1 and "chmod 600" in result.stderr and "Traceback" not in result.stderr
