"""The "rawgrid" map (docs/register-map-rawgrid.md) on the wire: a plain pymodbus client
against ``serve_tcp`` in this process and against ``tactile-sim run --map rawgrid`` as a
process, both on ephemeral loopback ports.

No mocks and no ``gateway``: the numbers are the document's (ids, version, serial, an
unloaded cell at 3895 counts), the truth the array's own (``true_force_n`` by physical
channel, ``register_channels`` for the storage order). The shared leak guard of
``tests/conftest.py`` checks that no task, thread or process outlives a test.
"""

from __future__ import annotations

import asyncio
import re
import signal
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import numpy as np
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu.mei_message import ReadDeviceInformationResponse

from sim_device import ArrayConfig, Scenario, SimArray, serve_tcp
from sim_device.profiles import ProfileBuilder
from sim_device.scenarios import UniformLoad

N, COLUMNS = 36, 6
UNLOADED = 3895  # 4095 * 195 / 205 = 3895.24, the open sensor shunted by the 195 kohm board leakage
SERIAL = [0x0000, 0x0001, 0xE240, 0x0007]


@asynccontextmanager
async def client_for(port: int) -> AsyncIterator[AsyncModbusTcpClient]:
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0)
    assert await client.connect()
    try:
        yield client
    finally:
        client.close()


async def check_the_fixed_registers_and_refusals(client: AsyncModbusTcpClient) -> None:
    """Everything the document fixes, whatever the load: ids, serial, count, exceptions, FC 43."""
    rr = await client.read_input_registers(0, count=6, device_id=1)
    assert not rr.isError(), rr
    assert rr.registers == [0x5447, 0x0103, *SERIAL]
    rr = await client.read_input_registers(8, count=1, device_id=1)
    assert rr.registers == [N]
    # the default map's clock address holds the constant serial number: it never advances
    await asyncio.sleep(0.05)
    again = await client.read_input_registers(2, count=4, device_id=1)
    assert again.registers == SERIAL
    # unmapped input addresses: the default map's bitmaps (16) and ADC block (100), the gaps,
    # one past the ADC block, and a read covering a gap
    for address, count in (
        (16, 1),
        (100, 1),
        (100, 16),
        (6, 1),
        (7, 1),
        (9, 1),
        (31, 1),
        (32 + N, 1),
        (0, 9),
    ):
        rr = await client.read_input_registers(address, count=count, device_id=1)
        assert rr.isError() and rr.exception_code == 2, (address, count, rr)
    # no holding registers at all
    for address in (0, 1, 2, 8, 10, 100):
        rr = await client.read_holding_registers(address, count=1, device_id=1)
        assert rr.isError() and rr.exception_code == 2, (address, rr)
    rr = await client.write_register(0, 1, device_id=1)
    assert rr.isError() and rr.exception_code == 2
    rr = await client.write_registers(100, [1, 2], device_id=1)
    assert rr.isError() and rr.exception_code == 2
    rr = await client.read_coils(0, count=1, device_id=1)
    assert rr.isError() and rr.exception_code == 2
    # device identification: basic and regular reads give the same three objects
    for read_code in (1, 2):
        response = await client.read_device_information(read_code=read_code, device_id=1)
        assert isinstance(response, ReadDeviceInformationResponse), response
        assert response.information == {0: b"Acme Tactile", 1: b"AT-6x6", 2: b"1.3"}
    rr = await client.read_device_information(read_code=4, object_id=4, device_id=1)  # no ProductName
    assert rr.isError() and rr.exception_code == 2


async def test_served_in_process_registers_and_storage_order() -> None:
    config = ArrayConfig(register_map="rawgrid", channels=N, columns=COLUMNS, noise_lsb_rms=2.0)
    top_left = 0  # physical channel 0: row 0 (top), column 0
    load = UniformLoad(ProfileBuilder(2.0).build(), channels=(top_left,))
    array = SimArray(config.with_changes(scenario=Scenario("top-left", config.layout, loads=[load])))
    async with serve_tcp(array, tick_s=None) as server, client_for(server.port) as client:
        await check_the_fixed_registers_and_refusals(client)
        rr = await client.read_input_registers(32, count=N, device_id=1)
        assert not rr.isError(), rr
        counts = np.array(rr.registers)
        # the wire is the latest conversion, physical channels put in register order
        order = array.register_channels()
        np.testing.assert_array_equal(counts, array.latest().adc_counts[0][order])
        # the loaded top-left cell is stored in the last row of the block: register 32 + 30
        loaded = int(np.flatnonzero(array.true_force_n()[order])[0])
        assert loaded == 30 and array.register_position(loaded) == (0, 0)
        assert 3000 < counts[loaded] < 3340  # 2 N: 3317 at first (noise: 6 sigma 12), creeping lower
        unloaded = np.delete(counts, loaded)
        assert np.abs(unloaded - UNLOADED).max() <= 13  # 2 LSB RMS, 6 sigma, and the rounding


async def test_unloaded_array_reads_the_leakage_count() -> None:
    config = ArrayConfig(register_map="rawgrid", channels=N, columns=COLUMNS, noise_lsb_rms=0.0)
    async with serve_tcp(SimArray(config)) as server, client_for(server.port) as client:
        rr = await client.read_input_registers(32, count=N, device_id=1)
        assert rr.registers == [UNLOADED] * N


def tactile_sim() -> list[str]:
    """The installed console script next to this interpreter (``python -m`` without one)."""
    script = Path(sys.executable).with_name("tactile-sim")
    return [str(script)] if script.exists() else [sys.executable, "-m", "sim_device.cli"]


async def test_tactile_sim_run_map_rawgrid_process() -> None:
    options = ["--channels", str(N), "--columns", str(COLUMNS), "--noise-lsb", "0", "--no-spread"]
    proc = await asyncio.create_subprocess_exec(
        *tactile_sim(), "run", "--map", "rawgrid", "--tcp", "127.0.0.1:0", *options,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        banner = await asyncio.wait_for(proc.stderr.readline(), timeout=20.0)
        match = re.search(rb"on tcp 127\.0\.0\.1:(\d+);.*map rawgrid", banner)
        assert match, banner
        async with client_for(int(match.group(1))) as client:
            await check_the_fixed_registers_and_refusals(client)
            rr = await client.read_input_registers(32, count=N, device_id=1)
            assert rr.registers == [UNLOADED] * N
        proc.send_signal(signal.SIGTERM)
        _out, err = await asyncio.wait_for(proc.communicate(), timeout=10.0)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode == 0, err
    assert b"stopped" in err and b"Traceback" not in err
