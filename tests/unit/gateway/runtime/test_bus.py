"""The poll loop of a bus on the in-process virtual bus: no sockets, no waiting.

Each test drives ``BusWorker.poll_cycle`` by hand with a scripted fault, a fake monotonic
clock and a seeded random generator, and checks what the loop published and counted.
"""

from __future__ import annotations

import dataclasses
import random

import numpy as np
import pytest

from gateway.config import bus_config_for, device_config_for, gateway_config_for
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.model import SensorParams
from gateway.runtime.bus import BusWorker, DeviceRunner
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot

#: docs/parameters.md, "What these values give": R_total at t = 0 for 0.5, 1, 2 and 5 N
SPEC_FORCES_N = [0.5, 1.0, 2.0, 5.0]
SPEC_OHM = [138.5e3, 93.8e3, 46.9e3, 9.98e3]
#: eq. 18 by hand, R_ref = 10 kohm, 16 bit: round(65535 * 10k / (10k + R))
SPEC_COUNTS = [4413, 6314, 11518, 32800]


class Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def device_image(clock: bool = True, gaps: bool = True, counts: list[int] = SPEC_COUNTS) -> VirtualDevice:
    dev = VirtualDevice()
    if clock:
        dev.set_input(2, [0, 0, 0, 1234])  # 1.234 s, uint64 ms
    if gaps:
        dev.set_input(16, [0] * 33)  # the three bitmaps and every register between them
    else:
        for address in (16, 32, 48):
            dev.set_input(address, [0])
    dev.set_input(100, counts)
    return dev


def setup(
    dev: VirtualDevice, retries: int = 2
) -> tuple[Poller, BusWorker, DeviceRunner, VirtualTransport, Clock]:
    # the spec's t = 0 resistances on the static curve (no creep): a gateway that starts on a
    # loaded, creeping sensor reads it from its equilibrium instead (tests/unit/gateway/model/
    # test_start_state.py), which is not what this table gives
    device = device_config_for("arr", 1, [SensorParams()] * 4, 2, 2.5, effects=("tunneling", "contact"))
    bus = bus_config_for(
        "line", "tcp", [device], host="127.0.0.1", port=502, retries=retries,
        backoff_initial_s=0.1, backoff_max_s=2.0, timeout_s=0.2,
    )  # fmt: skip
    vt = VirtualTransport("line", {1: dev}, timeout_s=0.2)
    clock = Clock()
    poller = Poller(
        gateway_config_for([bus]),
        transport_factory=lambda _bus: vt,
        rng=random.Random(7),
        wall_clock=lambda: 1_700_000_000.0,
        monotonic=clock,
    )
    worker = poller.workers[0]
    return poller, worker, worker.runners[0], vt, clock


def latest(poller: Poller) -> DeviceSnapshot:
    return poller.snapshot().devices["arr"]


async def test_a_poll_gives_the_spec_forces_for_hand_computed_counts() -> None:
    poller, worker, _, vt, _ = setup(device_image())
    await worker.poll_cycle()
    snap = latest(poller)
    assert snap.up and snap.status.tolist() == [ChannelStatus.OK] * 4
    # the spec prints R to 3-4 digits and the ADC quantizes it: forces within 0.5 %
    np.testing.assert_allclose(snap.force_n, SPEC_FORCES_N, rtol=5e-3)
    np.testing.assert_allclose(snap.resistance_ohm, SPEC_OHM, rtol=2e-3)
    assert snap.device_time_s == pytest.approx(1.234)
    assert vt.requests == [("input", 1, 2, 4), ("input", 1, 16, 33), ("input", 1, 100, 4)]
    counters = poller.snapshot().counters["arr"]
    assert counters.reads_total == 3 and counters.polls_total == 1
    await worker.close()


async def test_timeouts_are_retried_and_then_the_device_is_stale_with_backoff() -> None:
    poller, worker, runner, vt, clock = setup(device_image(), retries=2)
    vt.fail_next("timeout", 2)  # two lost answers: the third attempt gets through
    await worker.poll_cycle()
    assert latest(poller).up and len(vt.requests) == 5
    assert dict(poller.snapshot().counters["arr"].read_errors_total)["timeout"] == 2

    delays = []
    for failures in (1, 2, 3):
        clock.now_s = runner.next_attempt + 0.001
        vt.fail_next("timeout", 3)  # 1 + retries attempts, all lost
        await worker.poll_cycle()
        snap = latest(poller)
        assert not snap.up and "no answer" in (snap.error or "")
        assert (snap.status == ChannelStatus.STALE).all()
        np.testing.assert_allclose(snap.force_n, SPEC_FORCES_N, rtol=5e-3)  # last values kept
        assert runner.failures == failures
        delays.append(runner.next_attempt - clock.now_s)
    # full jitter: uniform(0, min(max, 0.1 * 2^(n-1))), never below a tenth of the initial
    for n, delay in enumerate(delays, start=1):
        assert 0.01 <= delay <= min(2.0, 0.1 * 2 ** (n - 1))
    assert dict(poller.snapshot().counters["arr"].read_errors_total)["timeout"] == 2 + 9
    # not due yet: nothing is sent
    before = len(vt.requests)
    clock.now_s = runner.next_attempt - 0.001
    await worker.poll_cycle()
    assert len(vt.requests) == before
    await worker.close()


