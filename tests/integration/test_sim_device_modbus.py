"""sim_device against real servers on 127.0.0.1 and on a socat pty pair, with plain pymodbus clients.

No mocks: every test starts a server (port 0, or a pty), reads or writes with an
``AsyncModbusTcpClient`` / ``AsyncModbusSerialClient`` / ``AsyncModbusTlsClient`` and
compares with the simulator's own sensor physics (``sim_device.sensor``, run over the whole
load history at once), eq. 18 by hand, the scenario and the register map. Nothing here
imports ``gateway``.
"""

from __future__ import annotations

import asyncio
import shutil
import ssl
import subprocess
import threading
import time
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient, AsyncModbusTlsClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType
from pymodbus.pdu.mei_message import ReadDeviceInformationResponse
from waiting import ManualClock, until

from sim_device import ArrayConfig, LineTiming, Scenario, SimArray, serve_serial, serve_tcp, serve_tls
from sim_device import registers as reg
from sim_device.sensor import PaperSensor

Client = AsyncModbusTcpClient | AsyncModbusSerialClient | AsyncModbusTlsClient


@pytest.fixture(autouse=True)
async def no_leaked_tasks() -> AsyncIterator[None]:
    before = asyncio.all_tasks()
    threads = threading.active_count()
    yield
    for _ in range(5):
        await asyncio.sleep(0)
    leaked = [t for t in asyncio.all_tasks() - before if t is not asyncio.current_task() and not t.done()]
    assert not leaked, f"tasks left behind: {leaked}"
    assert threading.active_count() == threads, "threads left behind"


async def tcp_client(port: int, **options: object) -> AsyncModbusTcpClient:
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=1.0, retries=0, **options)  # type: ignore[arg-type]
    assert await client.connect()
    return client


async def read_floats(client: Client, address: int, n: int, device_id: int) -> np.ndarray:
    """n float32 values starting at ``address`` (reads of at most 124 registers)."""
    words: list[int] = []
    for start in range(0, 2 * n, 124):
        count = min(124, 2 * n - start)
        rr = await client.read_input_registers(address + start, count=count, device_id=device_id)
        assert not rr.isError(), rr
        words.extend(rr.registers)
    return np.array(words, dtype=">u2").view(">f4").astype(np.float64)


async def snapshot(client: Client, n: int, device_id: int = 1) -> dict[str, np.ndarray | int]:
    """A consistent read of the measurement blocks (retried until the sample counter holds still)."""
    for _ in range(50):
        head = await client.read_input_registers(0, count=7, device_id=device_id)
        assert not head.isError(), head
        adc = await client.read_input_registers(reg.IR_ADC_COUNTS, count=n, device_id=device_id)
        assert not adc.isError(), adc
        data: dict[str, np.ndarray | int] = {
            "adc": np.array(adc.registers),
            "resistance": await read_floats(client, reg.IR_RESISTANCE, n, device_id),
            "force": await read_floats(client, reg.IR_TRUE_FORCE, n, device_id),
            "temperature": await read_floats(client, reg.IR_TEMPERATURE, n, device_id),
            "true_resistance": await read_floats(client, reg.IR_TRUE_RESISTANCE, n, device_id),
        }
        tail = await client.read_input_registers(0, count=7, device_id=device_id)
        if tail.registers == head.registers:
            r = head.registers
            data["counter"] = (r[0] << 16) | r[1]
            data["time_ms"] = (r[2] << 48) | (r[3] << 32) | (r[4] << 16) | r[5]
            data["status"] = r[6]
            return data
    pytest.fail("the sample counter never held still over one snapshot")


