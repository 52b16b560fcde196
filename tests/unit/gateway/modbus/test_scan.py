"""The scan analysis (``gateway.modbus.scan``) on hand-made snapshots: what an unknown board's
registers suggest, and that no snapshot set makes it fail."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import parse_config
from gateway.modbus.scan import (
    ClockCandidate,
    ConstantRegister,
    Snapshot,
    adc_bits_for,
    analyse,
    config_snippet,
    constant_runs,
    printable_text,
)

IDS = [0x5447, 0x0103, 0x0000, 0x0001, 0xE240, 0x0007]
FRAME_ADDRESS, CHANNELS = 32, 36


def board(
    rounds: int = 20,
    interval_s: float = 0.2,
    load: bool = True,
    seed: int = 3,
    extra: Callable[[float, dict[int, int | None]], None] | None = None,
) -> list[Snapshot]:
    """An undocumented board read ``rounds`` times over input 0..79: ids at 0-5, unreadable
    6-9, a uint32 ms counter at 10-11 (crossing 65536), unreadable 12-31, 36 12-bit counts
    at 32 (idle near 3000 with 2 LSB noise, a load moving across), unreadable 68-79."""
    rng = np.random.default_rng(seed)
    snapshots: list[Snapshot] = []
    for k in range(rounds):
        t = 100.0 + k * interval_s + float(rng.uniform(-0.002, 0.002))
        regs: dict[int, int | None] = dict.fromkeys(range(80))
        regs.update(enumerate(IDS))
        ms = 64_000 + round((t - 100.0) * 1000.0)
        regs[10], regs[11] = ms >> 16, ms & 0xFFFF
        centre = CHANNELS * k / rounds
        for i in range(CHANNELS):
            counts = 3000.0 + rng.normal(0.0, 2.0)
            if load:
                counts -= 1500.0 * math.exp(-(((i - centre) / 2.0) ** 2))
            regs[FRAME_ADDRESS + i] = int(np.clip(round(counts), 0, 4095))
        if extra is not None:
            extra(t, regs)
        snapshots.append((t, {"input": regs}))
    return snapshots


def test_the_frame_is_the_first_suggestion() -> None:
    result = analyse(board())
    best = result.best_frame
    assert best is not None
    assert (best.table, best.address, best.count, best.bits) == ("input", FRAME_ADDRESS, CHANNELS, 12)
    assert best.changed == CHANNELS and not best.float_like
    assert all(f.address >= FRAME_ADDRESS for f in result.frames), "the ids and the clock are no frame"


def test_an_idle_frame_with_only_noise_is_found() -> None:
    result = analyse(board(rounds=5, load=False))
    best = result.best_frame
    assert best is not None and (best.address, best.count, best.bits) == (FRAME_ADDRESS, CHANNELS, 12)


def test_the_ms_counter_is_the_clock() -> None:
    result = analyse(board())
    assert [(c.table, c.address, c.registers, c.unit) for c in result.clocks] == [("input", 10, 2, "ms")]
    clock = result.clocks[0]
    assert clock.rate_per_s == pytest.approx(1000.0, rel=0.02)
    assert clock.type_name == "uint32" and clock.tick_s == 1e-3 and clock.description == "ms"


def test_the_id_registers_are_constants_and_no_frame() -> None:
    result = analyse(board())
    assert [(c.address, c.value) for c in result.constants] == list(enumerate(IDS))
    assert constant_runs(result.constants) == [("input", 0, IDS)]
    assert printable_text(IDS) == ["TG"]


def test_register_statistics() -> None:
    result = analyse(board(rounds=6))
    ident = result.stats("input", 4)
    assert ident is not None and (ident.minimum, ident.maximum, ident.distinct, ident.changed) == (
        0xE240,
        0xE240,
        1,
        False,
    )
    gap = result.stats("input", 7)
    assert gap is not None and not gap.readable and gap.unreadable == 6 and gap.minimum is None
    channel = result.stats("input", FRAME_ADDRESS)
    assert channel is not None and channel.changed and channel.samples == 6
    assert result.stats("input", 500) is None and result.snapshots == 6


def test_a_constant_block_next_to_a_live_register_is_no_frame() -> None:
    """Eight configuration words and one status register that toggles: not an ADC frame."""

    def status(t: float, regs: dict[int, int | None]) -> None:
        regs.update({70 + k: 0x1000 + 17 * k for k in range(8)})
        regs[78] = round(t * 10) % 2

    result = analyse(board(extra=status))
    assert [f.address for f in result.frames] == [FRAME_ADDRESS]


def test_a_uint64_ms_clock_after_a_uint32_sample_counter() -> None:
    """The simulator's layout: sample counter at 0-1 (100 Hz), uint64 device time in ms at
    2-5 whose upper words are still zero."""
    snapshots: list[Snapshot] = []
    for k in range(8):
        t = 5.0 + 0.1 * k
        counter, ms = round(t * 100), round(t * 1000)
        regs = {0: counter >> 16, 1: counter & 0xFFFF, 2: 0, 3: 0, 4: ms >> 16, 5: ms & 0xFFFF, 6: 4}
        snapshots.append((t, {"input": regs}))
    clocks = analyse(snapshots).clocks
    assert [(c.address, c.registers, c.unit) for c in clocks] == [(0, 2, None), (2, 4, "ms")]
    assert clocks[0].description == "ticks at 100 Hz" and clocks[0].tick_s == pytest.approx(0.01)
    result = analyse(snapshots)
    assert result.best_clock is not None and result.best_clock.address == 2
    assert [c.address for c in result.constants] == [6], "clock words are no constants"


@pytest.mark.parametrize(
    ("per_s", "registers", "unit"),
    [(1.0, 1, "s"), (1e3, 2, "ms"), (1e6, 2, "us"), (32768.0, 2, None), (1e6, 4, "us")],
)
def test_clock_units(per_s: float, registers: int, unit: str | None) -> None:
    snapshots: list[Snapshot] = []
    for k in range(20):
        t = 1000.0 + 0.2 * k
        value = int((t - 1000.0) * per_s) + 12345
        words = [(value >> (16 * (registers - 1 - j))) & 0xFFFF for j in range(registers)]
        snapshots.append((t, {"holding": dict(enumerate(words, start=40))}))
    clocks = analyse(snapshots).clocks
    assert [(c.table, c.address, c.registers, c.unit) for c in clocks] == [("holding", 40, registers, unit)]
    assert clocks[0].rate_per_s == pytest.approx(per_s, rel=0.1)


def test_a_constant_word_before_a_counter_is_not_its_high_word() -> None:
    """A version word (0x0103) and then a 16-bit ms counter: read as the uint16 it may well
    be; the gateway steps a narrow counter modulo its range, so this reading stays right
    even if the word above is the counter's after all."""
    snapshots: list[Snapshot] = [
        (t, {"input": {0: 0x0103, 1: round(t * 1000) & 0xFFFF}}) for t in (0.1 * k for k in range(10))
    ]
    result = analyse(snapshots)
    assert [(c.address, c.registers, c.unit) for c in result.clocks] == [(1, 1, "ms")]
    assert [(c.address, c.value) for c in result.constants] == [(0, 0x0103)]


