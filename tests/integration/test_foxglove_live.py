"""``tactile-gateway run`` with ``[foxglove]`` against ``tactile-sim run``: a Foxglove
protocol client (tests/unit/gateway/foxglove/foxglove_wsclient.py) subscribes and receives the
array's forces as a 4 x 4 ``foxglove.Grid``, the layout and the summary, with the frames'
times advancing; then SIGTERM stops the gateway cleanly."""

from __future__ import annotations

import asyncio
import importlib.util
import json
import signal
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import aiohttp
import numpy as np
import pytest
from netutil import free_port
from waiting import until

pytestmark = [pytest.mark.slow]

BIN = Path(sys.executable).parent
CLIENT = Path(__file__).resolve().parents[1] / "unit" / "gateway" / "foxglove" / "foxglove_wsclient.py"


def _client_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("foxglove_wsclient_live", CLIENT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


async def _connect(
    session: aiohttp.ClientSession, ws_client: ModuleType, port: int, gateway: subprocess.Popen[bytes]
) -> aiohttp.ClientWebSocketResponse:
    """The gateway's Foxglove server, once it listens (the gateway may still be starting)."""

    async def connect() -> aiohttp.ClientWebSocketResponse:
        assert gateway.poll() is None, "the gateway exited"
        ws: aiohttp.ClientWebSocketResponse = await ws_client.connect(session, port)
        return ws

    ws: aiohttp.ClientWebSocketResponse = await until(
        connect, 30.0, "the gateway's Foxglove server", ignore=(aiohttp.ClientConnectionError,)
    )
    return ws


async def _receive(
    port: int, gateway: subprocess.Popen[bytes]
) -> tuple[dict[str, tuple[int, bytes]], dict[str, tuple[int, bytes]]]:
    """Once the array answers (the gateway may poll before the simulator listens: those
    frames are stale, NaN): the layout, a summary saying up and a grid with forces; then a
    later grid."""
    ws_client = _client_module()
    topics = ["/tactile/arr/arr", "/tactile/arr/summary", "/tactile/arr/layout"]
    first: dict[str, tuple[int, bytes]] = {}
    async with aiohttp.ClientSession() as session:
        ws = await _connect(session, ws_client, port, gateway)
        async with ws:
            client = ws_client.FoxgloveClient(ws)
            await client.advertised(set(topics), timeout_s=30.0)
            await client.subscribe(topics)
            async with asyncio.timeout(60.0):
                while set(first) != set(topics):
                    topic, log_ns, payload = await client.message(timeout_s=30.0)
                    if topic == "/tactile/arr/summary" and not json.loads(payload)["up"]:
                        continue
                    if topic == "/tactile/arr/arr" and (
                        "/tactile/arr/summary" not in first
                        or not np.isfinite(ws_client.decode_grid(payload).values).any()
                    ):
                        continue
                    first.setdefault(topic, (log_ns, payload))
            later = await client.collect({"/tactile/arr/arr"}, timeout_s=30.0)
    return first, later


def test_the_running_gateway_serves_the_simulated_array_to_a_foxglove_client(tmp_path: Path) -> None:
    sim_port, fox_port = free_port(), free_port()
    config = tmp_path / "gateway.toml"
    config.write_text(
        f'[metrics]\naddress = "127.0.0.1:{free_port()}"\n\n'
        f'[foxglove]\nhost = "127.0.0.1"\nport = {fox_port}\n\n'
        f'[[bus]]\nname = "sim"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {sim_port}\n'
        "poll_interval_s = 0.05\n\n"
        '[[bus.device]]\nname = "arr"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 16\ncolumns = 4\n'
    )
    sim = subprocess.Popen(
        [str(BIN / "tactile-sim"), "run", "--tcp", f"127.0.0.1:{sim_port}", "--channels", "16",
         "--columns", "4", "--scenario", "indentation", "--speed", "5"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    gateway = subprocess.Popen(
        [str(BIN / "tactile-gateway"), "run", "-c", str(config)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        first, later = asyncio.run(_receive(fox_port, gateway))
    finally:
        gateway.send_signal(signal.SIGTERM)
        try:
            _, err = gateway.communicate(timeout=20)
            print(err.decode(errors="replace"))  # shown by pytest when the test fails
        finally:
            sim.terminate()
            sim.wait(timeout=10)
    assert gateway.returncode == 0, err.decode(errors="replace")
    grid = _client_module().decode_grid(first["/tactile/arr/arr"][1])
    assert grid.values.shape == (4, 4) and grid.frame_id == "arr"
    assert grid.field_names == ["force_n"]
    finite = grid.values[np.isfinite(grid.values)]
    assert finite.size > 0 and (finite >= 0.0).all()
    assert grid.cell_size_m == pytest.approx((0.0025, 0.0025))
    assert later["/tactile/arr/arr"][0] > first["/tactile/arr/arr"][0], "a later poll, a later time"
    layout = json.loads(first["/tactile/arr/layout"][1])
    assert [(r["name"], r["rows"], r["columns"]) for r in layout["regions"]] == [("arr", 4, 4)]
    summary = json.loads(first["/tactile/arr/summary"][1])
    assert summary["device"] == "arr" and summary["up"] is True
    assert sum(summary["status_counts"].values()) == 16
    assert f"serving Foxglove on ws://127.0.0.1:{fox_port}" in err.decode(errors="replace")