def check_against_model(data: dict[str, np.ndarray | int], array: SimArray) -> None:
    """What the registers say is the array's physics for the scripted load: the true
    resistance of its paper sensor run over the whole history in one go (the server
    advances it lazily, in pieces), the ADC counts of eq. 18 within the configured noise,
    the float32 block eq. 18 of the counts, the bench force the scenario's."""
    period = array.config.sample_period_s
    counter = int(data["counter"])
    times = np.asarray(np.arange(counter) * period, dtype=np.float64)
    assert int(data["time_ms"]) == round(times[-1] * 1000.0)
    force = array.scenario.force_n(times)
    r_model = PaperSensor(array.channel_params).run(force, times, 0.0).total_ohm[-1]
    r_ref, full_scale = array.config.reference_ohm, 2**array.config.adc_bits - 1
    expected = r_ref / (r_ref + r_model) * full_scale
    noise = array.config.noise_lsb_rms
    assert np.abs(np.asarray(data["adc"]) - expected).max() <= 6.0 * noise + 1.0
    np.testing.assert_allclose(np.asarray(data["true_resistance"]), r_model, rtol=1e-6)
    # bench force: the scenario at the sample time
    np.testing.assert_array_equal(np.asarray(data["force"]), force[-1].astype(np.float32))
    np.testing.assert_array_equal(np.asarray(data["temperature"]), np.float32(25.0))
    # float32 block = eq. 18 of the ADC block
    counts = np.asarray(data["adc"], dtype=np.float64)
    with np.errstate(divide="ignore"):
        from_counts = np.where(counts == 0, np.inf, r_ref * (full_scale / counts - 1.0))
    np.testing.assert_array_equal(np.asarray(data["resistance"]), from_counts.astype(np.float32))


HOLDS = {"scenario": "holds", "speed": 200.0, "sample_period_s": 2.0, "noise_lsb_rms": 2.0, "seed": 5}


async def run_device_to(client: Client, clock: ManualClock, arrays: list[SimArray], device_s: float) -> None:
    """Move the arrays' clock (the test's, not the wall's) to ``device_s`` of device time in
    pieces, reading each array's sample counter after every piece: the server advances the
    physics lazily, a piece per read, as it does on the wall clock, but the device stands at
    exactly ``device_s`` however long the reads take on a busy machine."""
    speed = arrays[0].config.speed
    pieces = 8
    start_s = clock() * speed
    for k in range(1, pieces + 1):
        clock.now_s = (start_s + (device_s - start_s) * k / pieces) / speed
        for array in arrays:
            rr = await client.read_input_registers(reg.IR_SAMPLE_COUNTER, count=2, device_id=array.device_id)
            assert not rr.isError(), rr
    for array in arrays:
        assert array.device_time_s == pytest.approx(device_s)


async def test_tcp_reads_what_the_model_predicts() -> None:
    clock = ManualClock()
    array = SimArray(ArrayConfig(**HOLDS), clock=clock)  # type: ignore[arg-type]
    async with serve_tcp(array) as server:
        client = await tcp_client(server.port)
        try:
            await run_device_to(client, clock, [array], 160.0)  # the 2 N hold, creeping
            data = await snapshot(client, 16)
            assert np.asarray(data["force"]).min() == pytest.approx(2.0)
            check_against_model(data, array)
            assert int(data["status"]) == 0
        finally:
            client.close()


async def test_rtu_serial_two_arrays_on_one_bus(pty_pair: tuple[str, str]) -> None:
    server_end, client_end = pty_pair
    slow = {**HOLDS, "speed": 100.0}
    second_config = ArrayConfig(**{**slow, "channels": 8, "columns": 4, "seed": 9})  # type: ignore[arg-type]
    clock = ManualClock()
    first = SimArray(ArrayConfig(**slow), device_id=1, clock=clock)  # type: ignore[arg-type]
    second = SimArray(second_config, device_id=7, clock=clock)
    async with serve_serial([first, second], port=server_end, baudrate=115200, line_timing=False):
        client = AsyncModbusSerialClient(client_end, baudrate=115200, timeout=0.5, retries=0)
        assert await client.connect()
        try:
            await run_device_to(client, clock, [first, second], 30.0)  # the 0.5 N hold, creeping
            check_against_model(await snapshot(client, 16, 1), first)
            check_against_model(await snapshot(client, 8, 7), second)
            with pytest.raises(ModbusException):  # nobody answers for id 3 on the bus
                await client.read_input_registers(0, count=2, device_id=3)
            rr = await client.read_holding_registers(0, count=1, device_id=7)
            assert rr.registers == [8]
        finally:
            client.close()


async def test_line_timing_at_9600_baud(pty_pair: tuple[str, str]) -> None:
    server_end, client_end = pty_pair
    array = SimArray(ArrayConfig())
    turnaround_s = 0.005
    async with serve_serial(
        array, port=server_end, baudrate=9600, line_timing=True, turnaround_s=turnaround_s
    ):
        client = AsyncModbusSerialClient(client_end, baudrate=9600, timeout=1.0, retries=0)
        assert await client.connect()
        try:
            frame_s = LineTiming(9600, turnaround_s).transaction_s(8, 5 + 2 * 10)
            assert frame_s == pytest.approx((8 + 25 + 7) * 11 / 9600 + turnaround_s)
            for _ in range(3):
                start = time.perf_counter()
                rr = await client.read_input_registers(reg.IR_ADC_COUNTS, count=10, device_id=1)
                elapsed = time.perf_counter() - start
                assert not rr.isError()
                assert frame_s <= elapsed < frame_s + 0.25
        finally:
            client.close()


