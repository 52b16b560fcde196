"""The processes and the configuration of ``bench_hand_rate``: the simulated hand, a light
device serving the same registers, the clients of every output, and the gateway's file."""

from __future__ import annotations

SIM_SCRIPT = """
import asyncio, logging, sys
from sim_device.hand import HandDevice
from sim_device.hand_server import serve_hand_tcp

async def main():
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # a client leaving is no news here
    async with serve_hand_tcp(HandDevice("grasp", seed=1), host="127.0.0.1", port=0) as sim:
        print(sim.port, flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)

asyncio.run(main())
"""

#: The hand's 1,062 registers (profile addresses, registers 1500..2561) in a plain pymodbus block,
#: a new frame every 1/30 s (a random walk: no physics), answered by the same pymodbus server
#: code as the simulator's: a device that costs little CPU, to see the gateway's own limits.
LIGHT_SCRIPT = """
import asyncio, logging, sys, time
import numpy as np
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

FIRST, N, HZ = 1500, 1062, 30.0
rng = np.random.default_rng(1)
frame = {"index": -1, "values": rng.integers(100, 30000, N), "list": []}
t0 = time.monotonic()

async def action(function_code, start_address, address, count, registers, set_values):
    index = int((time.monotonic() - t0) * HZ)
    if index != frame["index"]:
        frame["index"] = index
        frame["values"] = np.clip(frame["values"] + rng.integers(-50, 51, N), 100, 30000)
        frame["list"] = frame["values"].tolist()
    registers[address - start_address : address - start_address + count] = (
        frame["list"][address - FIRST : address - FIRST + count])
    return None

async def main():
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    bits = [SimData(0, count=16, values=False, datatype=DataType.BITS)]
    holding = [SimData(FIRST, count=N, values=0, datatype=DataType.REGISTERS, readonly=True)]
    inputs = [SimData(0, values=0, datatype=DataType.UINT16)]
    device = SimDevice(id=1, simdata=(bits, bits, holding, inputs), action=action)
    server = ModbusTcpServer([device], address=("127.0.0.1", 0))
    await server.serve_forever(background=True)
    print(server.transport.sockets[0].getsockname()[1], flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    await server.shutdown()

asyncio.run(main())
"""

CLIENTS_SCRIPT = r"""
import asyncio, json, sys
import aiohttp

counts = {"foxglove": 0, "page": 0, "stream": 0, "scrapes": 0}
sockets = []  # closed first at the end: the server sees a goodbye, not a reset

async def foxglove(session, port, ready):
    async with session.ws_connect(f"ws://127.0.0.1:{port}", protocols=["foxglove.sdk.v1"],
                                  max_msg_size=0) as ws:
        sockets.append(ws)
        channels = {}
        while len(channels) < int(sys.argv[3]):
            body = json.loads((await ws.receive()).data)
            if body["op"] == "advertise":
                channels.update({c["topic"]: c for c in body["channels"]})
        subs = [{"id": k + 1, "channelId": c["id"]} for k, c in enumerate(channels.values())]
        await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))
        ready.set_result(None)
        async for msg in ws:
            if msg.type is aiohttp.WSMsgType.BINARY and msg.data[0] == 1:
                counts["foxglove"] += 1

async def follow(session, url, key, ready):
    async with session.get(url) as resp:
        ready.set_result(None)
        tail = b""
        async for chunk in resp.content.iter_any():  # a 1,062-channel frame is a long line
            joined = tail + chunk
            counts[key] += joined.count(b"data: ")
            tail = joined[-5:]

async def scrape(session, base):
    while True:
        async with session.get(base + "/metrics") as resp:
            await resp.read()
            counts["scrapes"] += 1
        await asyncio.sleep(1.0)

async def main():
    base, fox_port = sys.argv[1], int(sys.argv[2])
    loop = asyncio.get_running_loop()
    ready = [loop.create_future() for _ in range(3)]
    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=None)) as session:
        tasks = [asyncio.create_task(foxglove(session, fox_port, ready[0])),
                 asyncio.create_task(follow(session, base + "/api/live", "page", ready[1])),
                 asyncio.create_task(follow(session, base + "/api/devices/hand/stream", "stream", ready[2])),
                 asyncio.create_task(scrape(session, base))]
        await asyncio.wait_for(asyncio.gather(*ready), 60)
        print("ready", flush=True)
        await loop.run_in_executor(None, sys.stdin.read)
        for ws in sockets:
            await ws.close()
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    print(json.dumps(counts), flush=True)

asyncio.run(main())
"""


def config_text(sim_port: int, broker_port: int, metrics_port: int, fox_port: int, interval_s: float) -> str:
    return f"""
[metrics]
address = "127.0.0.1:{metrics_port}"

[mqtt]
host = "127.0.0.1"
port = {broker_port}
gateway = "bench"

[foxglove]
host = "127.0.0.1"
port = {fox_port}

[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = {sim_port}
poll_interval_s = {interval_s!r}

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"

[bus.device.front_end]
kind = "transimpedance"
bias_v = 1.0
feedback_ohm = 1000.0
adc_bits = 16
adc_reference_v = 1.0
"""
