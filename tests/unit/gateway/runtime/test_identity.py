"""Checks at connect: ``verify_device`` on the in-process virtual bus, and what the bus loop
does with a device that is not the configured one (not polled, stale, counted, re-verified
after a reconnect)."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from gateway.config import DeviceConfig, GatewayConfig, parse_config
from gateway.errors import DeviceExceptionResponse, DeviceMismatchError, DeviceTimeoutError
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.bus import BusWorker, DeviceRunner
from gateway.runtime.identity import verify_device
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot

CONFIG = """\
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
retries = 0
timeout_s = 0.2
backoff_initial_s = 0.1
backoff_max_s = 2.0

[[bus.device]]
name = "jaw"
device_id = 1
profile = "acme-at6x6"
"""
#: a device with its own checks (no profile): a holding register and a channel count
OWN = """\
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "own"
device_id = 3
channels = 4
[bus.device.registers]
adc_address = 100
[bus.device.front_end]
kind = "low_side"
supply_v = 3.3
reference_ohm = 10000.0
adc_bits = 12
[bus.device.checks]
registers = [{ what = "firmware", table = "holding", address = 5, value = 0x0102 }]
channel_count = { table = "holding", address = 9 }
"""
PRODUCT_ID = 0x5447  # 21575
ADC = ("input", 1, 32, 36)  # acme: 36 counts from input register 32


def config(text: str = CONFIG) -> GatewayConfig:
    return parse_config(text, source=Path("/cfg/gateway.toml"))


def acme() -> DeviceConfig:
    return config().buses[0].devices[0]


def acme_image(product_id: int = PRODUCT_ID, count: int = 36) -> VirtualDevice:
    dev = VirtualDevice()
    dev.set_input(0, [product_id])
    dev.set_input(8, [count])
    dev.set_input(32, [3895] * 36)  # unloaded: 194.75 kohm each
    dev.identification.update({"VendorName": "Acme Tactile", "ProductCode": "AT-6x6", "ModelName": "x"})
    return dev


async def connected(dev: VirtualDevice, device_id: int = 1) -> VirtualTransport:
    vt = VirtualTransport("line", {device_id: dev}, timeout_s=0.2)
    await vt.connect()
    return vt


# --------------------------------------------------------------------------- verify_device
async def test_a_matching_device_passes_and_is_read_check_by_check() -> None:
    vt = await connected(acme_image())
    await verify_device(vt, acme())
    # product id, channel count (both input registers), then FC 43/14
    assert vt.requests == [("input", 1, 0, 1), ("input", 1, 8, 1), ("identification", 1, 0, 0)]
    await vt.close()


async def test_a_wrong_product_id_is_named_in_decimal_and_hex() -> None:
    vt = await connected(acme_image(product_id=0x1234))
    with pytest.raises(DeviceMismatchError) as err:
        await verify_device(vt, acme())
    assert str(err.value) == (
        "not the configured device: its product id (input register 0) reads 4660 (0x1234), "
        "the configuration (profile 'acme-at6x6') expects 21575 (0x5447); not polled until it matches"
    )
    assert vt.requests == [("input", 1, 0, 1)]  # the first failing check ends the verification
    await vt.close()


async def test_a_wrong_channel_count_is_named() -> None:
    vt = await connected(acme_image(count=16))
    with pytest.raises(DeviceMismatchError) as err:
        await verify_device(vt, acme())
    message = str(err.value)
    assert "its channel count (input register 8) reads 16 (0x0010)" in message
    assert "expects 36 (0x0024)" in message
    assert ("identification", 1, 0, 0) not in vt.requests
    await vt.close()


async def test_a_holding_register_check_without_profile() -> None:
    device = config(OWN).buses[0].devices[0]
    dev = VirtualDevice()
    dev.set_holding(5, [0x0103])
    dev.set_holding(9, [4])
    vt = await connected(dev, device_id=3)
    with pytest.raises(DeviceMismatchError) as err:
        await verify_device(vt, device)
    # no profile: "the configuration" without a source
    assert str(err.value) == (
        "not the configured device: its firmware (holding register 5) reads 259 (0x0103), "
        "the configuration expects 258 (0x0102); not polled until it matches"
    )
    dev.set_holding(5, [0x0102])
    await verify_device(vt, device)
    assert vt.requests[-2:] == [("holding", 3, 5, 1), ("holding", 3, 9, 1)]  # no identification
    await vt.close()


async def test_an_identification_that_differs_is_named() -> None:
    dev = acme_image()
    dev.identification["ProductCode"] = "AT-8x8"
    vt = await connected(dev)
    with pytest.raises(DeviceMismatchError) as err:
        await verify_device(vt, acme())
    assert str(err.value) == (
        "not the configured device: its identification product_code is 'AT-8x8', the configuration "
        "(profile 'acme-at6x6') expects 'AT-6x6'; not polled until it matches"
    )
    await vt.close()


async def test_a_missing_identification_object_is_nothing() -> None:
    dev = acme_image()
    del dev.identification["VendorName"]
    vt = await connected(dev)
    with pytest.raises(DeviceMismatchError) as err:
        await verify_device(vt, acme())
    assert "its identification vendor_name is nothing, the configuration" in str(err.value)
    assert "expects 'Acme Tactile'" in str(err.value)
    # the text must match exactly: a trailing space is another vendor
    dev.identification["VendorName"] = "Acme Tactile "
    with pytest.raises(DeviceMismatchError, match="is 'Acme Tactile ', the configuration"):
        await verify_device(vt, acme())
    await vt.close()


async def test_transport_errors_propagate_as_they_are() -> None:
    vt = await connected(acme_image())
    vt.fail_next(("exception", 2))
    with pytest.raises(DeviceExceptionResponse) as err:
        await verify_device(vt, acme())
    assert err.value.exception_code == 2
    assert not isinstance(err.value, DeviceMismatchError)
    vt.fail_next("ok")
    vt.fail_next(("exception", 4))  # the channel-count read
    with pytest.raises(DeviceExceptionResponse) as err:
        await verify_device(vt, acme())
    assert err.value.exception_code == 4
    vt.fail_next("timeout")
    with pytest.raises(DeviceTimeoutError):
        await verify_device(vt, acme())
    # a check register the device does not have answers exception 2 (illegal data address)
    dev = acme_image()
    del dev.input[8]
    vt2 = await connected(dev)
    with pytest.raises(DeviceExceptionResponse) as err:
        await verify_device(vt2, acme())
    assert err.value.exception_code == 2
    await vt.close()
    await vt2.close()


# --------------------------------------------------------------------------- the bus loop
class Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def setup(dev: VirtualDevice) -> tuple[Poller, BusWorker, DeviceRunner, VirtualTransport, Clock]:
    vt = VirtualTransport("line", {1: dev}, timeout_s=0.2)
    clock = Clock()
    poller = Poller(
        config(),
        transport_factory=lambda _bus: vt,
        rng=random.Random(7),
        wall_clock=lambda: 1_700_000_000.0,
        monotonic=clock,
    )
    worker = poller.workers[0]
    return poller, worker, worker.runners[0], vt, clock


def latest(poller: Poller) -> DeviceSnapshot:
    return poller.snapshot().devices["jaw"]


def mismatches(poller: Poller) -> int:
    return dict(poller.snapshot().counters["jaw"].read_errors_total)["mismatch"]


async def test_a_device_that_fails_its_check_is_not_polled() -> None:
    poller, worker, runner, vt, clock = setup(acme_image(product_id=0x1234))
    await worker.poll_cycle()
    assert vt.requests == [("input", 1, 0, 1)]  # the check only: no ADC read
    snap = latest(poller)
    assert not snap.up
    assert (snap.status == ChannelStatus.STALE).all() and snap.n_channels == 36
    assert np.isnan(snap.force_n).all()  # never polled: no values
    assert "not the configured device" in (snap.error or "")
    assert "reads 4660 (0x1234)" in (snap.error or "") and "expects 21575 (0x5447)" in (snap.error or "")
    counters = poller.snapshot().counters["jaw"]
    assert mismatches(poller) == 1 and counters.reads_total == 1 and counters.polls_total == 0
    assert not runner.verified

    # tried again after its back-off, still the wrong device: checked again, still not polled
    clock.now_s = runner.next_attempt + 0.001
    await worker.poll_cycle()
    assert vt.requests == [("input", 1, 0, 1)] * 2
    assert mismatches(poller) == 2

    # the right device answers now: verified, then polled in the same cycle
    vt.devices[1].set_input(0, [PRODUCT_ID])
    clock.now_s = runner.next_attempt + 0.001
    await worker.poll_cycle()
    assert vt.requests[2:] == [("input", 1, 0, 1), ("input", 1, 8, 1), ("identification", 1, 0, 0), ADC]
    snap = latest(poller)
    assert snap.up and snap.error is None and runner.verified
    assert not (snap.status == ChannelStatus.STALE).any()
    assert mismatches(poller) == 2 and poller.snapshot().counters["jaw"].polls_total == 1
    await worker.close()


async def test_a_device_is_verified_once_per_connection_and_again_after_a_reconnect() -> None:
    poller, worker, _, vt, clock = setup(acme_image())
    await worker.poll_cycle()
    assert vt.requests == [("input", 1, 0, 1), ("input", 1, 8, 1), ("identification", 1, 0, 0), ADC]
    assert latest(poller).up

    # another device now answers at this id: on the same connection it is not checked again
    vt.devices[1].set_input(0, [0x1234])
    vt.requests.clear()
    clock.now_s += 0.1
    await worker.poll_cycle()
    assert vt.requests == [ADC]
    assert latest(poller).up

    # the connection drops; on the new one the device is verified before it is polled
    vt.requests.clear()
    vt.fail_next("disconnect")
    clock.now_s += 0.1
    await worker.poll_cycle()
    assert not vt.connected and not latest(poller).up
    vt.requests.clear()
    clock.now_s += 0.1
    await worker.poll_cycle()
    assert vt.connects == 2
    assert vt.requests == [("input", 1, 0, 1)]  # the failing check, no ADC read
    snap = latest(poller)
    assert not snap.up and "its product id (input register 0) reads 4660 (0x1234)" in (snap.error or "")
    assert (snap.status == ChannelStatus.STALE).all()
    assert mismatches(poller) == 1
    errors = dict(poller.snapshot().counters["jaw"].read_errors_total)
    assert errors["connection"] == 1 and errors["timeout"] == 0
    await worker.close()


async def test_a_check_that_times_out_is_a_timeout_not_a_mismatch() -> None:
    poller, worker, runner, vt, _ = setup(acme_image())
    vt.fail_next("timeout")
    await worker.poll_cycle()
    assert vt.requests == [("input", 1, 0, 1)]
    snap = latest(poller)
    assert not snap.up and not runner.verified
    errors = dict(poller.snapshot().counters["jaw"].read_errors_total)
    assert errors["timeout"] == 1 and errors["mismatch"] == 0
    await worker.close()