async def test_rtu_garbled_frame_then_recovery(pty_pair: tuple[str, str]) -> None:
    server_end, client_end = pty_pair
    array = SimArray(ArrayConfig())
    async with serve_serial(array, port=server_end, baudrate=115200, line_timing=False):
        seen: list[bytes] = []

        def trace(sending: bool, data: bytes) -> bytes:
            if not sending:
                seen.append(bytes(data))
            return data

        client = AsyncModbusSerialClient(
            client_end, baudrate=115200, timeout=0.3, retries=0, trace_packet=trace
        )
        assert await client.connect()
        try:
            array.faults.garble = True
            with pytest.raises(ModbusException):
                await client.read_input_registers(0, count=2, device_id=1)
            frame = b"".join(seen)
            assert frame[:2] == b"\x01\x04" and len(frame) == 9, "a whole frame arrived, with a bad CRC"
            array.faults.exception_code = 6
            array.faults.garble = False
            rr = await client.read_input_registers(0, count=2, device_id=1)
            assert rr.isError() and rr.exception_code == 6
            array.faults.clear()
            rr = await client.read_input_registers(0, count=2, device_id=1)
            assert not rr.isError() and len(rr.registers) == 2
        finally:
            client.close()


@pytest.mark.slow  # waits out two client time-outs (about 2 s)
async def test_rtu_framing_over_tcp() -> None:
    clock = ManualClock()
    arrays = [SimArray(ArrayConfig(**HOLDS), device_id=i, clock=clock) for i in (1, 2)]  # type: ignore[arg-type]
    async with serve_tcp(arrays, framer="rtu") as server:
        client = await tcp_client(server.port, framer=FramerType.RTU)
        client.comm_params.timeout_connect = 0.3
        try:
            await run_device_to(client, clock, arrays, 100.0)  # the 0.5 N hold
            check_against_model(await snapshot(client, 16, 2), arrays[1])
            with pytest.raises(ModbusException):  # unknown id: silence, as on a bus
                await client.read_input_registers(0, count=2, device_id=5)
            arrays[0].faults.garble = True
            with pytest.raises(ModbusException):
                await client.read_input_registers(0, count=2, device_id=1)
            arrays[0].faults.clear()
            assert not (await client.read_input_registers(0, count=2, device_id=1)).isError()
        finally:
            client.close()


@pytest.fixture
def certificate(tmp_path: Path) -> tuple[str, str]:
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.fail("openssl is missing (Debian package openssl)")
    cert, key = tmp_path / "server.crt", tmp_path / "server.key"
    subprocess.run(
        [openssl, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(cert),
         "-days", "1", "-subj", "/CN=localhost", "-addext", "subjectAltName=IP:127.0.0.1,DNS:localhost"],
        check=True, capture_output=True,
    )  # fmt: skip
    return str(cert), str(key)


async def test_tls_reads_what_the_model_predicts(certificate: tuple[str, str]) -> None:
    cert, key = certificate
    clock = ManualClock()
    array = SimArray(ArrayConfig(**HOLDS), clock=clock)  # type: ignore[arg-type]
    async with serve_tls(array, certfile=cert, keyfile=key) as server:
        context = ssl.create_default_context(cafile=cert)
        client = AsyncModbusTlsClient("127.0.0.1", port=server.port, sslctx=context, timeout=1.0, retries=0)
        assert await client.connect()
        try:
            await run_device_to(client, clock, [array], 60.0)  # the 0.5 N hold
            check_against_model(await snapshot(client, 16), array)
        finally:
            client.close()


