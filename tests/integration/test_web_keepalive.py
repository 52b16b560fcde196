"""An event stream with nothing to send gets a keepalive comment after ``keepalive_s`` of
silence, and one that gets frames gets none (real gateway, simulator and aiohttp client)."""

from __future__ import annotations

import asyncio

import aiohttp
from web_fixtures import first_poll, gateway_with_page


async def _lines_for(url: str, seconds: float) -> list[tuple[float, bytes]]:
    """The lines of the event stream at ``url`` for ``seconds`` after its headers, each with
    the time it arrived since the request was sent (the server's silence starts later)."""
    loop = asyncio.get_running_loop()
    out: list[tuple[float, bytes]] = []
    async with aiohttp.ClientSession() as http:
        t0 = loop.time()
        resp = await http.get(url)
        assert resp.status == 200

        async def read() -> None:
            async for line in resp.content:
                out.append((loop.time() - t0, line))

        try:
            await asyncio.wait_for(read(), seconds)
        except TimeoutError:
            pass
        finally:
            resp.close()
    return out


async def test_an_idle_page_stream_gets_a_keepalive_and_a_busy_one_does_not() -> None:
    keepalive_s = 0.3
    async with gateway_with_page(keepalive_s=keepalive_s) as gw:
        await first_poll(gw)
        base = gw.server.base_url
        idle, busy = await asyncio.gather(
            _lines_for(base + "/api/live?device=none", 6 * keepalive_s),
            _lines_for(base + "/api/devices/arr/stream", 6 * keepalive_s),
        )
    kept = [t for t, line in idle if line == b": keepalive\n"]
    assert kept, idle
    assert kept[0] >= keepalive_s  # not before the silence has lasted that long
    assert not any(line.startswith(b"data: ") for _, line in idle)  # no device "none"
    assert [line for _, line in busy if line == b": keepalive\n"] == []
    assert sum(line.startswith(b"data: ") for _, line in busy) >= 3  # 20 polls a second
