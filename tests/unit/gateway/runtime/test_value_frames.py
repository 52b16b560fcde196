"""Devices described by a ``[bus.device.frame]``, polled on the in-process virtual bus: the
values land in the right channels in every encoding, a device's own force or pressure is
passed through (with drift correction on request), a vendor function code and a row select
are read by configuration alone, and set-up writes are made, read back and never more.

Expected values are computed by hand from the registers written into the virtual device."""

from __future__ import annotations

import math
import random
import struct

import numpy as np
import pytest

from gateway.config import GatewayConfig, parse_config
from gateway.errors import ConfigError
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.poller import Poller
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot
from gateway.runtime.summary import device_summary

BUS = """
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = 502
timeout_s = 0.2
retries = 0
backoff_initial_s = 0.1

[[bus.device]]
name = "arr"
device_id = 1
channels = 4
columns = 2
pitch_mm = 2.5
"""
#: the spec's t = 0 resistances on the static curve (no creep): a gateway that starts on a loaded,
#: creeping sensor reads it from its equilibrium instead (tests/unit/gateway/model/test_start_state.py)
STATIC = """
[bus.device.model]
effects = ["tunneling", "contact"]
"""


def config(extra: str) -> GatewayConfig:
    return parse_config(BUS + extra)


class Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def poller_for(cfg: GatewayConfig, dev: VirtualDevice) -> tuple[Poller, VirtualTransport, Clock]:
    vt = VirtualTransport("line", {1: dev}, timeout_s=0.2)
    clock = Clock()
    poller = Poller(
        cfg,
        transport_factory=lambda _bus: vt,
        rng=random.Random(3),
        wall_clock=lambda: 1_700_000_000.0,
        monotonic=clock,
    )
    return poller, vt, clock


async def poll(poller: Poller) -> DeviceSnapshot:
    await poller.workers[0].poll_cycle()
    return poller.snapshot().devices["arr"]


def f32_cdab(value: float) -> list[int]:
    hi, lo = struct.unpack(">HH", struct.pack(">f", value))
    return [lo, hi]


# ------------------------------------------------------------------ device-calibrated output
async def test_a_force_frame_in_mn_from_a_vendor_function_code_reads_newtons() -> None:
    cfg = config("""
[bus.device.frame]
quantity = "force"
unit = "mN"
table = "vendor"
function_code = 0x42
""")
    dev = VirtualDevice()
    dev.set_vendor_image(0x42, [1500, 0, 250, 40000])
    poller, vt, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    assert snap.up, snap.error
    assert snap.force_n.tolist() == [1.5, 0.0, 0.25, 40.0]
    assert snap.status.tolist() == [
        ChannelStatus.OK,
        ChannelStatus.NO_CONTACT,
        ChannelStatus.OK,
        ChannelStatus.OK,
    ]
    assert math.isclose(snap.total_force_n, 41.75)
    assert np.isnan(snap.resistance_ohm).all()  # the device reports no resistance
    assert vt.requests == [("vendor 0x42", 1, 0, 4)]  # one request, the start and count of the frame
    assert vt.writes == []
    assert snap.force_static_n.tolist() == [1.5, 0.0, 0.25, 40.0]


async def test_a_pressure_frame_in_int16_with_scale_acts_on_the_cell_area() -> None:
    cfg = config("""
[bus.device.frame]
quantity = "pressure"
unit = "kPa"
type = "int16"
scale = 0.5
table = "holding"
address = 20
""")
    dev = VirtualDevice()
    # int16: 400 -> 200 kPa; -2 (0xFFFE) -> -1 kPa (no contact); 0; 20 -> 10 kPa
    dev.set_holding(20, [400, 0xFFFE, 0, 20])
    poller, _, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    area_mm2 = 2.5 * 2.5
    # F = p (kPa) x A (mm^2) x 1e-3 (kPa mm^2 = 1e3 Pa x 1e-6 m^2 = 1e-3 N)
    assert snap.force_n[0] == pytest.approx(200.0 * area_mm2 * 1e-3, rel=1e-12)  # 1.25 N
    assert snap.force_n[3] == pytest.approx(10.0 * area_mm2 * 1e-3, rel=1e-12)
    assert snap.status[1] == ChannelStatus.NO_CONTACT and snap.force_n[1] == 0.0


async def test_a_nan_output_is_flagged_an_error_never_a_force() -> None:
    cfg = config("""
[bus.device.frame]
quantity = "force"
type = "float32"
order = "CDAB"
address = 0
""")
    dev = VirtualDevice()
    dev.set_input(0, f32_cdab(1.0) + f32_cdab(float("nan")) + f32_cdab(float("inf")) + f32_cdab(0.5))
    poller, _, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    assert snap.force_n[0] == 1.0 and snap.force_n[3] == 0.5
    assert snap.status[1] == ChannelStatus.ERROR and snap.status[2] == ChannelStatus.ERROR
    assert np.isnan(snap.force_n[1]) and np.isnan(snap.force_n[2])
    assert snap.total_force_n == 1.5