async def test_device_identification_and_unknown_unit() -> None:
    arrays = [
        SimArray(ArrayConfig(channels=12, columns=4), device_id=1),
        SimArray(ArrayConfig(), device_id=2),
    ]
    async with serve_tcp(arrays) as server:
        client = await tcp_client(server.port)
        try:
            response = await client.read_device_information(read_code=2, device_id=1)
            assert isinstance(response, ReadDeviceInformationResponse), response
            info = response.information
            assert info[0] == b"Tactile Gateway Project" and info[1] == b"TSA-SIM"
            assert info[2] == arrays[0].identity()["MajorMinorRevision"].encode()
            assert info[4] == b"Simulated MIS piezoresistive sensor array"
            assert info[5] == b"Linqstat 3x4"
            response = await client.read_device_information(read_code=2, device_id=2)
            assert isinstance(response, ReadDeviceInformationResponse), response
            info2 = response.information
            assert info2[5] == b"Linqstat 4x4"
            rr = await client.read_input_registers(0, count=2, device_id=9)
            assert rr.isError() and rr.exception_code == 11
            rr = await client.read_input_registers(7, count=1, device_id=1)  # not in the map
            assert rr.isError() and rr.exception_code == 2
            rr = await client.read_coils(0, count=1, device_id=1)
            assert rr.isError() and rr.exception_code == 2
        finally:
            client.close()


async def read_holding(client: Client, n: int) -> list[int]:
    head = await client.read_holding_registers(0, count=12, device_id=1)
    modes = await client.read_holding_registers(reg.HR_CHANNEL_MODE, count=n, device_id=1)
    assert not head.isError() and not modes.isError()
    return [*head.registers, *modes.registers]


async def test_invalid_configuration_writes_are_refused() -> None:
    clock = ManualClock()
    array = SimArray(ArrayConfig(), clock=clock)
    async with serve_tcp(array) as server:
        client = await tcp_client(server.port)
        try:
            before = await read_holding(client, 16)
            assert before[:2] == [16, 16] and before[10:12] == [4, 2500]
            electronics = array.electronics
            cases = [
                (reg.HR_CHANNEL_COUNT, [8], 2),
                (reg.HR_GRID_COLUMNS, [2, 1000], 2),
                (reg.HR_ADC_BITS, [7], 3),
                (reg.HR_ADC_BITS, [17], 3),
                (reg.HR_SUPPLY_V, [0x4120], 3),
                (reg.HR_SUPPLY_V + 1, [0, 0], 3),
                (reg.HR_SUPPLY_V, reg.float32_words([25.0]), 3),
                (reg.HR_REFERENCE_OHM, reg.float32_words([5.0]), 3),
                (reg.HR_SAMPLE_PERIOD_S, reg.float32_words([11.0]), 3),
                (reg.HR_NOISE_LSB_RMS, reg.float32_words([float("inf")]), 3),
                (reg.HR_CHANNEL_MODE + 4, [1, 3], 3),
                (reg.HR_CHANNEL_MODE + 15, [0, 0], 2),
                (12, [1], 2),
            ]
            for address, values, code in cases:
                if len(values) == 1:
                    rr = await client.write_register(address, values[0], device_id=1)
                else:
                    rr = await client.write_registers(address, values, device_id=1)
                assert rr.isError() and rr.exception_code == code, (address, values, rr)
                assert await read_holding(client, 16) == before
                assert array.electronics == electronics
            rr = await client.write_registers(reg.HR_ADC_BITS, [12, *reg.float32_words([3.3])], device_id=1)
            assert not rr.isError()
            rr = await client.write_register(reg.HR_CHANNEL_MODE + 5, 1, device_id=1)
            assert not rr.isError()
            after = await read_holding(client, 16)
            assert after[1] == 12 and after[12 + 5] == 1  # 12 configuration registers, then the modes
            assert array.electronics.adc_bits == 12 and array.electronics.supply_v == pytest.approx(3.3)
            # the mode holds from the next conversion on: one sample period of device time
            assert array.device_time_s == array.last_sample_time_s
            clock.advance(array.electronics.sample_period_s / array.config.speed)
            status = await client.read_input_registers(reg.IR_STATUS_SUMMARY, count=1, device_id=1)
            opened = await client.read_input_registers(reg.IR_OPEN_BITMAP, count=1, device_id=1)
            assert status.registers[0] & reg.STATUS_ANY_OPEN and opened.registers[0] == 1 << 5
        finally:
            client.close()


