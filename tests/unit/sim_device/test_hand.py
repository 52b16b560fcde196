"""The simulated hand's logic (``sim_device.hand``): regions, layouts, the transimpedance
read-out and its saturation code, 30 Hz frames by the device's own clock, dead, frozen and
stuck taxels, joints, status codes and error bits, and the hand's scenario files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim_device import hand_map as hm
from sim_device.hand import FRAME_PERIOD_S, HandDevice, HandWriteError, raw_from_resistance
from sim_device.hand_scenarios import TaxelSpec, load_hand_scenario, parse_taxel_specs
from sim_device.profiles import ScenarioError


class Clock:
    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def hand(scenario: str = "idle", clock: Clock | None = None, **options: object) -> HandDevice:
    return HandDevice(scenario, clock=clock or Clock(), noise_lsb=0.0, **options)  # type: ignore[arg-type]


def test_seventeen_regions_of_the_public_shapes_sum_to_1062() -> None:
    sizes = {r.name: (r.rows, r.columns) for r in hm.REGIONS}
    assert len(sizes) == 17
    for finger in ("index", "middle", "ring", "little"):
        assert (sizes[f"{finger}-tip"], sizes[f"{finger}-nail"], sizes[f"{finger}-pad"]) == (
            (3, 3),
            (12, 8),
            (10, 8),
        )
    assert [sizes[f"thumb-{p}"] for p in ("tip", "nail", "middle", "pad")] == [
        (3, 3),
        (12, 8),
        (3, 3),
        (12, 8),
    ]
    assert sizes["palm"] == (14, 8)
    per_group = {g: sum(r.size for r in hm.REGIONS if r.group == g) for g in hm.PUBLIC_BLOCK_BYTES}
    assert per_group == {"little": 185, "ring": 185, "middle": 185, "index": 185, "thumb": 210, "palm": 112}
    assert hm.N_TAXELS == 4 * 185 + 210 + 112 == 1062


def test_byte_layout_halves_the_public_addresses_and_blocks_are_contiguous() -> None:
    layout = hm.Layout("byte")
    assert [layout.block_address(g) for g in hm.PUBLIC_BLOCK_BYTES] == [1500, 1685, 1870, 2055, 2240, 2450]
    a = layout.addresses()
    assert (a["little-tip"], a["little-nail"], a["little-pad"]) == (1500, 1509, 1605)
    assert (a["thumb-tip"], a["thumb-nail"], a["thumb-middle"], a["thumb-pad"]) == (2240, 2249, 2345, 2354)
    # 185 registers per finger: 370 bytes, the distance between the public byte addresses
    assert a["ring-tip"] - a["little-tip"] == 185 and a["palm"] - a["thumb-tip"] == 210


def test_register_layout_and_offset_shift_every_block() -> None:
    assert hm.Layout("register").addresses()["palm"] == 4900
    shifted = hm.Layout("register", 100).addresses()
    assert shifted["little-tip"] == 3100 and shifted["index-pad"] == 4110 + 100 + 9 + 96
    assert hm.Layout("byte", -300).addresses()["little-tip"] == 1200


@pytest.mark.parametrize(
    ("kind", "offset", "message"),
    [
        ("word", 0, "must be one of byte, register"),
        ("byte", -500, "overlaps the control registers 1000..1039"),
        ("register", 61000, "outside 0..65535"),
    ],
)
def test_a_layout_that_cannot_be_served_is_refused(kind: str, offset: int, message: str) -> None:
    with pytest.raises(hm.LayoutError, match=message):
        hm.Layout(kind, offset)


def test_raw_value_is_proportional_to_conductance_and_saturates_to_the_code() -> None:
    r_ohm = np.array([np.inf, 65535.0, 2000.0, 1010.0, 1004.0, 500.0])
    raw = raw_from_resistance(r_ohm, 0.0, 0xFFFF)
    # 65535 * 1000 / r: 0, 1000, 32767.5 -> 32768, 64886, 65274 (below 0xFF00), saturated
    assert raw.tolist() == [0, 1000, 32768, 64886, 65274, 0xFFFF]
    assert raw_from_resistance(np.array([900.0]), 0.0, 0xFF00).tolist() == [0xFF00]


def test_registers_change_once_a_frame_by_the_device_clock() -> None:
    clock = Clock()
    h = HandDevice("sine", clock=clock, noise_lsb=2.0)
    first = h.taxels("palm")
    clock.now_s = 0.9 * FRAME_PERIOD_S
    assert np.array_equal(h.taxels("palm"), first) and h.frame_index == 0
    clock.now_s = 1.01 * FRAME_PERIOD_S
    assert h.frame_index == 1 and not np.array_equal(h.taxels("palm"), first)
    second = h.taxels("palm")
    clock.now_s = 1.99 * FRAME_PERIOD_S
    assert np.array_equal(h.taxels("palm"), second)
    clock.now_s = 1.0  # 30 frames a second
    assert h.frame_index == 30


def test_values_rise_with_pressure_and_idle_reads_zero() -> None:
    idle = hand("idle").taxels("palm")
    assert idle.max() == 0
    light = hand("palm-held").taxels("palm")
    heavy = HandDevice("palm-held", clock=Clock(), noise_lsb=0.0, param_spread=False)
    assert light.min() > 0 and hand("palm-held").taxels("index-pad").max() == 0
    assert heavy.taxels("palm").min() > 0


def test_a_heavy_load_reads_the_saturation_code(tmp_path: Path) -> None:
    path = tmp_path / "crush.toml"
    path.write_text(
        "[region.palm]\n[[region.palm.load]]\nchannels = [0, 1]\ninitial_n = 50.0\nsteps = [{ hold_s = 1 }]\n"
    )
    h = HandDevice(str(path), clock=Clock(), noise_lsb=0.0, saturation_code=0xFFFE)
    palm = h.taxels("palm")
    assert palm[:2].tolist() == [0xFFFE, 0xFFFE] and palm[2:].max() == 0


def test_dead_frozen_and_stuck_taxels() -> None:
    clock = Clock()
    h = HandDevice(
        "grasp",
        clock=clock,
        dead=parse_taxel_specs("thumb-pad,palm:17", "--dead"),
        frozen=parse_taxel_specs("middle-tip,index-tip:4=1234", "--frozen", allow_value=True),
        stuck=parse_taxel_specs("palm:5", "--stuck"),
    )
    clock.now_s = 4.5  # palm pressed, fingers touching
    palm = h.taxels("palm")
    assert h.taxels("thumb-pad").max() == 0 and palm[17] == 0
    assert palm[5] == 0xFFFF and palm[4] > 0
    frozen_at_start = HandDevice("grasp", clock=Clock(), frozen=[TaxelSpec("middle-tip")]).taxels(
        "middle-tip"
    )
    assert h.taxels("middle-tip").max() <= frozen_at_start.max() + 20  # unloaded values at t = 0
    assert h.taxels("ring-tip").min() > 500  # its neighbours touch
    assert h.taxels("index-tip")[4] == 1234 and h.taxels("index-tip")[3] > 500
    before = h.taxels("middle-tip")
    clock.now_s = 9.0
    assert np.array_equal(h.taxels("middle-tip"), before)


def test_taxel_specs_are_checked_precisely() -> None:
    with pytest.raises(ValueError, match="no region 'thumb-pads'"):
        parse_taxel_specs("thumb-pads", "--dead")
    with pytest.raises(ValueError, match=r"thumb-tip has taxels 0\.\.8, not 9"):
        parse_taxel_specs("thumb-tip:9", "--dead")
    with pytest.raises(ValueError, match="only frozen taxels take =VALUE"):
        parse_taxel_specs("palm:1=3", "--stuck")


def test_set_points_move_the_joints_and_status_codes_follow() -> None:
    clock = Clock()
    h = hand("idle", clock)
    h.write(hm.HR_ANGLE_SET, [500, 1000])
    h.write(hm.HR_FORCE_SET + 2, [150])
    assert h.read(hm.HR_ANGLE_SET, 3) == [500, 1000, 0] and h.read(hm.HR_FORCE_SET + 2, 1) == [150]
    assert h.read(hm.HR_STATUS, 2) == [1, 1]  # grasping
    clock.now_s = 0.3  # 1000 per mille a second: 300 after 0.3 s
    assert h.read(hm.HR_ANGLE_ACTUAL, 2) == [300, 300]
    clock.now_s = 0.6
    assert h.read(hm.HR_ANGLE_ACTUAL, 2) == [500, 600] and h.read(hm.HR_STATUS, 2) == [0, 1]


def test_a_force_set_point_stops_the_finger_when_reached() -> None:
    clock = Clock()
    h = hand("grasp", clock)
    h.write(hm.HR_FORCE_SET + 3, [100])  # 1 N on the index
    clock.now_s = 2.9  # the touch starts at 3 s: 0 -> 0.8 N a taxel over 0.5 s
    h.write(hm.HR_ANGLE_SET + 3, [1000])
    assert h.read(hm.HR_FORCE_ACTUAL + 3, 1) == [0] and h.read(hm.HR_STATUS + 3, 1) == [1]
    clock.now_s = 3.3
    # 89 tip and pad taxels reach 1 N in all at 0.011 N each, a frame after 3 s
    force, angle = h.read(hm.HR_FORCE_ACTUAL + 3, 1)[0], h.read(hm.HR_ANGLE_ACTUAL + 3, 1)[0]
    assert force >= 100 and h.read(hm.HR_STATUS + 3, 1) == [2]
    assert 100 <= angle <= 200  # moved 0.1 s + a frame or two at 1000 per mille a second, then stopped
    clock.now_s = 3.8
    assert h.read(hm.HR_ANGLE_ACTUAL + 3, 1) == [angle]


def test_error_bits_and_the_status_they_give() -> None:
    h = hand()
    h.set_error("index", "stall")
    h.set_error("thumb-rotate", "over-temperature")
    h.set_error("thumb-rotate", "communication")
    assert h.read(hm.HR_ERRORS, 6) == [0, 0, 0, 0b1, 0, 0b10010]
    assert h.read(hm.HR_STATUS, 6) == [0, 0, 0, 3, 0, 4]
    h.set_error("index", "stall", on=False)
    assert h.read(hm.HR_STATUS + 3, 1) == [0]
    with pytest.raises(ValueError, match="no error bit 'hot'"):
        h.set_error("index", "hot")


def test_writes_are_refused_outside_the_set_points_and_their_ranges() -> None:
    h = hand()
    with pytest.raises(HandWriteError, match="1016 is not writable") as exc:
        h.write(hm.HR_ANGLE_ACTUAL, [1])
    assert exc.value.code == 2
    with pytest.raises(HandWriteError, match=r"0\.\.1000") as exc:
        h.write(hm.HR_ANGLE_SET, [1, 1001])
    assert exc.value.code == 3 and h.angle_set[0] == 0  # all or nothing


def test_force_calibration_register_leaves_the_taxels_alone() -> None:
    h = hand("palm-held")
    before = h.taxels("palm")
    h.write(hm.HR_FORCE_CALIBRATE, [1])
    assert h.force_calibrations == 1 and np.array_equal(h.taxels("palm"), before)
    assert h.read(hm.HR_FORCE_CALIBRATE, 1) == [0]


def test_hand_scenario_file(tmp_path: Path) -> None:
    path = tmp_path / "touch.toml"
    path.write_text(
        'name = "touch"\ndead = ["thumb"]\nfrozen = ["middle-tip=7"]\nstuck = ["palm:3"]\n'
        "[region.index-tip]\nsettled = true\n[[region.index-tip.load]]\n"
        "initial_n = 1.0\nsteps = [{ hold_s = 5 }]\n"
    )
    with pytest.raises(ScenarioError, match="no region 'thumb'"):
        load_hand_scenario(str(path))
    path.write_text(path.read_text().replace('dead = ["thumb"]', 'dead = ["thumb-tip"]'))
    h = HandDevice(str(path), clock=Clock(), noise_lsb=0.0)
    assert h.scenario.name == "touch"
    assert h.taxels("thumb-tip").max() == 0 and h.taxels("middle-tip").tolist() == [7] * 9
    assert h.taxels("palm")[3] == 0xFFFF and h.taxels("index-tip").min() > 0
    assert h.taxels("index-pad").max() == 0


def test_unknown_scenario_names_the_hand_ones() -> None:
    with pytest.raises(ScenarioError, match="grasp, slide, palm-held"):
        load_hand_scenario("graps")


def test_slide_moves_the_contact_along_the_palm() -> None:
    clock = Clock()
    h = hand("slide", clock)
    columns = []
    for t_s in (4.0, 12.0, 20.0):  # pressed in by 2 s, then sliding at 1 mm/s along the 8 columns
        clock.now_s = t_s
        force = h.true_force_n("palm").reshape(14, 8)
        columns.append(int(np.argmax(force.sum(axis=0))))
        assert h.taxels("palm").reshape(14, 8)[:, columns[-1]].max() > 0
    assert columns[0] < columns[1] < columns[2]
    assert h.taxels("thumb-pad").max() == 0


def test_palm_held_is_loaded_and_settled_from_the_start() -> None:
    clock = Clock()
    h = hand("palm-held", clock)
    start = h.taxels("palm").astype(float)
    clock.now_s = 60.0
    later = h.taxels("palm").astype(float)
    # settled: no creep left, the values stay within a few per cent over a minute
    assert start.min() > 300 and np.all(np.abs(later - start) <= 0.03 * start)
    assert all(h.taxels(r.name).max() == 0 for r in hm.REGIONS if r.name != "palm")


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["--layout", "register"], 2, "only used with --map hand"),
        (["--map", "skin60", "--dead", "palm"], 2, "only used with --map hand"),
        (
            ["--map", "hand", "--record", "x.csv"],
            2,
            "--record and --log-requests are not used with --map hand",
        ),
        (["--map", "hand", "--dead", "thumb-pads"], 1, "--dead: no region 'thumb-pads'"),
        (["--map", "hand", "--frozen", "palm:112"], 1, "--frozen: palm has taxels 0..111, not 112"),
        (["--map", "hand", "--base-offset", "-600"], 1, "overlaps the control registers 1000..1039"),
        (["--map", "hand", "--joint-error", "index"], 1, "is not JOINT:BIT"),
        (["--map", "hand", "--scenario", "graps"], 1, "or a hand scenario (grasp, slide, palm-held)"),
    ],
)
def test_command_line_refuses_bad_hand_options_precisely(args: list[str], code: int, message: str) -> None:
    from click.testing import CliRunner

    from sim_device.cli import main

    result = CliRunner().invoke(main, ["run", *args, "--stop-after", "0"])
    assert result.exit_code == code, result.output
    assert message in result.output and "Traceback" not in result.output


def test_rest_offsets_are_each_taxels_own_and_fixed() -> None:
    clock = Clock()
    h = HandDevice("idle", clock=clock, noise_lsb=0.0, rest_offset_lsb=150.0, seed=3)
    first = np.concatenate([h.taxels(r.name) for r in hm.REGIONS])
    # uniform in 0..300 over 1,062 taxels: mean 150 +- 3 standard errors (86.6 / sqrt(1062) = 2.7)
    assert first.min() >= 0 and first.max() <= 300
    assert abs(first.mean() - 150.0) < 8.1
    assert len(np.unique(first)) > 250  # each its own
    clock.now_s = 2.0
    later = np.concatenate([h.taxels(r.name) for r in hm.REGIONS])
    assert np.array_equal(first, later)  # unloaded: the offset alone, frame after frame
    # the same seed gives the same skin; the offset is not the noise stream's
    again = HandDevice("idle", clock=Clock(), noise_lsb=0.0, rest_offset_lsb=150.0, seed=3)
    assert np.array_equal(np.concatenate([again.taxels(r.name) for r in hm.REGIONS]), first)
    with pytest.raises(ValueError, match=r"rest_offset_lsb = -1\.0 must be within 0\.\.10000 LSB"):
        HandDevice("idle", clock=Clock(), rest_offset_lsb=-1.0)