async def test_drift_correction_on_a_device_output_holds_a_creeping_reading_flat() -> None:
    """The device's static table reads x = F (1 + a (1 - e^(-t / tau))) under a held F: with
    the same creep in [bus.device.frame].drift the force stays F (the Kelvin element's
    discrete update: z_k = e z_(k-1) + (1 - e) a F)."""
    cfg = config("""
[bus.device.frame]
quantity = "force"
type = "float32"
address = 0
drift = { creep_fraction = 0.2, creep_tau_s = 10.0 }
""")
    dev = VirtualDevice()
    poller, _, clock = poller_for(cfg, dev)
    held_n, a, tau, dt = 2.0, 0.2, 10.0, 1.0
    z = 0.0
    forces = []
    # the device starts unloaded (the gateway reads its first sample at rest), then holds F
    for k in range(-1, 30):
        if k > 0:
            e = math.exp(-dt / tau)
            z = e * z + (1.0 - e) * a * held_n
        reading = held_n + z if k >= 0 else 0.0  # what the device's own table reports, creeping up
        words: list[int] = []
        for _ in range(4):
            words += list(struct.unpack(">HH", struct.pack(">f", reading)))
        dev.set_input(0, words)
        snap = await poll(poller)
        if k >= 0:
            forces.append(float(snap.force_n[0]))
        clock.now_s += dt
    assert z > 0.3  # the reading crept up by more than 15 % ...
    assert max(abs(f - held_n) for f in forces) < 1e-6  # ... and the force stayed flat
    # the same device without the drift table reads the creep
    plain = config("""
[bus.device.frame]
quantity = "force"
type = "float32"
address = 0
""")
    poller2, _, _ = poller_for(plain, dev)
    assert (await poll(poller2)).force_n[0] == pytest.approx(held_n + z, rel=1e-6)


# ------------------------------------------------------------------ encodings and blocks
async def test_resistance_in_float32_cdab_over_two_blocks_lands_in_channel_order() -> None:
    cfg = config(
        STATIC
        + """
[bus.device.frame]
quantity = "resistance"
unit = "kohm"
type = "float32"
order = "CDAB"
blocks = [{ address = 300, values = 1 }, { address = 10, values = 3 }]
"""
    )
    dev = VirtualDevice()
    dev.set_input(300, f32_cdab(93.8))
    dev.set_input(10, f32_cdab(46.9) + f32_cdab(9.98) + f32_cdab(138.5))
    poller, _, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    assert snap.resistance_ohm.tolist() == pytest.approx([93.8e3, 46.9e3, 9.98e3, 138.5e3], rel=1e-6)
    # docs/parameters.md: these resistances are 1, 2, 5 and 0.5 N at t = 0
    assert snap.force_n.tolist() == pytest.approx([1.0, 2.0, 5.0, 0.5], rel=0.01)


async def test_counts_frame_at_an_odd_address_reads_as_the_adc_map_does() -> None:
    """A DFRobot-style frame (input 7.., uint16 counts) gives the forces the spec's counts mean."""
    counts = [6314, 11518, 32800, 4413]  # tests/unit/gateway/runtime/test_bus.py: 1, 2, 5, 0.5 N
    cfg = config(
        STATIC
        + """
[bus.device.front_end]
kind = "high_side"
reference_ohm = 10000.0
supply_v = 3.3
adc_reference_v = 3.3
adc_bits = 16

[bus.device.frame]
quantity = "counts"
address = 7
"""
    )
    dev = VirtualDevice()
    dev.set_input(7, counts)
    poller, vt, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    assert snap.force_n.tolist() == pytest.approx([1.0, 2.0, 5.0, 0.5], rel=0.01)
    assert vt.requests == [("input", 1, 7, 4)]  # only the frame: no status, no clock, no writes


async def test_uint32_counts_with_offset_go_through_the_front_end() -> None:
    cfg = config(
        STATIC
        + """
[bus.device.front_end]
kind = "high_side"
reference_ohm = 10000.0
supply_v = 3.3
adc_reference_v = 3.3
adc_bits = 16

[bus.device.frame]
quantity = "counts"
type = "uint32"
order = "DCBA"
offset = -100.0
address = 0
"""
    )
    dev = VirtualDevice()
    words = []
    for c in (6314, 11518, 32800, 4413):
        raw = c + 100
        hi, lo = raw >> 16, raw & 0xFFFF
        swap = lambda w: ((w & 0xFF) << 8) | (w >> 8)  # noqa: E731
        words += [swap(lo), swap(hi)]  # DCBA: little-endian bytes and words
    dev.set_input(0, words)
    poller, _, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    assert snap.force_n.tolist() == pytest.approx([1.0, 2.0, 5.0, 0.5], rel=0.01)


