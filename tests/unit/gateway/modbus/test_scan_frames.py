"""The frame the scan suggests on a DFRobot-style board (issue 23 item 6): identity and count
registers next to the frame are constants, never cells of it, and idle cells inside and at
the ends of the frame stay in it."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from gateway.config import parse_config
from gateway.modbus.scan import Snapshot, analyse, config_snippet, constant_runs
from gateway.modbus.scan_snippet import count_register, identity_registers

VID = PID = 0x3343
FRAME, CELLS, COUNT = 7, 36, 43


def dfrobot(
    rounds: int = 20, gap: str = "zero", idle_value: int = 9, idle: tuple[int, ...] = (0, 4, 17, 18, 35)
) -> list[Snapshot]:
    """Input 0 = VID, 1 = PID, 2..6 zeros (``gap="zero"``) or unreadable (``"absent"``), 36
    12-bit cells at 7..42 (a press moving across the 6x6 grid on a noise floor of 10-30
    counts; the ``idle`` cells read ``idle_value`` and never move), 43 = 36."""
    rng = np.random.default_rng(5)
    snapshots: list[Snapshot] = []
    for k in range(rounds):
        regs: dict[int, int | None] = {0: VID, 1: PID, COUNT: CELLS}
        regs.update(dict.fromkeys(range(2, FRAME), 0 if gap == "zero" else None))
        x, y = 5.0 * k / rounds, 2.5
        for i in range(CELLS):
            r2 = (i % 6 - x) ** 2 + (i // 6 - y) ** 2
            counts = 20 + rng.integers(-10, 11) + 3000.0 * math.exp(-r2 / 2.0)
            regs[FRAME + i] = idle_value if i in idle else int(min(counts, 4095))
        snapshots.append((10.0 + 0.2 * k, {"input": regs}))
    return snapshots


@pytest.mark.parametrize("gap", ["zero", "absent"])
def test_the_frame_is_input_7_to_42_without_the_id_and_count_registers(gap: str) -> None:
    result = analyse(dfrobot(gap=gap))
    best = result.best_frame
    assert best is not None
    assert (best.table, best.address, best.count, best.end, best.bits) == ("input", FRAME, CELLS, 42, 12)
    assert best.changed == CELLS - 5
    assert [(f.address, f.count) for f in result.frames] == [(FRAME, CELLS)]
    constants = {(c.address, c.value) for c in result.constants}
    assert {(0, VID), (1, PID), (COUNT, CELLS)} <= constants
    if gap == "zero":
        assert constant_runs(result.constants) == [
            ("input", 0, [VID, PID, 0, 0, 0, 0, 0]),
            ("input", 43, [36]),
        ]


def test_idle_cells_reading_zero_like_the_gap_are_cut_by_the_count_register() -> None:
    """Idle cells at 0, the first cell among them, read like the zeros of the gap before the
    frame; the count register after it (36) says where the frame starts."""
    result = analyse(dfrobot(idle_value=0))
    best = result.best_frame
    assert best is not None and (best.address, best.count) == (FRAME, CELLS)
    assert count_register(result) is not None


def test_the_snippet_suggests_the_id_and_count_checks() -> None:
    result = analyse(dfrobot())
    count = count_register(result)
    assert count is not None and (count.table, count.address, count.value) == ("input", COUNT, CELLS)
    assert [(c.address, c.value) for c in identity_registers(result)] == [(0, VID), (1, PID)]
    text = config_snippet(result, device_id=1)
    assert text is not None
    device = tomllib.loads(text)["bus"]["device"][0]
    assert device["channels"] == CELLS and device["registers"] == {"table": "input", "adc_address": FRAME}
    assert device["front_end"]["adc_bits"] == 12
    assert device["checks"] == {
        "registers": [
            {"what": "identifier", "table": "input", "address": 0, "value": VID},
            {"what": "identifier", "table": "input", "address": 1, "value": PID},
        ],
        "channel_count": {"table": "input", "address": COUNT},
    }
    named = text.replace("[[bus.device]]\n", '[[bus.device]]\nname = "dfr"\n', 1)
    config = parse_config('[[bus]]\nname = "b"\nkind = "tcp"\nhost = "h"\n\n' + named)
    checks = config.buses[0].devices[0].checks
    assert [(c.what, c.table, c.address, c.value) for c in checks.registers] == [
        ("identifier", "input", 0, VID),
        ("identifier", "input", 1, PID),
        ("channel count", "input", COUNT, CELLS),
    ]


def test_a_constant_inside_the_frame_out_of_the_codes_range_splits_it() -> None:
    """A frame's constant cells stay in it; an identifier-like word inside a run does not."""

    def with_word(snapshots: list[Snapshot]) -> list[Snapshot]:
        return [(t, {"input": {**regs["input"], FRAME + 18: 0xBEEF}}) for t, regs in snapshots]

    result = analyse(with_word(dfrobot(idle=(4, 30))))
    assert sorted((f.address, f.count) for f in result.frames) == [(FRAME, 18), (FRAME + 19, 17)]
    assert (FRAME + 18, 0xBEEF) in {(c.address, c.value) for c in result.constants}
