"""SIGHUP with a configuration whose calibration file is a named pipe (issue 33 §6).

The reload opened the FIFO before checking what it is, and the open waited for a writer on
the poll loop: polling stopped while /metrics still answered ``tactile_device_up 1``, and
SIGTERM was ignored. The reload must be refused with a message naming the file, and polling
must go on.
"""

from __future__ import annotations

import asyncio
import os
import signal
from pathlib import Path

import pytest
from netutil import free_port
from test_metrics_http import GATEWAY, _array, _write_config, scrape, scrape_until, wait_until

from sim_device import serve_tcp

pytestmark = pytest.mark.slow  # a gateway process


async def test_a_reload_naming_a_fifo_as_calibration_is_refused_and_polling_goes_on(tmp_path: Path) -> None:
    fifo = tmp_path / "cal.toml"
    os.mkfifo(fifo)
    array = _array(speed=1.0)
    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        port = free_port()
        cfg = tmp_path / "gateway.toml"
        _write_config(cfg, port, sim.port, 0.05)
        proc = await asyncio.create_subprocess_exec(
            *GATEWAY, "run", "-c", str(cfg), stderr=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.DEVNULL
        )
        log: list[str] = []

        async def read_log() -> None:
            assert proc.stderr is not None
            while line := await proc.stderr.readline():
                log.append(line.decode())

        reader = asyncio.create_task(read_log())
        url = f"http://127.0.0.1:{port}/metrics"
        up_key = ("tactile_device_up", (("device", "array1"),))
        reads_key = ("tactile_reads_total", (("device", "array1"),))
        try:
            values = await scrape_until(url, lambda v: v.get(up_key) == 1.0, proc, 15, "the device up", log)
            assert values.get(up_key) == 1.0, "".join(log)
            with cfg.open("a", encoding="utf-8") as f:
                f.write('calibration = "cal.toml"\n')
            proc.send_signal(signal.SIGHUP)

            def refused() -> bool:
                said = any("reload failed" in line and "not a regular file" in line for line in log)
                return said or proc.returncode is not None

            await wait_until(refused, 15, "the reload refused, naming the FIFO")
            assert proc.returncode is None, "".join(log)
            line = next(line for line in log if "reload failed" in line)
            assert str(fifo) in line and len(line) < 400, line
            # the poll loop goes on: the read counter moves after the refusal
            reads0 = (await scrape(url))[reads_key]
            values = await scrape_until(
                url, lambda v: v.get(reads_key, reads0) > reads0, proc, 15, "another read of the device", log
            )
            assert values[reads_key] > reads0 and values[up_key] == 1.0
            proc.send_signal(signal.SIGTERM)
            code = await asyncio.wait_for(proc.wait(), timeout=15)
            assert code == 0, "".join(log)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            await reader