async def test_a_row_select_board_is_read_row_by_row() -> None:
    """Two rows of two: the board answers the selected row's columns at holding 50..51."""
    cfg = config("""
[bus.device.frame]
quantity = "force"
unit = "mN"
table = "holding"
row_select_address = 40
blocks = [{ address = 50, values = 2, row = 0 }, { address = 50, values = 2, row = 1 }]
""")
    rows = {0: [100, 200], 1: [300, 400]}
    dev = VirtualDevice()

    class RowBoard(dict[int, int]):
        def __getitem__(self, address: int) -> int:
            if address in (50, 51):
                return rows[dev.holding_select][address - 50]
            return super().__getitem__(address)

        def __contains__(self, address: object) -> bool:
            return address in (40, 50, 51)

        def get(self, address: int, default: object = None) -> int:  # type: ignore[override]
            if address not in self:
                return default  # type: ignore[return-value]
            return self[address]

        def __setitem__(self, address: int, value: int) -> None:
            if address == 40:
                dev.holding_select = value
            super().__setitem__(address, value)

    dev.holding_select = 0  # type: ignore[attr-defined]
    dev.holding = RowBoard()
    poller, vt, _ = poller_for(cfg, dev)
    snap = await poll(poller)
    assert snap.force_n.tolist() == [0.1, 0.2, 0.3, 0.4]
    assert vt.writes == [(1, 40, (0,)), (1, 40, (1,))]


# ------------------------------------------------------------------ writes
SETUP = """
[[bus.device.setup]]
what = "raw counts output"
address = 16
value = 0

[[bus.device.setup]]
what = "AD mask off"
address = 17
value = 0
verify = false

[bus.device.actions]
zero = [{ what = "dynamic zero", address = 18, value = 1, verify = false }]

[bus.device.frame]
quantity = "force"
unit = "mN"
address = 0
"""


async def test_set_up_writes_are_made_once_per_connect_and_read_back() -> None:
    dev = VirtualDevice()
    dev.set_input(0, [1, 2, 3, 4])
    dev.set_holding(16, [1, 5, 0])
    poller, vt, _ = poller_for(config(SETUP), dev)
    snap = await poll(poller)
    assert snap.up, snap.error
    assert vt.writes == [(1, 16, (0,)), (1, 17, (0,))]
    assert ("holding", 1, 16, 1) in vt.requests  # read back
    assert ("holding", 1, 17, 1) not in vt.requests  # verify = false
    await poll(poller)
    assert vt.writes == [(1, 16, (0,)), (1, 17, (0,))]  # not again on the same connection
    assert dev.holding[18] == 0  # the action is never run by polling


async def test_a_set_up_the_device_does_not_take_stops_the_polls_with_the_reason() -> None:
    dev = VirtualDevice()
    dev.set_input(0, [1, 2, 3, 4])
    dev.set_holding(16, [1, 5, 0])
    vt_devices = {1: dev}
    cfg = config(SETUP)
    poller, vt, _ = poller_for(cfg, dev)
    original = vt._write_single  # the register ignores the write (a read-only mode register)

    async def ignore(device_id: int, address: int, value: int, what: str) -> None:
        if address != 16:
            await original(device_id, address, value, what)

    vt._write_single = ignore  # type: ignore[method-assign]
    snap = await poll(poller)
    assert not snap.up
    assert "raw counts output" in (snap.error or "") and "read back 1" in (snap.error or "")
    assert not any(r[0] == "input" for r in vt.requests)  # never polled in the wrong mode
    assert vt_devices[1] is dev


async def test_without_writes_configured_nothing_is_written() -> None:
    cfg = config("""
[bus.device.frame]
quantity = "force"
address = 0
""")
    dev = VirtualDevice()
    dev.set_input(0, [1, 2, 3, 4])
    poller, vt, _ = poller_for(cfg, dev)
    for _ in range(3):
        await poll(poller)
    assert vt.writes == []
    assert {r[0] for r in vt.requests} == {"input"}


