"""Fuzzing the register decoding (issue 16 §3): ``gateway.modbus.decode`` with random register
lists (values outside 0..65535, wrong types and shapes included), and ``decode_sample`` with
random ``RegisterImage``s of devices of every block type (adc and float32, with and without
status, clock, reference and temperature blocks, both word and byte orders). Only
``DecodeError`` may escape. Then ``DeviceProcessor`` converts every decodable sample without
raising, and puts no NaN or inf where the status says a value is valid.
"""

from __future__ import annotations

import functools
import math
import struct
import warnings

import numpy as np
from fuzz_support import FUZZ, Tally
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import DeviceConfig, RegisterMap, device_config_for
from gateway.errors import DecodeError
from gateway.modbus import decode
from gateway.modbus.image import RegisterImage, decode_sample
from gateway.modbus.register_map import DeviceClock, register_blocks
from gateway.model import Divider, LowSideDivider, SensorParams, Transimpedance
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import VALUED, ChannelStatus

# ----------------------------------------------------------------------------- decode.py
register_values = st.one_of(
    st.integers(0, 0xFFFF),
    st.sampled_from([-1, 0x10000, 2**31, 2**63 - 1, -(2**63), 2**64, 2**70, -(2**70)]),
    st.integers(),
)
register_lists = st.one_of(
    st.lists(st.integers(0, 0xFFFF), max_size=12),
    st.lists(register_values, max_size=12),
    st.lists(st.one_of(register_values, st.floats(), st.booleans()), max_size=6),
    st.lists(st.lists(st.integers(0, 0xFFFF), max_size=3), max_size=3),  # nested, ragged
    st.lists(st.text(max_size=3), max_size=3),
)
orders = st.sampled_from(["big", "little", "BIG", "", "middle"])


def test_fuzz_decode_functions() -> None:
    tally = Tally("decode: every function on random register lists")

    @settings(FUZZ, max_examples=300)
    @given(
        st.sampled_from(["as_registers", "uint16", "uint32", "uint64", "float32", "bitmap", "value"]),
        register_lists,
        orders,
        orders,
        st.integers(-3, 200),
    )
    def run(function: str, regs: list[object], word_order: str, byte_order: str, n: int) -> None:
        try:
            if function == "as_registers":
                out = decode.as_registers(regs, expected=n if n % 2 else None)
                assert out.dtype == np.uint16
            elif function == "uint16":
                out = decode.decode_uint16(regs, byte_order)
                assert out.dtype == np.uint16
            elif function == "uint32":
                out = decode.decode_uint32(regs, word_order, byte_order)
                assert np.all((out >= 0) & (out < 2**32))
            elif function == "uint64":
                decode.decode_uint64(regs, word_order, byte_order)
            elif function == "float32":
                out = decode.decode_float32(regs, word_order, byte_order)
                assert out.dtype == np.float64
            elif function == "bitmap":
                out = decode.decode_bitmap(regs, n, byte_order)
                assert out.shape == (max(n, 0),)
            else:
                ints = [r for r in regs if isinstance(r, int)]  # Sequence[int] by contract
                value = decode.register_value(ints, word_order, byte_order)
                assert 0 <= value < 2 ** (16 * len(ints))
        except DecodeError as exc:
            assert str(exc) and "\n" not in str(exc), repr(str(exc))
            tally(f"{function} refused")
            return
        tally(f"{function} decoded")

    run()
    tally.report()


# ------------------------------------------------------------------------ decode_sample
FRONT_ENDS = {
    "high_side": Divider(5.0, 10e3, 16),
    "low_side": LowSideDivider(5.0, 10e3, 12),
    "transimpedance": Transimpedance(bias_v=0.5, feedback_ohm=1e4, adc_reference_v=3.3, adc_bits=12),
}
EFFECTS = {
    "paper": ("tunneling", "contact", "creep"),
    "tunneling": ("tunneling",),
    "all": (
        "tunneling",
        "contact",
        "creep",
        "creep2",
        "hysteresis",
        "temperature",
        "series_resistance",
        "leakage",
    ),
}


@functools.cache
def device(
    encoding: str,
    n: int,
    status: bool,
    clock: int,
    reference: bool,
    temperature: bool,
    word_order: str,
    byte_order: str,
    table: str,
    front_end: str,
    effects: str,
) -> DeviceConfig:
    registers = RegisterMap(
        adc_address=100,
        float_address=400,
        word_order=word_order,
        byte_order=byte_order,
        status_address=16 if status else None,
        force_reference_address=1000 if reference else None,
        temperature_address=2000 if temperature else None,
        clock=DeviceClock(2, clock, 1e-3, table) if clock else None,
        table=table,
    )
    return device_config_for(
        "arr",
        1,
        [SensorParams()] * n,
        max(1, math.isqrt(n)),
        2.5,
        encoding=encoding,
        front_end=FRONT_ENDS[front_end],
        effects=EFFECTS[effects],
        registers=registers,
    )