@pytest.mark.slow  # waits out client time-outs (about 3 s)
async def test_each_fault_appears_and_the_server_keeps_serving() -> None:
    clock = ManualClock()
    array = SimArray(ArrayConfig(scenario="holds", speed=20.0), clock=clock)
    async with serve_tcp(array) as server:
        client = await tcp_client(server.port)
        client.comm_params.timeout_connect = 0.3

        async def healthy() -> None:
            rr = await client.read_input_registers(0, count=2, device_id=1)
            assert not rr.isError() and len(rr.registers) == 2

        try:
            array.faults.delay_s = 0.2
            start = time.perf_counter()
            await healthy()
            assert time.perf_counter() - start >= 0.2
            array.faults.clear()
            start = time.perf_counter()
            await healthy()
            assert time.perf_counter() - start < 0.1

            array.faults.exception_code = 6  # DEVICE_BUSY
            rr = await client.read_input_registers(0, count=2, device_id=1)
            assert rr.isError() and rr.exception_code == 6
            array.faults.clear()
            await healthy()

            array.faults.no_response = True
            with pytest.raises(ModbusException):
                await client.read_input_registers(0, count=2, device_id=1)
            array.faults.clear()
            await healthy()

            array.faults.garble = True
            with pytest.raises(ModbusException):
                await client.read_input_registers(0, count=2, device_id=1)
            array.faults.clear()
            await healthy()

            array.faults.drop_connection = True
            with pytest.raises(ModbusException):
                await client.read_input_registers(0, count=2, device_id=1)
            array.faults.clear()
            await until(
                lambda: client.connected and server._server.active_connections, 10.0, "the client reconnected"
            )
            await healthy()

            # a channel goes open on schedule (device time)
            array.faults.schedule(array.device_time_s + 1.0, channel=2, channel_mode="open")
            opened = await client.read_input_registers(reg.IR_OPEN_BITMAP, count=1, device_id=1)
            assert opened.registers == [0], "open before its time"
            clock.advance(1.5 / array.config.speed)  # 1.5 s of device time: past the scheduled instant
            opened = await client.read_input_registers(reg.IR_OPEN_BITMAP, count=1, device_id=1)
            assert opened.registers == [1 << 2]
            adc = await client.read_input_registers(reg.IR_ADC_COUNTS + 2, count=1, device_id=1)
            assert adc.registers == [0]
        finally:
            client.close()


async def test_client_disconnecting_mid_request() -> None:
    clock = ManualClock()
    array = SimArray(ArrayConfig(), clock=clock)
    delay_s = 0.2
    async with serve_tcp(array) as server:
        array.faults.delay_s = delay_s
        client = await tcp_client(server.port)
        # the device's clock moves one sample period, so serving the request (the server reads
        # the registers, then holds the answer back) converts one sample: that is the event
        clock.advance(array.electronics.sample_period_s / array.config.speed)
        counter = array.sample_counter
        pending = asyncio.ensure_future(client.read_input_registers(0, count=2, device_id=1))
        await until(lambda: array.sample_counter > counter, 10.0, "the server to take the request")
        served_at = time.monotonic()
        assert not pending.done(), "the answer was not held back"
        client.close()
        with pytest.raises(ModbusException):
            await pending
        # half a request frame, then the connection goes away
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(b"\x00\x01\x00\x00\x00\x06\x01\x04")
        await writer.drain()
        writer.close()
        await writer.wait_closed()
        del reader
        array.faults.clear()
        # Kept on purpose: the instant the held-back answer falls due, with nobody to take it,
        # is what is under test (the server must keep serving after it). Measured from when
        # the request was served, with a margin, not a fixed guess.
        await asyncio.sleep(max(0.0, served_at + delay_s - time.monotonic()) + 0.05)
        again = await tcp_client(server.port)
        try:
            rr = await again.read_input_registers(0, count=2, device_id=1)
            assert not rr.isError()
        finally:
            again.close()


async def test_server_stops_cleanly_and_frees_the_port() -> None:
    array = SimArray(ArrayConfig())
    async with serve_tcp(array) as server:
        port = server.port
        client = await tcp_client(port)
        assert not (await client.read_input_registers(0, count=1, device_id=1)).isError()
    # no wait: the port is closed when the server's block has ended (it awaits the listener)
    with pytest.raises(OSError):
        await asyncio.open_connection("127.0.0.1", port)
    client.close()
    async with serve_tcp(array, port=port) as again:  # the port can be bound again at once
        assert again.port == port


async def test_scenario_objects_are_served() -> None:
    layout = ArrayConfig(channels=4, columns=2).layout
    array = SimArray(ArrayConfig(channels=4, columns=2, scenario=Scenario.constant(1.25, layout)))
    async with serve_tcp(array) as server:
        client = await tcp_client(server.port)
        try:
            forces = await read_floats(client, reg.IR_TRUE_FORCE, 4, 1)
            np.testing.assert_array_equal(forces, 1.25)
        finally:
            client.close()