# ------------------------------------------------------------------ what is on
def test_check_lines_say_what_is_read_tracked_and_written() -> None:
    lines = device_summary(config(SETUP).buses[0].devices[0])
    text = "\n".join(lines)
    assert "values: force in mN, uint16 ABCD, input registers: 0+4" in text
    assert "passed through" in text and "no drift correction" in text
    assert "set-up at connect: raw counts output: holding 16 <- 0 (function 6, read back)" in text
    assert "action zero: dynamic zero: holding 18 <- 1 (function 6, not read back)" in text
    physics = config("""
[bus.device.front_end]
kind = "high_side"
reference_ohm = 10000.0
supply_v = 3.3
adc_reference_v = 3.3
adc_bits = 16

[bus.device.frame]
address = 7

[bus.device.model]
effects = ["tunneling", "contact", "creep", "hysteresis"]
""")
    text = "\n".join(device_summary(physics.buses[0].devices[0]))
    assert "drift correction on: creep, hysteresis, timed by the host's monotonic clock" in text
    assert "4 from the defaults" in text
    assert "no channel is calibrated" in text
    assert "writes: none" in text


# ------------------------------------------------------------------ refusals
@pytest.mark.parametrize(
    ("frame", "message"),
    [
        ('quantity = "torque"', "quantity: 'torque' is not allowed"),
        ('quantity = "force"\nunit = "kPa"', "unit: 'kPa' is not allowed"),
        ('type = "float32"\norder = "AB"\naddress = 0', "order"),
        ("address = 0\nvalues = 3", "carry 3 values for channels = 4"),
        (
            "blocks = [{ address = 0, values = 2, row = 1 }, { address = 0, values = 2, row = 2 }]",
            "row_select_address",
        ),
        ("address = 0\ndrift = { creep_fraction = 0.1 }", "drift"),
        ("address = 0\nfunction_code = 0x42", "only a vendor read has a function_code"),
        ('quantity = "force"\ntable = "vendor"\nfunction_code = 3', "function_code"),
        ("address = 0\nscale = 0", "scale"),
    ],
)
def test_a_bad_frame_is_refused_with_the_key_and_the_allowed_values(frame: str, message: str) -> None:
    with pytest.raises(ConfigError, match="frame") as err:
        config("\n[bus.device.frame]\n" + frame + "\n")
    assert message in str(err.value), str(err.value)


FRAME_AT_0 = "[bus.device.frame]\naddress = 0\n"


def test_a_write_names_one_value_or_several_with_function_16() -> None:
    with pytest.raises(ConfigError, match=r"setup\[0\].*function 6 writes one register"):
        config("[[bus.device.setup]]\naddress = 1\nvalues = [1, 2]\nfunction = 6\n" + FRAME_AT_0)
    with pytest.raises(ConfigError, match=r"actions.zero\[0\].value.*0..65535"):
        config("[bus.device.actions]\nzero = [{ address = 1, value = 70000 }]\n" + FRAME_AT_0)


# ------------------------------------------------------------------ no zero
NO_ZERO_BOARD = """
[bus.device.front_end]
kind = "high_side"
reference_ohm = 10000.0
supply_v = 3.3
adc_bits = 12

[bus.device.frame]
quantity = "counts"
address = 7
"""


async def test_an_idle_cell_without_a_zero_reads_no_zero_and_is_not_counted() -> None:
    """A DFRobot-style board without a zero: idle cells read 200 counts of 4095, which the
    assumed divider takes for 10 kohm x (4095 / 200 - 1) = 194.75 kohm and the default model
    for about 0.12 N (the phantom force a user reported). Within 6 % of full scale of the open
    code (0..245.7) a force without a zero is NO_ZERO: its value is kept but it is not
    counted in the array's total or contact; 246 counts and a load of 2000 read OK. With
    baselines the idle cells read 0 N, no contact."""
    dev = VirtualDevice()
    dev.set_input(7, [200, 245, 246, 2000])
    poller, _, _ = poller_for(config(NO_ZERO_BOARD), dev)
    snap = await poll(poller)
    nz, ok = ChannelStatus.NO_ZERO, ChannelStatus.OK
    assert snap.status.tolist() == [nz, nz, ok, ok], snap.status
    assert 0.05 < snap.force_n[0] < 0.2  # the value is kept: the phantom force
    assert snap.channels_in_contact == 2
    assert snap.total_force_n == pytest.approx(float(snap.force_n[2] + snap.force_n[3]), rel=1e-12)
    tared = BUS.replace("pitch_mm = 2.5\n", "pitch_mm = 2.5\nbaseline_counts = [200, 200, 200, 200]\n")
    zeroed = parse_config(tared + NO_ZERO_BOARD)  # the same board, every channel tared at 200 counts
    poller2, _, _ = poller_for(zeroed, dev)
    dev.set_input(7, [200, 200, 200, 2000])
    snap2 = await poll(poller2)
    none = ChannelStatus.NO_CONTACT
    assert snap2.status.tolist() == [none, none, none, ok]
    assert snap2.force_n.tolist()[:3] == [0.0, 0.0, 0.0]
