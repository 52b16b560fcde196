"""The hand's status words through a real poll: the gateway polls a Modbus TCP server holding
the ``dexhand-1062`` profile's taxels and four status words (loopback, ephemeral port); the
page's frame (``/api/devices/hand/frame``) and ``/metrics`` carry the words as served, bit by
bit, and the layout carries the 17 regions."""

from __future__ import annotations

import json
import urllib.request

from prometheus_client import CollectorRegistry
from pymodbus.simulator import DataType, SimData, SimDevice
from test_web_hand import WORDS
from web_fixtures import until

from gateway.config import parse_config
from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.web import FrameHub, WebPage
from sim_device.modbus_server import serve_device_tcp

HAND = """
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = {port}
poll_interval_s = 0.05
timeout_s = 1.0

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
"""
#: the status words' registers (bytes 2000, 2002, 2004, 2006 of WORDS: registers 1000..1003):
#: index fault (4, an error code), index stall and communication (0b10001), thumb idle, no error
WORD_REGISTERS = {1000: 4, 1001: 0b10001, 1002: 0, 1003: 0}


def registers() -> list[int]:
    regs = [0] * 2600
    for k in range(1062):  # the taxels from byte 3000 (register 1500) on
        regs[1500 + k] = 1000 + k
    for address, value in WORD_REGISTERS.items():
        regs[address] = value
    return regs


def get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as resp:
        return bytes(resp.read())


async def test_a_poll_of_the_hand_carries_its_status_words_to_the_page_and_metrics() -> None:
    table = [SimData(0, values=registers(), datatype=DataType.REGISTERS)]
    bits = [SimData(0, count=16, values=False, datatype=DataType.BITS)]
    async with serve_device_tcp(SimDevice(id=1, simdata=(bits, bits, table, table))) as port:
        config = parse_config(HAND.format(port=port) + WORDS)
        dev = config.buses[0].devices[0]
        holder = SnapshotHolder()
        hub = FrameHub(holder)
        page = WebPage(hub, device_configs=lambda: [dev])
        server = MetricsServer(
            make_registry(holder.get, CollectorRegistry()), "127.0.0.1", 0, None, page.install
        )
        with server:
            async with Poller(config, holder):
                await until(lambda: (e := hub.latest("hand")) is not None and e.seq > 0 and e.snapshot.up,
                            20, "a good poll of the hand")  # fmt: skip
                frame = json.loads(get(server.base_url + "/api/devices/hand/frame"))
                layout = json.loads(get(server.base_url + "/api/devices/hand"))
                metrics = get(server.base_url + "/metrics").decode()
    assert len(layout["regions"]) == 17 and len(frame["force_n"]) == 1062
    words = {w["name"]: w for w in frame["device_status"]}
    assert (words["index-state"]["value"], words["index-state"]["code"], words["index-state"]["error"]) == (
        4, "fault", True)  # fmt: skip
    on = {b["label"] for b in words["index-errors"]["bits"] if b["on"]}
    assert on == {"stall", "communication"} and words["index-errors"]["error"]
    assert words["thumb-state"]["code"] == "idle" and not words["thumb-errors"]["error"]
    assert 'tactile_device_status_bit{bit="communication",device="hand",word="index-errors"} 1.0' in metrics
    assert 'tactile_device_status_bit{bit="motor",device="hand",word="index-errors"} 0.0' in metrics
    assert 'tactile_device_status_code{code="fault",device="hand",word="index-state"} 4.0' in metrics
    assert 'tactile_device_status_error{device="hand",word="thumb-errors"} 0.0' in metrics


#: the hand simulator's six joints' status codes and error bits (its map: holding registers
#: 1028..1033 and 1034..1039), in the profile's bytes
SIM_WORDS = "".join(
    f"""
[[bus.device.status_word]]
name = "{joint}-status"
address = {2 * (1028 + j)}
codes = {{ 0 = "idle", 1 = "grasping", 2 = "force reached", 3 = "stall", 4 = "fault" }}
error_codes = [3, 4]

[[bus.device.status_word]]
name = "{joint}-errors"
address = {2 * (1034 + j)}
errors = {{ 0 = "stall", 1 = "over-temperature", 2 = "over-current", 3 = "motor", 4 = "communication" }}
"""
    for j, joint in enumerate(("little", "ring", "middle", "index", "thumb-bend", "thumb-rotate"))
)


async def test_the_hand_simulator_s_status_and_error_bits_reach_the_page() -> None:
    """The independent hand simulator (``sim_device.hand``) with an over-temperature on the
    index finger: its status code reads fault (an error bit other than stall) and its error
    word has exactly that bit set; the other fingers read no error."""
    from sim_device.hand import HandDevice
    from sim_device.hand_server import serve_hand_tcp

    hand = HandDevice()
    hand.set_error("index", "over-temperature")
    async with serve_hand_tcp(hand) as sim:
        config = parse_config(HAND.format(port=sim.port) + SIM_WORDS)
        holder = SnapshotHolder()
        hub = FrameHub(holder)
        page = WebPage(hub, device_configs=lambda: [config.buses[0].devices[0]])
        server = MetricsServer(
            make_registry(holder.get, CollectorRegistry()), "127.0.0.1", 0, None, page.install
        )
        with server:
            async with Poller(config, holder):
                await until(lambda: (e := hub.latest("hand")) is not None and e.seq > 0 and e.snapshot.up,
                            20, "a good poll of the hand simulator")  # fmt: skip
                frame = json.loads(get(server.base_url + "/api/devices/hand/frame"))
                metrics = get(server.base_url + "/metrics").decode()
    words = {w["name"]: w for w in frame["device_status"]}
    assert len(words) == 12
    assert (words["index-status"]["code"], words["index-status"]["error"]) == ("fault", True)
    assert {b["label"] for b in words["index-errors"]["bits"] if b["on"]} == {"over-temperature"}
    for joint in ("little", "ring", "middle", "thumb-bend", "thumb-rotate"):
        assert not words[f"{joint}-errors"]["error"] and not words[f"{joint}-status"]["error"], joint
    assert (
        'tactile_device_status_bit{bit="over-temperature",device="hand",word="index-errors"} 1.0' in metrics
    )
    assert 'tactile_device_status_error{device="hand",word="ring-errors"} 0.0' in metrics
