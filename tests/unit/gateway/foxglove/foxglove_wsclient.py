"""A small client of Foxglove's WebSocket protocol for the tests (aiohttp), with its own
protobuf wire decoder for ``foxglove.Grid`` (no protobuf package needed): an independent
reader of what the gateway serves.

Protocol (foxglove-sdk 0.30 speaks the subprotocol ``foxglove.sdk.v1``): the server sends
``serverInfo`` and ``advertise`` (JSON text); a client sends ``subscribe`` with its own
subscription ids; data comes as binary ``messageData``: opcode 1, subscription id (uint32
LE), log time (uint64 LE, ns), then the message.
"""

from __future__ import annotations

import asyncio
import json
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import aiohttp
import numpy as np
from numpy.typing import NDArray

SUBPROTOCOL = "foxglove.sdk.v1"


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if b < 0x80:
            return value, i


def fields(buf: bytes) -> dict[int, list[Any]]:
    """Protobuf wire fields: number -> values (int for varint, bytes for length-delimited and
    fixed width, as raw bytes)."""
    out: dict[int, list[Any]] = {}
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        value: int | bytes
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = buf[i : i + 8], i + 8
        elif wire == 2:
            n, i = _varint(buf, i)
            value, i = buf[i : i + n], i + n
        elif wire == 5:
            value, i = buf[i : i + 4], i + 4
        else:
            raise ValueError(f"wire type {wire}")
        out.setdefault(number, []).append(value)
    return out


def _double(f: dict[int, list[Any]], n: int) -> float:
    return float(struct.unpack("<d", f[n][0])[0]) if n in f else 0.0


def _fixed32(f: dict[int, list[Any]], n: int) -> int:
    return int(struct.unpack("<I", f[n][0])[0]) if n in f else 0


@dataclass(frozen=True)
class DecodedGrid:
    sec: int
    nsec: int
    frame_id: str
    position_m: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    column_count: int
    cell_size_m: tuple[float, float]
    row_stride: int
    cell_stride: int
    field_names: list[str]
    field_types: list[int]
    values: NDArray[np.float32]  # rows x columns


def decode_grid(buf: bytes) -> DecodedGrid:
    """``foxglove.Grid`` (Grid.proto: 1 timestamp, 2 frame_id, 3 pose, 4 column_count,
    5 cell_size, 6 row_stride, 7 cell_stride, 8 fields, 9 data)."""
    f = fields(buf)
    ts = fields(f[1][0]) if 1 in f else {}
    pose = fields(f[3][0]) if 3 in f else {}
    pos = fields(pose[1][0]) if 1 in pose else {}
    rot = fields(pose[2][0]) if 2 in pose else {}
    cell = fields(f[5][0]) if 5 in f else {}
    packed = [fields(b) for b in f.get(8, [])]
    columns = _fixed32(f, 4)
    data = f[9][0] if 9 in f else b""
    values = np.frombuffer(data, dtype="<f4").reshape(-1, columns).astype(np.float32)
    return DecodedGrid(
        sec=ts.get(1, [0])[0],
        nsec=ts.get(2, [0])[0],
        frame_id=f[2][0].decode() if 2 in f else "",
        position_m=(_double(pos, 1), _double(pos, 2), _double(pos, 3)),
        orientation=(_double(rot, 1), _double(rot, 2), _double(rot, 3), _double(rot, 4)),
        column_count=columns,
        cell_size_m=(_double(cell, 1), _double(cell, 2)),
        row_stride=_fixed32(f, 6),
        cell_stride=_fixed32(f, 7),
        field_names=[p[1][0].decode() for p in packed],
        field_types=[p.get(3, [0])[0] for p in packed],
        values=values,
    )


class FoxgloveClient:
    """One connection: ``channels`` (topic -> advertised channel) once ``advertised`` ran."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.server_info: dict[str, Any] | None = None
        self.channels: dict[str, dict[str, Any]] = {}
        self._topics: dict[int, str] = {}  # subscription id -> topic

    async def advertised(self, topics: set[str], timeout_s: float = 10.0) -> None:
        """Read until ``topics`` are all advertised."""
        async with asyncio.timeout(timeout_s):
            while not topics <= set(self.channels):
                msg = await self.ws.receive()
                if msg.type is not aiohttp.WSMsgType.TEXT:
                    raise AssertionError(f"expected a JSON message, got {msg.type}: {msg.data!r}")
                body = json.loads(msg.data)
                if body["op"] == "serverInfo":
                    self.server_info = body
                elif body["op"] == "advertise":
                    self.channels.update({c["topic"]: c for c in body["channels"]})

    async def subscribe(self, topics: list[str]) -> None:
        subs = []
        for topic in topics:
            sid = len(self._topics) + 1
            self._topics[sid] = topic
            subs.append({"id": sid, "channelId": self.channels[topic]["id"]})
        await self.ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def message(self, timeout_s: float) -> tuple[str, int, bytes]:
        """The next messageData: (topic, log time ns, payload); other messages are skipped."""
        async with asyncio.timeout(timeout_s):
            while True:
                msg = await self.ws.receive()
                if msg.type is aiohttp.WSMsgType.BINARY and msg.data[0] == 1:
                    sid, log_ns = struct.unpack_from("<IQ", msg.data, 1)
                    return self._topics[sid], log_ns, bytes(msg.data[13:])
                if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                    raise AssertionError(f"the server closed the connection: {msg!r}")

    async def collect(
        self, wanted: set[str], timeout_s: float, poke: Callable[[], None] | None = None
    ) -> dict[str, tuple[int, bytes]]:
        """The first message of each topic in ``wanted``; ``poke`` (if given) is called
        whenever 0.2 s pass without one (a new frame to publish), until ``timeout_s``."""
        got: dict[str, tuple[int, bytes]] = {}
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while not wanted <= set(got):
            left = deadline - loop.time()
            if left <= 0:
                raise AssertionError(f"no message on {sorted(wanted - set(got))} within {timeout_s} s")
            try:
                topic, log_ns, payload = await self.message(min(0.2, left) if poke else left)
            except TimeoutError:
                if poke is not None:
                    poke()
                continue
            got.setdefault(topic, (log_ns, payload))
        return got


def connect(session: aiohttp.ClientSession, port: int) -> Any:
    return session.ws_connect(f"ws://127.0.0.1:{port}", protocols=[SUBPROTOCOL], max_msg_size=0)
