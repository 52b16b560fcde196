"""End to end over Modbus TCP: the simulated array, the gateway, drift-corrected forces.

The "holds" scenario at 60x speed: 0 N, then 0.5, 2 and 5 N held 120 s (device time) each.
With the channel parameters equal to the simulated sensors', the drift-corrected force
must follow the bench's true force within 0.1 N while the static estimate creeps away.
Also here: Modbus/TCP over TLS (an untrusted server is refused) and the write guard.
"""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from gateway.cli.simulated import gateway_params
from gateway.config import (
    BusConfig,
    DeviceConfig,
    RegisterMap,
    TlsConfig,
    bus_config_for,
    device_config_for,
    gateway_config_for,
)
from gateway.errors import DeviceConnectionError, WriteNotAllowedError
from gateway.modbus.client import ModbusTransport
from gateway.modbus.image import RegisterImage, decode_sample
from gateway.modbus.plan import ReadRequest
from gateway.model import Divider
from gateway.runtime.bus import Conversion
from gateway.runtime.clock import CLOCK_STUCK_AFTER_S
from gateway.runtime.poller import Poller, ReloadReport, SnapshotHolder
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot, GatewaySnapshot
from sim_device import ArrayConfig, SimArray, serve_tcp, serve_tls

SPEED = 60.0
SETTLE_S = 2.0  # device time after a step before a sample counts
TOLERANCE_N = 0.1


