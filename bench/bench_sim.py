"""Benchmark: full reads per second of a 64-channel simulated array versus a bare pymodbus server.

A full read is the ADC block (64 registers) and the float32 resistance block (128 registers,
two requests) over loopback Modbus TCP, from one plain ``AsyncModbusTcpClient``. The baseline
is a pymodbus ``SimDevice`` with static registers of the same layout, measured in the same
run with the same client code. Goal: simulated / bare >= 0.8.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable

from pymodbus.client import AsyncModbusTcpClient

from sim_device import ArrayConfig, SimArray, serve_tcp
from sim_device import registers as reg
from sim_device.modbus_server import serve_static_tcp

CHANNELS = 64
DURATION_S = 5.0


class _Reader:
    """One plain client doing full reads (ADC block + float32 block) of one server."""

    def __init__(self, port: int) -> None:
        self.client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=5.0, retries=0)
        self.reads: list[Callable[[], Awaitable[object]]] = [
            lambda: self.client.read_input_registers(reg.IR_ADC_COUNTS, count=CHANNELS, device_id=1),
            lambda: self.client.read_input_registers(reg.IR_RESISTANCE, count=CHANNELS, device_id=1),
            lambda: self.client.read_input_registers(
                reg.IR_RESISTANCE + CHANNELS, count=CHANNELS, device_id=1
            ),
        ]
        self.done = 0
        self.elapsed_s = 0.0

    async def connect(self) -> None:
        if not await self.client.connect():
            raise RuntimeError("cannot connect to the benchmark server")
        for read in self.reads:  # warm up, and check that the layout answers
            response = await read()
            if getattr(response, "isError", lambda: True)():
                raise RuntimeError(f"read failed: {response}")

    async def run(self, duration_s: float) -> None:
        start = time.perf_counter()
        while time.perf_counter() - start < duration_s:
            for read in self.reads:
                await read()
            self.done += 1
        self.elapsed_s += time.perf_counter() - start

    @property
    def rate(self) -> float:
        return self.done / self.elapsed_s


async def _run(duration_s: float, slices: int = 10) -> tuple[float, float]:
    """Both servers run at once; the two clients take turns in short slices (fair under drift).

    The simulated array has no background ticker here: all of its physics (every 10 ms
    sample, also those due while the bare server was being measured) is paid for inside
    its own read slices.
    """
    config = ArrayConfig(channels=CHANNELS, columns=8, scenario="indentation", speed=1.0)
    async with serve_static_tcp(CHANNELS) as port, serve_tcp(SimArray(config), tick_s=None) as server:
        bare, simulated = _Reader(port), _Reader(server.port)
        await bare.connect()
        await simulated.connect()
        try:
            for _ in range(slices):
                await bare.run(duration_s / slices)
                await simulated.run(duration_s / slices)
        finally:
            bare.client.close()
            simulated.client.close()
    return bare.rate, simulated.rate


def main() -> None:
    bare, simulated = asyncio.run(_run(DURATION_S))
    print(
        f"bare pymodbus SimDevice ({CHANNELS} ch): {bare:8.1f} full reads/s (ADC + float blocks, 3 requests)"
    )
    print(f"sim_device SimArray     ({CHANNELS} ch): {simulated:8.1f} full reads/s (physics at 100 Hz)")
    print(f"ratio simulated / bare: {simulated / bare:.2f} (goal >= 0.8)")


if __name__ == "__main__":
    main()