def test_two_slow_counters_side_by_side_are_two_clocks() -> None:
    """A seconds counter and a minutes-ish counter next to each other: no carry links them,
    so they are not one uint32."""
    snapshots: list[Snapshot] = [
        (t, {"input": {20: int(t) // 3, 21: int(t)}}) for t in (0.5 * k + 0.25 for k in range(30))
    ]
    clocks = analyse(snapshots).clocks
    assert [(c.address, c.registers) for c in clocks] == [(20, 1), (21, 1)]
    assert clocks[1].unit == "s"


def test_a_ramping_channel_inside_the_frame_is_no_clock() -> None:
    def ramp(t: float, regs: dict[int, int | None]) -> None:
        regs[FRAME_ADDRESS + 10] = 1000 + round((t - 100.0) * 200.0)

    result = analyse(board(extra=ramp))
    assert [c.address for c in result.clocks] == [10]
    assert result.best_frame is not None and result.best_frame.count == CHANNELS


@pytest.mark.parametrize("edge", [FRAME_ADDRESS, FRAME_ADDRESS + CHANNELS - 1])
def test_a_frame_edge_channel_whose_noise_rises_every_round_is_no_clock(edge: int) -> None:
    """Seen under load on the simulator's rawgrid map: in 5 rounds the first channel's noise
    rose at every round (+1 or +2 counts), steady enough for a slow counter; nothing is left
    of it (6-31 unreadable), so only the rest of the frame can tell it is a channel."""

    def rising(t: float, regs: dict[int, int | None]) -> None:
        k = round((t - 100.0) / 0.1)
        regs[edge] = 2995 + 2 * k

    result = analyse(board(rounds=5, interval_s=0.1, load=False, extra=rising))
    assert [c.address for c in result.clocks] == [10]
    best = result.best_frame
    assert best is not None and (best.address, best.count) == (FRAME_ADDRESS, CHANNELS)


@pytest.mark.parametrize("rounds", [3, 5, 20])
def test_a_frame_of_steadily_rising_channels_is_no_row_of_clocks(rounds: int) -> None:
    """A probe pressing in: every channel rises steadily, so any two neighbours read as a
    "uint32" that rises steadily too. They are ADC channels, and the frame stays whole."""

    def pressing(t: float, regs: dict[int, int | None]) -> None:
        k = round((t - 100.0) / 0.2)
        regs.update({FRAME_ADDRESS + i: 1000 + 80 * i + (25 + i) * k for i in range(CHANNELS)})

    result = analyse(board(rounds=rounds, extra=pressing))
    assert [c.address for c in result.clocks] == [10]
    best = result.best_frame
    assert best is not None and (best.address, best.count) == (FRAME_ADDRESS, CHANNELS)


def test_float32_pairs_are_marked_and_rank_below_adc_counts() -> None:
    rng = np.random.default_rng(1)

    def floats(t: float, regs: dict[int, int | None]) -> None:
        values = np.asarray(20e3 + rng.normal(0.0, 5.0, size=6), dtype=">f4").view(">u2")
        regs.update({70 + k: int(w) for k, w in enumerate(values)})

    result = analyse(board(extra=floats))
    by_address = {f.address: f for f in result.frames}
    assert by_address[70].float_like and not by_address[FRAME_ADDRESS].float_like
    assert result.frames[0].address == FRAME_ADDRESS


def test_16_bit_counts_that_read_as_float_words_are_still_counts() -> None:
    """Counts around 18000 are plausible float32 high words, on every register alike."""

    def high_counts(t: float, regs: dict[int, int | None]) -> None:
        regs.update({FRAME_ADDRESS + i: int(regs[FRAME_ADDRESS + i] or 0) + 15_000 for i in range(CHANNELS)})

    best = analyse(board(extra=high_counts)).best_frame
    assert best is not None and best.bits == 16 and not best.float_like


def test_the_config_snippet_is_toml_for_the_device() -> None:
    text = config_snippet(analyse(board()), device_id=7)
    assert text is not None
    device = tomllib.loads(text)["bus"]["device"][0]
    assert device["device_id"] == 7 and device["channels"] == CHANNELS and device["encoding"] == "adc"
    assert device["registers"] == {"table": "input", "adc_address": FRAME_ADDRESS}
    assert device["front_end"] == {
        "kind": "high_side",
        "supply_v": 3.3,
        "reference_ohm": 10000.0,
        "adc_bits": 12,
    }
    assert device["clock"] == {"table": "input", "address": 10, "registers": 2, "unit": "ms"}
    # with a bus and a name, the gateway accepts it as it stands
    named = text.replace("[[bus.device]]\n", '[[bus.device]]\nname = "found"\n', 1)
    config = parse_config('[[bus]]\nname = "b"\nkind = "tcp"\nhost = "h"\n\n' + named)
    dev = config.buses[0].devices[0]
    assert (dev.registers.adc_address, dev.n_channels, dev.front_end.adc_bits) == (
        FRAME_ADDRESS,
        CHANNELS,
        12,
    )
    assert dev.registers.clock is not None and dev.registers.clock.tick_s == 1e-3


def test_the_config_snippet_without_clock_and_with_ticks() -> None:
    def no_clock(t: float, regs: dict[int, int | None]) -> None:
        regs[10] = regs[11] = None

    device = tomllib.loads(config_snippet(analyse(board(extra=no_clock))) or "")["bus"]["device"][0]
    assert "clock" not in device and "device_id" not in device

    def ticks(t: float, regs: dict[int, int | None]) -> None:
        regs[10], regs[11] = 0, round(t * 100) & 0xFFFF

    device = tomllib.loads(config_snippet(analyse(board(extra=ticks))) or "")["bus"]["device"][0]
    assert device["clock"]["tick_s"] == pytest.approx(0.01) and "unit" not in device["clock"]


def test_without_a_frame_there_is_no_snippet() -> None:
    snapshots: list[Snapshot] = [(float(k), {"input": dict(enumerate(IDS))}) for k in range(5)]
    result = analyse(snapshots)
    assert result.frames == () and result.clocks == () and len(result.constants) == len(IDS)
    assert config_snippet(result) is None


def test_one_snapshot_suggests_nothing() -> None:
    """Without a second reading a constant block and a frame look alike."""
    result = analyse(board(rounds=1))
    assert result.frames == () and result.clocks == () and result.constants == ()
    assert analyse([]).registers == ()


@pytest.mark.parametrize(("maximum", "bits"), [(0, 10), (1023, 10), (1024, 12), (4095, 12), (16384, 16)])
def test_adc_bits_is_the_smallest_width_that_fits(maximum: int, bits: int) -> None:
    assert adc_bits_for(maximum) == bits


def test_printable_text_keeps_codes_and_drops_float_words() -> None:
    assert printable_text([0x4142, 0x4344, 0x0000, 0x3C23]) == ["ABCD"]
    assert printable_text([0x40A0, 0x461C]) == []
    assert constant_runs(
        [ConstantRegister("input", 1, 5), ConstantRegister("input", 2, 6), ConstantRegister("input", 9, 7)]
    ) == [("input", 1, [5, 6]), ("input", 9, [7])]


def test_clock_candidate_descriptions() -> None:
    assert ClockCandidate("input", 0, 2, 250_000.0, None).description == "ticks at 250 kHz"
    assert ClockCandidate("input", 0, 4, 2.5e6, None).description == "ticks at 2.5 MHz"
    assert ClockCandidate("input", 0, 1, 1.0, "s").end == 0


values = st.one_of(st.none(), st.integers(0, 0xFFFF), st.sampled_from([0, 1, 0xFFFF, 0x8000]))
tables = st.dictionaries(st.integers(0, 40), values, max_size=30)
snapshot_sets = st.lists(
    st.tuples(
        st.floats(-1e6, 1e6, allow_nan=False),
        st.dictionaries(st.sampled_from(["input", "holding"]), tables, max_size=2),
    ),
    max_size=12,
)


@settings(max_examples=300, deadline=None)
@given(snapshots=snapshot_sets)
def test_any_snapshot_set_is_analysed_without_error(snapshots: list[Snapshot]) -> None:
    result = analyse(snapshots)
    config_snippet(result, device_id=1)
    clock_registers = {(c.table, a) for c in result.clocks for a in range(c.address, c.end + 1)}
    covered: set[tuple[str, int]] = set()
    for f in result.frames:
        span = {(f.table, a) for a in range(f.address, f.end + 1)}
        assert f.count >= 4 and f.bits in (10, 12, 14, 16) and 0.0 <= f.score <= 100.0
        assert not span & clock_registers and not span & covered
        covered |= span
    for c in result.clocks:
        assert c.registers in (1, 2, 4) and c.rate_per_s > 0
    assert not {(c.table, c.address) for c in result.constants} & (clock_registers | covered)


@st.composite
def counting_snapshots(draw: st.DrawFn) -> list[Snapshot]:
    """Registers that mostly rise, with random steps, wraps, gaps and equal times: the clock
    search's corners."""
    n = draw(st.integers(0, 10))
    times = sorted(draw(st.lists(st.floats(0.0, 100.0), min_size=n, max_size=n)))
    width = draw(st.integers(1, 6))
    value = draw(st.integers(0, 2**64 - 1))
    snapshots: list[Snapshot] = []
    for t in times:
        value = (value + draw(st.integers(0, 2**40))) % 2**64
        words = [(value >> (16 * (3 - k))) & 0xFFFF for k in range(4)]
        regs: dict[int, int | None] = {
            k: draw(st.one_of(st.none(), st.just(words[k % 4]))) for k in range(width)
        }
        snapshots.append((t, {"input": regs}))
    return snapshots


@settings(max_examples=300, deadline=None)
@given(snapshots=counting_snapshots())
def test_rising_registers_are_analysed_without_error(snapshots: list[Snapshot]) -> None:
    result = analyse(snapshots)
    for c in result.clocks:
        assert c.rate_per_s > 0 and c.tick_s > 0 and c.description