async def until(cond: Callable[[], bool], timeout_s: float, step_s: float = 0.05) -> bool:
    """Wait until ``cond()`` holds (True) or ``timeout_s`` passed (False)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if cond():
            return True
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(step_s)


class Recorder:
    """Keeps one row per new device sample: (device time, corrected, static, true force)."""

    def __init__(self, device: str) -> None:
        self.device = device
        self.rows: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []

    def __call__(self, snap: GatewaySnapshot) -> None:
        dev = snap.devices.get(self.device)
        if dev is None or not dev.up or dev.device_time_s is None:
            return
        if self.rows and dev.device_time_s <= self.rows[-1][0]:
            return
        ok = np.isin(dev.status, (ChannelStatus.OK, ChannelStatus.NO_CONTACT))
        self.rows.append(
            (
                dev.device_time_s,
                np.where(ok, dev.force_n, np.nan),
                np.where(ok, dev.force_static_n, np.nan),
                np.array(dev.reference_force_n),
            )
        )


def drift_errors(rows: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]) -> dict[str, float]:
    """Fraction of settled loaded samples within tolerance, and static-error growth per hold."""
    assert rows, "no samples were recorded"
    t = np.array([r[0] for r in rows])
    corrected = np.vstack([r[1] for r in rows])
    static = np.vstack([r[2] for r in rows])
    true = np.vstack([r[3] for r in rows])
    level = true.mean(axis=1)
    # a step is a change of the true force; a sample is settled SETTLE_S after the last one
    change = np.r_[True, np.abs(np.diff(level)) > 1e-3]
    last_step = np.maximum.accumulate(np.where(change, t, -np.inf))
    settled = (t - last_step >= SETTLE_S) & (level > 0.4)
    err = np.abs(corrected - true)[settled]
    within = float(np.mean(err[np.isfinite(err)] <= TOLERANCE_N)) if err.size else 0.0
    static_err = np.abs(static - true)
    start_err, end_err = [], []
    for step_t in np.unique(last_step[settled]):
        hold = settled & (last_step == step_t)
        idx = np.nonzero(hold)[0]
        if idx.size < 6:
            continue
        k = max(1, idx.size // 5)
        start_err.append(float(np.nanmean(static_err[idx[:k]])))
        end_err.append(float(np.nanmean(static_err[idx[-k:]])))
    return {
        "samples": float(err.size),
        "within": within,
        "corrected_max_n": float(np.nanmax(err)) if err.size else float("nan"),
        "corrected_mean_n": float(np.nanmean(err)) if err.size else float("nan"),
        "static_start_n": float(np.mean(start_err)) if start_err else float("nan"),
        "static_end_n": float(np.mean(end_err)) if end_err else float("nan"),
        "holds": float(len(end_err)),
    }


def holds_array(
    channels: int = 16, columns: int = 4, device_id: int = 1, clock: Callable[[], float] | None = None
) -> SimArray:
    cfg = ArrayConfig(
        channels=channels,
        columns=columns,
        pitch_mm=2.5,
        seed=1,
        scenario="holds",
        speed=SPEED,
        noise_lsb_rms=2.0,
    )
    return SimArray(cfg, device_id=device_id, clock=clock)


def array_device(array: SimArray, name: str, device_id: int = 1, bench: bool = True) -> DeviceConfig:
    cfg = array.config
    return device_config_for(
        name,
        device_id,
        gateway_params(array.channel_params),
        cfg.columns,
        cfg.pitch_mm,
        front_end=Divider(cfg.supply_v, cfg.reference_ohm, cfg.adc_bits),
        registers=RegisterMap(force_reference_address=1000 if bench else None),
    )


async def run_holds(config_bus: BusConfig, array: SimArray, device: str, budget_s: float) -> dict[str, float]:
    holder = SnapshotHolder()
    rec = Recorder(device)
    holder.subscribe(rec)
    end_s = array.scenario.duration_s
    async with Poller(gateway_config_for([config_bus]), holder):
        finished = await until(lambda: array.device_time_s >= end_s, budget_s)
    assert finished, "the scenario did not finish in time"
    return drift_errors(rec.rows)


def report(kind: str, r: dict[str, float]) -> str:
    return (
        f"{kind}: {int(r['samples'])} settled samples, {100 * r['within']:.1f} % within {TOLERANCE_N} N "
        f"(corrected |error| mean {r['corrected_mean_n']:.4f} N, max {r['corrected_max_n']:.4f} N); "
        f"static |error| {r['static_start_n']:.4f} N early in a hold -> {r['static_end_n']:.4f} N at its end "
        f"over {int(r['holds'])} holds"
    )


async def test_holds_drift_corrected_over_tcp() -> None:
    array = holds_array()
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        bus = bus_config_for(
            "tcp",
            "tcp",
            [array_device(array, "arr")],
            host="127.0.0.1",
            port=server.port,
            poll_interval_s=0.02,
        )
        r = await run_holds(bus, array, "arr", budget_s=25.0)
    message = report("TCP", r)
    print(message)
    assert r["samples"] >= 100, message
    assert r["within"] >= 0.95, message
    assert r["holds"] == 3, message
    assert r["static_end_n"] > r["static_start_n"] + 0.05, message


async def test_rtu_framing_over_tcp_reads_the_same_array() -> None:
    cfg = ArrayConfig(channels=16, columns=4, pitch_mm=2.5, seed=2, scenario="holds", speed=1.0)
    array = SimArray(cfg, device_id=3)
    async with serve_tcp([array], host="127.0.0.1", port=0, framer="rtu") as server:
        bus = bus_config_for(
            "rtu-tcp",
            "rtu-over-tcp",
            [array_device(array, "arr", device_id=3)],
            host="127.0.0.1",
            port=server.port,
        )
        snap = await Poller(gateway_config_for([bus])).poll_once()
    dev = snap.devices["arr"]
    assert dev.up, dev.error
    assert dev.device_time_s is not None
    # the scenario starts at 0 N: every channel reads no contact
    assert all(ChannelStatus(s) == ChannelStatus.NO_CONTACT for s in dev.status)


async def test_device_identification_and_holding_registers() -> None:
    array = holds_array(channels=16)
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        bus = bus_config_for("tcp", "tcp", [array_device(array, "arr")], host="127.0.0.1", port=server.port)
        async with ModbusTransport(bus) as transport:
            ident = await transport.read_device_identification(1)
            regs = await transport.read_holding_registers(1, 0, 1)
    assert ident["VendorName"] == "Tactile Gateway Project"
    assert ident["ProductCode"] == "TSA-SIM"
    assert regs == [16]


async def test_write_without_allow_write_is_refused_before_sending() -> None:
    received = bytearray()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while data := await reader.read(1024):
            received.extend(data)
        writer.close()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    array = holds_array(channels=4, columns=2)
    bus = bus_config_for("tcp", "tcp", [array_device(array, "arr")], host="127.0.0.1", port=port)
    try:
        async with ModbusTransport(bus) as transport:
            with pytest.raises(WriteNotAllowedError, match="allow_write"):
                await transport.write_registers(1, 1, [12], allow_write=False)
            await asyncio.sleep(0.1)
    finally:
        server.close()
        await server.wait_closed()
    assert bytes(received) == b""


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


@pytest.fixture
def tls_files(tmp_path: Path) -> dict[str, Path]:
    """A CA, a server certificate for 127.0.0.1 signed by it, and an unrelated CA."""
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.crt",
             "-days", "2", "-subj", "/CN=test-ca", cwd=tmp_path)  # fmt: skip
    _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out", "server.csr",
             "-subj", "/CN=127.0.0.1", cwd=tmp_path)  # fmt: skip
    (tmp_path / "ext.cnf").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    _openssl("x509", "-req", "-in", "server.csr", "-CA", "ca.crt", "-CAkey", "ca.key", "-CAcreateserial",
             "-out", "server.crt", "-days", "2", "-extfile", "ext.cnf", cwd=tmp_path)  # fmt: skip
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "other.key", "-out", "other.crt",
             "-days", "2", "-subj", "/CN=other-ca", cwd=tmp_path)  # fmt: skip
    return {n: tmp_path / n for n in ("ca.crt", "server.crt", "server.key", "other.crt")}


async def test_tls_refuses_an_untrusted_server_and_reads_a_trusted_one(tls_files: dict[str, Path]) -> None:
    array = holds_array(channels=4, columns=2)
    dev = array_device(array, "arr")
    untrusted = TlsConfig(ca_file=tls_files["other.crt"], cert_file=None, key_file=None, server_hostname=None)
    trusted = TlsConfig(ca_file=tls_files["ca.crt"], cert_file=None, key_file=None, server_hostname=None)
    wrong_name = TlsConfig(
        ca_file=tls_files["ca.crt"], cert_file=None, key_file=None, server_hostname="elsewhere"
    )
    certfile, keyfile = str(tls_files["server.crt"]), str(tls_files["server.key"])
    async with serve_tls([array], host="127.0.0.1", port=0, certfile=certfile, keyfile=keyfile) as server:

        def bus(tls: TlsConfig) -> BusConfig:
            return bus_config_for("tls", "tls", [dev], host="127.0.0.1", port=server.port, tls=tls)

        bad = ModbusTransport(bus(untrusted))
        with pytest.raises(DeviceConnectionError, match="certificate verify failed"):
            await bad.connect()
        assert not bad.connected
        named = ModbusTransport(bus(wrong_name))
        with pytest.raises(DeviceConnectionError, match="certificate verify failed"):
            await named.connect()
        refused = await Poller(gateway_config_for([bus(untrusted)])).poll_once()
        snap = await Poller(gateway_config_for([bus(trusted)])).poll_once()
    assert not refused.devices["arr"].up
    assert refused.counters["arr"].read_errors_total["connection"] >= 1
    dev_snap = snap.devices["arr"]
    assert dev_snap.up, dev_snap.error
    assert dev_snap.device_time_s is not None


class PausableClock:
    """``time.monotonic`` that stands still while paused and resumes where it stopped."""

    def __init__(self) -> None:
        self._paused_at: float | None = None
        self._lost_s = 0.0

    def __call__(self) -> float:
        return (time.monotonic() if self._paused_at is None else self._paused_at) - self._lost_s

    def pause(self) -> None:
        self._paused_at = time.monotonic()

    def resume(self) -> None:
        assert self._paused_at is not None
        self._lost_s += time.monotonic() - self._paused_at
        self._paused_at = None


async def test_reload_keeps_the_creep_state_of_unchanged_channels() -> None:
    # The simulated device's clock is paused across the reload: every poll in that window
    # reads the same instant, so no poll can move a kept creep state on and "kept" means
    # "exactly as before" (within rounding), whatever the load. A pause long enough for the
    # gateway to call the device clock stuck (CLOCK_STUCK_AFTER_S: the host clock takes over)
    # proves nothing, so such a round is not judged and the next one is tried.
    clock = PausableClock()
    array = holds_array(channels=4, columns=2, clock=clock)
    judged: list[tuple[ReloadReport, NDArray[np.float64], NDArray[np.float64]]] = []
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        device = array_device(array, "arr")
        bus = bus_config_for("tcp", "tcp", [device], host="127.0.0.1", port=server.port, poll_interval_s=0.02)
        poller = Poller(gateway_config_for([bus]))
        async with poller:
            # into the 2 N hold: the creep elements are loaded
            assert await until(lambda: array.device_time_s >= 150.0, 10.0)
            for r0_ohm in (1.5e5, 1.6e5, 1.7e5, 1.8e5, 1.9e5):
                clock.pause()
                paused_at = time.monotonic()
                array.advance()  # the device's last sample is at the paused instant
                instant_s = array.last_sample_time_s

                def converted(instant_s: float = instant_s) -> bool:
                    t = poller.snapshot().devices["arr"].device_time_s
                    return t is not None and abs(t - instant_s) < 5e-4  # the clock counts ms

                if await until(converted, 0.5 * CLOCK_STUCK_AFTER_S, step_s=0.005):
                    worker = poller.workers[0]
                    worker.settle_now(worker.runners[0])
                    before = worker.runners[0].state.model_state.kv1_strain.copy()
                    changed = list(device.channels)
                    changed[1] = dataclasses.replace(
                        changed[1], params=dataclasses.replace(changed[1].params, r0_ohm=r0_ohm)
                    )
                    new_device = dataclasses.replace(device, channels=tuple(changed))
                    report = await poller.reload(
                        gateway_config_for([dataclasses.replace(bus, devices=(new_device,))])
                    )
                    after = poller.workers[0].runners[0].state.model_state.kv1_strain.copy()
                    if time.monotonic() - paused_at < 0.5 * CLOCK_STUCK_AFTER_S:
                        judged.append((report, before, after))
                clock.resume()
                if judged:
                    break

                def resumed(resume_s: float = instant_s + 1.0) -> bool:
                    return array.device_time_s >= resume_s

                assert await until(resumed, 10.0)
            snap = poller.snapshot()
    assert judged, "every reload took longer than half CLOCK_STUCK_AFTER_S with the device clock paused"
    report, before, after = judged[0]
    assert report.channels_kept == 3 and report.channels_reset == 1
    assert np.all(before > 1e-5)
    np.testing.assert_allclose(after[[0, 2, 3]], before[[0, 2, 3]], rtol=1e-12)
    assert after[1] == 0.0
    assert snap.devices["arr"].up
    assert snap.counters["arr"].reads_total > 0


class RecordingTransport(ModbusTransport):
    """The real transport, keeping every register block it read (to convert them again)."""

    def __init__(self, bus: BusConfig) -> None:
        super().__init__(bus)
        self.reads: list[tuple[int, list[int]]] = []

    async def read(self, device_id: int, request: ReadRequest) -> list[int]:
        regs = await super().read(device_id, request)
        assert request.kind == "input"  # the simulator's map: every block in input registers
        self.reads.append((request.address, list(regs)))
        return regs


async def test_back_to_back_polls_are_each_converted_once_in_order() -> None:
    """Polled back to back, each poll's conversion runs in steps while the next poll's
    requests are answered. Still every poll is converted once, published in poll order,
    and gives what converting it at once gives; a settled cycle leaves nothing pending."""
    array = holds_array(channels=16, columns=4)
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        device = array_device(array, "arr")
        bus = bus_config_for("tcp", "tcp", [device], host="127.0.0.1", port=server.port)
        poller = Poller(gateway_config_for([bus]), transport_factory=RecordingTransport)
        worker, runner = poller.workers[0], poller.workers[0].runners[0]
        transport = worker.transport
        assert isinstance(transport, RecordingTransport)
        assert len(runner.plan) >= 3  # one request per conversion step
        published: list[DeviceSnapshot] = []
        poller.holder.subscribe(lambda s: published.append(s.devices["arr"]))
        conversions: list[Conversion] = []
        await transport.connect()
        try:
            for _ in range(300):  # 0.3 s or more: past the first 10 s (device time) at no load
                assert await worker.poll_device(runner)
                assert runner.pending is not None
                conversions.append(runner.pending)
                # the previous poll was finished while this one's requests were answered
                assert len(published) == len(conversions) - 1
            await worker.poll_cycle()  # settles: its poll and the one before are published
            assert runner.pending is None and len(published) == len(conversions) + 1
        finally:
            await worker.close()
    firsts = zip(conversions, published[: len(conversions)], strict=True)
    assert all(c.result is not None and c.result[0] is snap for c, snap in firsts)
    assert runner.counters.polls_total == len(published)
    times = [s.device_time_s for s in published]
    assert all(b is not None and a is not None and b > a for a, b in itertools.pairwise(times))
    # the same registers converted poll by poll, at once
    processor = DeviceProcessor(device, "tcp", 0.1)
    state = processor.initial_state()
    per_poll = len(runner.plan)
    loaded = 0
    for k, snap in enumerate(published):
        blocks = transport.reads[k * per_poll : (k + 1) * per_poll]
        raw = decode_sample(device, RegisterImage.from_reads([("input", a, r) for a, r in blocks]))
        again, state = processor.process(state, raw, 0.0, 0.0)
        np.testing.assert_array_equal(again.status, snap.status)
        np.testing.assert_array_equal(again.force_n, snap.force_n)
        loaded += int(np.count_nonzero(snap.status == ChannelStatus.OK))
    assert loaded > 0, "no loaded channel was converted: the check above proves little"


async def test_a_failing_conversion_step_marks_its_poll_and_the_bus_goes_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A step that raises (a bug, or data the model cannot take) ends that poll only: it is
    counted as a decode error, the device shows the error, and the next polls convert."""
    array = holds_array(channels=4, columns=2)
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        device = array_device(array, "arr")
        bus = bus_config_for("tcp", "tcp", [device], host="127.0.0.1", port=server.port)
        poller = Poller(gateway_config_for([bus]))
        worker, runner = poller.workers[0], poller.workers[0].runners[0]
        processor = runner.processor
        track, calls = processor.track, 0

        def failing_third_track(*args: object, **kwargs: object) -> object:
            nonlocal calls
            calls += 1
            if calls == 3:
                raise RuntimeError("boom")
            return track(*args, **kwargs)  # type: ignore[arg-type]

        processor.track = failing_third_track  # type: ignore[method-assign,assignment]
        published: list[DeviceSnapshot] = []
        poller.holder.subscribe(lambda s: published.append(s.devices["arr"]))
        await worker.transport.connect()
        try:
            for _ in range(8):
                assert await worker.poll_device(runner)
            await worker.poll_cycle()
        finally:
            await worker.close()
    assert calls == 9
    failed = [s for s in published if not s.up]
    assert len(failed) == 1 and failed[0].error == "conversion failed: boom"
    assert published.index(failed[0]) == 2  # in poll order
    assert all(s.up for s in published[3:]) and len(published) == 9
    assert runner.counters.read_errors_total["decode"] == 1
    assert runner.counters.polls_total == 8
    assert "conversion failed" in caplog.text