devices = st.builds(
    device,
    st.sampled_from(["adc", "float32"]),
    st.sampled_from([1, 2, 5, 16, 17, 33]),
    st.booleans(),
    st.sampled_from([0, 1, 2, 4]),
    st.booleans(),
    st.booleans(),
    st.sampled_from(["big", "little"]),
    st.sampled_from(["big", "little"]),
    st.sampled_from(["input", "holding"]),
    st.sampled_from(list(FRONT_ENDS)),
    st.sampled_from(list(EFFECTS)),
)


def _float_words(value: float) -> tuple[int, int]:
    bits = struct.unpack(">I", struct.pack(">f", value))[0]
    return bits >> 16, bits & 0xFFFF


#: Register pairs that decode (in some order) to the floats a device should never send.
SPECIAL_PAIRS = [
    w
    for v in (math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e-45, 3.4e38, 1e-38, 1e3, 2e5)
    for w in (_float_words(v), _float_words(v)[::-1])
]
words = st.one_of(
    st.integers(0, 0xFFFF), st.sampled_from([0, 1, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF, 0x7F80, 0x7FC0, 0xFF80])
)


@st.composite
def block_values(draw: st.DrawFn, count: int) -> list[int]:
    style = draw(st.sampled_from(["random", "pairs", "constant"]))
    if style == "random":
        return draw(st.lists(words, min_size=count, max_size=count))
    if style == "constant":
        return [draw(words)] * count
    out: list[int] = []
    while len(out) < count:
        out.extend(draw(st.sampled_from(SPECIAL_PAIRS)))
    return out[:count]


@st.composite
def images(draw: st.DrawFn, dev: DeviceConfig) -> RegisterImage:
    """The device's blocks, each read, missing, short, shifted or of the other table, plus
    stray blocks."""
    reads = []
    for block in register_blocks(dev):
        fate = draw(st.sampled_from(["read"] * 6 + ["missing", "short", "shifted", "other table"]))
        kind, address, count = block.kind, block.address, block.count
        if fate == "missing":
            continue
        if fate == "short":
            count = max(0, count - draw(st.integers(1, count)))
        elif fate == "shifted":
            address = max(0, address + draw(st.integers(-3, 3)))
        elif fate == "other table":
            kind = "holding" if kind == "input" else "input"
        reads.append((kind, address, draw(block_values(count))))
    for _ in range(draw(st.integers(0, 2))):
        count = draw(st.integers(0, 40))
        reads.append(
            (
                draw(st.sampled_from(["input", "holding"])),
                draw(st.integers(0, 2100)),
                draw(block_values(count)),
            )
        )
    return RegisterImage.from_reads(draw(st.permutations(reads)))


def test_fuzz_decode_sample_and_the_processor() -> None:
    tally = Tally("decode_sample + DeviceProcessor on random register images (several per example)")
    examples: list[DeviceConfig] = []

    @settings(FUZZ, max_examples=300)
    @given(st.data(), devices, st.lists(st.floats(0.0, 1e5), min_size=1, max_size=4))
    def run(data: st.DataObject, dev: DeviceConfig, steps: list[float]) -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # no numpy warning reaches the log
            convert(data, dev, steps)

    def convert(data: st.DataObject, dev: DeviceConfig, steps: list[float]) -> None:
        examples.append(dev)
        processor = DeviceProcessor(dev, "bus", 0.1)
        state = processor.initial_state()
        host = 100.0
        for dt in steps:
            image = data.draw(images(dev))
            try:
                raw = decode_sample(dev, image)
            except DecodeError as exc:
                assert str(exc) and "\n" not in str(exc), repr(str(exc))
                tally("refused")
                continue
            host += dt
            snap, state = processor.process(state, raw, 1.7e9 + host, host)
            status = np.asarray(snap.status)
            valued = VALUED[status]
            bad = valued & ~np.isfinite(snap.force_n)
            assert not bad.any(), (
                f"{dev.encoding}: channels {np.nonzero(bad)[0].tolist()} have status "
                f"{[ChannelStatus(int(s)).label for s in status[bad]]} but force {snap.force_n[bad].tolist()}"
            )
            for view in snap.channels():
                for value in (view.resistance_ohm, view.force_n, view.force_static_n, view.reference_force_n):
                    assert value is None or math.isfinite(value), view
            assert math.isfinite(snap.total_force_n)
            assert snap.center_of_pressure_mm is None or all(
                math.isfinite(c) for c in snap.center_of_pressure_mm
            )
            assert snap.peak_force_n is None or math.isfinite(snap.peak_force_n)
            assert math.isfinite(snap.contact_area_mm2)
            tally("converted")

    run()
    print(f"FUZZ decode_sample + DeviceProcessor: {len(examples)} hypothesis examples")
    tally.report()
