"""A device's named status words (``[[bus.device.status_word]]``): parsed with precise
refusals, read with every poll (one register each in the read plan), carried in the snapshot
with their labels, exported in /metrics, hand-checked bit by bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from prometheus_client import CollectorRegistry, generate_latest

from gateway.config import parse_config
from gateway.errors import ConfigError
from gateway.metrics.collector import make_registry
from gateway.modbus.image import RegisterImage
from gateway.modbus.register_map import RegisterKind, register_blocks
from gateway.runtime.conversion import Conversion
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot

DEVICE = """
[[bus]]
name = "b"
kind = "tcp"
host = "127.0.0.1"
port = 502

[[bus.device]]
name = "hand"
device_id = 1
channels = 4
address_unit = "byte"
[bus.device.frame]
quantity = "counts"
table = "holding"
type = "uint16"
[bus.device.front_end]
kind = "ratio"
adc_bits = 16

[[bus.device.region]]
name = "tip"
address = 3000
rows = 2
columns = 2
{words}
"""
WORDS = """
[[bus.device.status_word]]
name = "index-state"
address = 2000
codes = { 0 = "idle", 1 = "grasping", 2 = "force reached", 3 = "stall", 4 = "fault" }
error_codes = [3, 4]

[[bus.device.status_word]]
name = "index-errors"
table = "input"
address = 2002
bits = { 5 = "calibrated" }
errors = { 0 = "stall", 1 = "over-temperature", 2 = "over-current", 3 = "motor", 4 = "communication" }
"""


def hand(words: str = WORDS):  # type: ignore[no-untyped-def]
    return parse_config(DEVICE.format(words=words)).buses[0].devices[0]


def test_status_words_are_parsed_at_their_registers() -> None:
    state, errors = hand().status_words
    # byte addresses: register = byte / 2; the frame's table by default
    assert (state.name, state.table, state.address) == ("index-state", RegisterKind.HOLDING, 1000)
    assert state.codes[3] == (3, "stall") and state.error_codes == frozenset({3, 4})
    assert (errors.table, errors.address) == (RegisterKind.INPUT, 1001)
    assert errors.errors[1] == (1, "over-temperature") and errors.bits == ((5, "calibrated"),)


def test_each_status_word_is_one_register_of_the_read_plan() -> None:
    words = [b for b in register_blocks(hand()) if b.purpose == "status_word"]
    assert [(b.kind, b.address, b.count) for b in words] == [(RegisterKind.HOLDING, 1000, 1),
                                                            (RegisterKind.INPUT, 1001, 1)]  # fmt: skip


def test_a_poll_carries_the_words_read_and_metrics_export_them() -> None:
    dev = hand()
    proc = DeviceProcessor(dev, "b", 0.05)
    # the taxels at 1500.. (bytes 3000..), the state word 3 (stall), the error bits 0b100110:
    # over-temperature (1), over-current (2) and calibrated (5)
    reads = [
        (RegisterKind.HOLDING, 1500, [100, 200, 300, 400]),
        (RegisterKind.HOLDING, 1000, [3]),
        (RegisterKind.INPUT, 1001, [0b100110]),
    ]
    job = Conversion(proc, proc.initial_state(), reads, 1000.0, 1.0, 0.0)  # type: ignore[arg-type]
    while not job.step():
        pass
    assert job.result is not None
    state, errors = job.result[0].status_words
    assert (state.value, state.code, state.error) == (3, "stall", True)
    assert errors.value == 0b100110 and errors.error
    on = {label for _, label, is_on, _ in errors.bits if is_on}
    assert on == {"over-temperature", "over-current", "calibrated"}
    assert [(b, is_err) for b, _, _, is_err in errors.bits] == [(0, True), (1, True), (2, True), (3, True),
                                                                 (4, True), (5, False)]  # fmt: skip

    text = generate_latest(
        make_registry(lambda: GatewaySnapshot.build({"hand": job.result[0]}, {}, 1), CollectorRegistry())  # type: ignore[index]
    ).decode()
    assert 'tactile_device_status_bit{bit="over-temperature",device="hand",word="index-errors"} 1.0' in text
    assert 'tactile_device_status_bit{bit="stall",device="hand",word="index-errors"} 0.0' in text
    assert 'tactile_device_status_code{code="stall",device="hand",word="index-state"} 3.0' in text
    assert 'tactile_device_status_error{device="hand",word="index-state"} 1.0' in text


def test_a_word_not_read_reads_none_and_exports_nothing() -> None:
    from gateway.modbus.status_word import read_status_words

    (state, _) = read_status_words(hand().status_words, RegisterImage.from_reads([]))
    assert state.value is None and state.code is None and not state.error
    assert np.all([not on for _, _, on, _ in state.bits])


@pytest.mark.parametrize(
    ("words", "message"),
    [
        ('[[bus.device.status_word]]\nname = "w"\naddress = 10\nbits = { 16 = "x" }',
         "bit 16 is out of range; allowed: 0..15"),
        ('[[bus.device.status_word]]\nname = "w"\naddress = 10\nbits = { 1 = "a" }\nerrors = { 1 = "b" }',
         "bit 1 is named in bits and in errors"),
        ('[[bus.device.status_word]]\nname = "w"\naddress = 10\nbits = { 1 = "a" }\ncodes = { 0 = "b" }',
         "not both"),
        ('[[bus.device.status_word]]\nname = "w"\naddress = 11\nbits = { 1 = "a" }',
         "11 is an odd byte address"),
        ('[[bus.device.status_word]]\nname = "w"\naddress = 10\ncodes = { 0 = "a" }\nerror_codes = [2]',
         "2 is not one of the codes named in codes; allowed: [0]"),
        ('[[bus.device.status_word]]\nname = "w"\naddress = 10', "give bits and/or errors"),
        ('[[bus.device.status_word]]\nname = "w"\naddress = 131072\nbits = { 1 = "a" }',
         "131072 is out of range; allowed: 0..131071 bytes"),
    ],
)  # fmt: skip
def test_bad_status_words_are_refused_precisely(words: str, message: str) -> None:
    with pytest.raises(ConfigError) as exc:
        hand(words)
    assert message in str(exc.value), str(exc.value)


def test_a_profile_may_name_status_words_and_a_device_replaces_them(tmp_path: Path) -> None:
    (tmp_path / "hand.toml").write_text(
        DEVICE.split("[[bus.device]]")[1]
        .split("\n", 1)[1]
        .replace('name = "hand"\ndevice_id = 1\nchannels = 4\n', "channels = 4\n")
        .replace("[bus.device.", "[")
        .replace("[[bus.device.", "[[")
        .format(words=WORDS.replace("[[bus.device.", "[[")),
        encoding="utf-8",
    )
    head = (
        DEVICE.split("[[bus.device]]")[0]
        + '[[bus.device]]\nname = "hand"\ndevice_id = 1\nprofile = "hand.toml"\n'
    )
    dev = parse_config(head, source=tmp_path / "gateway.toml").buses[0].devices[0]
    assert [w.name for w in dev.status_words] == ["index-state", "index-errors"]
    own = head + '[[bus.device.status_word]]\nname = "mine"\naddress = 20\nbits = { 0 = "on" }\n'
    dev = parse_config(own, source=tmp_path / "gateway.toml").buses[0].devices[0]
    assert [(w.name, w.address) for w in dev.status_words] == [("mine", 10)]