async def test_busy_is_retried_and_other_exceptions_are_not() -> None:
    poller, worker, _, vt, _ = setup(device_image())
    vt.fail_next(("exception", 6))
    await worker.poll_cycle()
    assert latest(poller).up and len(vt.requests) == 4
    vt.requests.clear()
    vt.fail_next(("exception", 4))
    await worker.poll_cycle()
    snap = latest(poller)
    assert not snap.up and "exception 4 (server device failure)" in (snap.error or "")
    assert len(vt.requests) == 1  # no retry of a device failure
    assert dict(poller.snapshot().counters["arr"].read_errors_total)["exception"] == 2
    await worker.close()


async def test_a_device_without_clock_registers_falls_back_to_the_host_clock() -> None:
    poller, worker, runner, vt, _ = setup(device_image(clock=False))
    await worker.poll_cycle()
    snap = latest(poller)
    assert snap.up and snap.device_time_s is None and not runner.clock
    assert all("device_time" not in r.purpose for r in runner.plan)
    assert vt.requests[0] == ("input", 1, 2, 4)  # refused with exception 2, then the poll again
    assert vt.requests[1:] == [("input", 1, 16, 33), ("input", 1, 100, 4)]
    await worker.close()


async def test_a_refused_merged_read_falls_back_to_separate_reads() -> None:
    poller, worker, runner, vt, _ = setup(device_image(gaps=False))
    await worker.poll_cycle()
    assert latest(poller).up and runner.merge_gap == 0
    assert ("input", 1, 16, 33) in vt.requests
    assert vt.requests[-4:] == [
        ("input", 1, 16, 1),
        ("input", 1, 32, 1),
        ("input", 1, 48, 1),
        ("input", 1, 100, 4),
    ]
    await worker.close()


async def test_a_lost_connection_is_reopened_on_the_next_cycle() -> None:
    poller, worker, runner, vt, clock = setup(device_image())
    await worker.poll_cycle()
    vt.fail_next("disconnect")
    await worker.poll_cycle()
    assert not latest(poller).up and not vt.connected
    # the device whose request lost the connection waits its back-off, reconnect or not
    await worker.poll_cycle()
    assert not latest(poller).up and vt.connects == 2
    clock.now_s = runner.next_attempt + 0.001
    await worker.poll_cycle()
    assert latest(poller).up and vt.connects == 2
    vt.refuse_connects = 1
    await worker.close()
    await worker.poll_cycle()
    snap = latest(poller)
    assert not snap.up and "connection refused" in (snap.error or "") and worker.connect_failures == 1
    errors = dict(poller.snapshot().counters["arr"].read_errors_total)
    assert errors["connection"] == 2 and errors["timeout"] == 0
    await worker.close()


async def test_garbled_and_short_answers_count_as_decode_errors_and_publish_nothing_wrong() -> None:
    poller, worker, runner, vt, clock = setup(device_image(), retries=0)
    await worker.poll_cycle()
    good = latest(poller).force_n.copy()
    vt.devices[1].set_input(100, [60000] * 4)  # what a wrong answer would say
    for fault in ("garbled", "short"):
        clock.now_s = runner.next_attempt + 0.001
        vt.fail_next("ok", 2)  # the ADC read (the third request) is the one that goes wrong
        vt.fail_next(fault)
        await worker.poll_cycle()
        snap = latest(poller)
        assert not snap.up
        np.testing.assert_array_equal(snap.force_n, good)  # stale: the last good values
    assert dict(poller.snapshot().counters["arr"].read_errors_total)["decode"] == 2
    await worker.close()


async def test_a_reload_keeps_the_counters() -> None:
    poller, worker, _, vt, _ = setup(device_image())
    vt.fail_next("timeout")
    await worker.poll_cycle()
    before = poller.snapshot().counters["arr"]
    await poller.reload(poller.config)
    after = poller.snapshot().counters["arr"]
    assert after.reads_total == before.reads_total == 4
    assert dict(after.read_errors_total) == dict(before.read_errors_total)
    await poller.stop()


async def test_after_a_reload_the_published_snapshot_has_the_new_interval_at_once() -> None:
    """The race behind a flaky end-to-end test: after SIGHUP and "reloaded", a scrape read the
    old poll interval until the first poll under the new configuration was published."""
    poller, worker, _, _, _ = setup(device_image())
    await worker.poll_cycle()
    assert latest(poller).poll_interval_s == 0.1 and latest(poller).up
    old_bus = poller.config.buses[0]
    new_bus = dataclasses.replace(old_bus, poll_interval_s=0.25)
    await poller.reload(gateway_config_for([new_bus]))
    snap = latest(poller)
    assert snap.poll_interval_s == 0.25
    assert snap.up and snap.force_n.tolist() == pytest.approx(SPEC_FORCES_N, rel=5e-3)  # values stand


async def test_a_failed_connect_names_the_bus_once_in_the_log(caplog: pytest.LogCaptureFixture) -> None:
    # was "bus line: bus 'line': cannot connect to ..."
    poller, worker, _, vt, _ = setup(device_image())
    vt.refuse_connects = 1
    with caplog.at_level("WARNING", logger="gateway.runtime.bus"):
        await worker.poll_cycle()
    lines = [r.getMessage() for r in caplog.records if "cannot connect" in r.getMessage()]
    assert lines, caplog.text
    assert lines == ["bus line: cannot connect to virtual bus 'line': connection refused (attempt 1)"]
    assert "cannot connect" in (latest(poller).error or "")  # the snapshot keeps the whole message
    await worker.close()
