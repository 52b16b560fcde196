"""A late answer on an RTU line is not the answer to the next request.

RTU frames carry no transaction id: an answer that reaches the gateway after its request was
given up (the poller was cancelled, a read timed out) looks like the answer to whatever the
gateway asks next, when the device id matches. Here a well-formed read-input-registers answer
of device 2 is put on the line (a socat pty pair, the simulator on the device end) at three
moments: before the gateway opens the port, while the port is being opened, and right after
the identification request has gone out. Each time the gateway must return the simulator's
real identification.
"""

from __future__ import annotations

import os
import time
from typing import Any

from test_gateway_tcp import array_device

from gateway.config import BusConfig, bus_config_for
from gateway.modbus.client import ModbusTransport
from sim_device import ArrayConfig, SimArray, serve_serial
from sim_device.maps import PRODUCT_CODE, VENDOR_NAME

BAUD = 115200
DEVICE_ID = 2


def crc16_modbus(data: bytes) -> int:
    """Modbus RTU CRC-16 (polynomial 0xA001 reflected, initial 0xFFFF)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def stale_read_input_answer(device_id: int, registers: list[int]) -> bytes:
    """A complete RTU answer to function 4: id, 4, byte count, registers, CRC (low byte first)."""
    body = bytes([device_id, 0x04, 2 * len(registers)])
    body += b"".join(r.to_bytes(2, "big") for r in registers)
    return body + crc16_modbus(body).to_bytes(2, "little")


STALE = stale_read_input_answer(DEVICE_ID, [0x1234, 0x0000, 0x00FF, 0xABCD])


def test_the_stale_frame_is_a_valid_rtu_answer() -> None:
    # reference frame of the Modbus specification: read holding 0x6B of device 0x11 -> CRC 0x8776
    assert crc16_modbus(bytes.fromhex("1103006B0003")).to_bytes(2, "little") == bytes.fromhex("7687")
    assert crc16_modbus(STALE) == 0  # a frame followed by its own CRC checks to zero
    assert STALE[:3] == bytes([DEVICE_ID, 0x04, 8])


def write_to_line(dev_port: str, frame: bytes) -> None:
    """Send ``frame`` towards the gateway end: written on the device end of the pty pair."""
    fd = os.open(dev_port, os.O_WRONLY | os.O_NOCTTY)
    try:
        os.write(fd, frame)
    finally:
        os.close(fd)


def waiting_on_gateway_port(transport: ModbusTransport) -> int:
    """Bytes the kernel holds for the gateway's open port (not yet read by pymodbus)."""
    client: Any = transport._client
    return int(client.ctx.transport.sync_serial.in_waiting)


def wait_for(cond: Any, timeout_s: float, what: str) -> None:
    """Block until ``cond()`` holds; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.0005)


def two_arrays() -> tuple[SimArray, SimArray]:
    cfg = ArrayConfig(channels=4, columns=2, pitch_mm=2.5, seed=7, scenario="holds", speed=1.0)
    return SimArray(cfg, device_id=1), SimArray(cfg, device_id=DEVICE_ID)


def line(gw_port: str, a1: SimArray, a2: SimArray) -> BusConfig:
    return bus_config_for(
        "line",
        "rtu",
        [array_device(a1, "first", 1, bench=False), array_device(a2, "second", DEVICE_ID, bench=False)],
        serial_port=gw_port,
        baudrate=BAUD,
        timeout_s=0.5,
    )


def assert_is_the_simulators_identification(ident: dict[str, str]) -> None:
    assert ident["VendorName"] == VENDOR_NAME
    assert ident["ProductCode"] == PRODUCT_CODE
    assert ident["ModelName"] == "Linqstat 2x2"


async def test_a_stale_answer_waiting_before_the_port_opens_is_not_the_answer(
    pty_pair: tuple[str, str],
) -> None:
    gw_port, dev_port = pty_pair
    a1, a2 = two_arrays()
    write_to_line(dev_port, STALE)  # a late answer from a connection that was closed
    async with (
        serve_serial([a1, a2], port=dev_port, baudrate=BAUD, line_timing=True),
        ModbusTransport(line(gw_port, a1, a2)) as transport,
    ):
        ident = await transport.read_device_identification(DEVICE_ID)
    assert_is_the_simulators_identification(ident)


class StaleWhileOpening(ModbusTransport):
    """Puts the first bytes of the stale answer on the line as the port comes up (after
    pyserial emptied the port's input on opening it) and waits until the kernel holds them
    for the port: the late answer of an earlier connection, arriving meanwhile."""

    dev_port = ""
    injected = b""

    def _trace_connect(self, connected: bool) -> None:
        super()._trace_connect(connected)
        if connected and not self.injected:
            self.injected = STALE[:6]  # a frame cut short: pymodbus would keep it and wait for more
            write_to_line(self.dev_port, self.injected)
            wait_for(lambda: waiting_on_gateway_port(self) >= len(self.injected), 5.0, "the stale bytes")


async def test_a_stale_answer_arriving_while_the_port_opens_is_dropped_at_connect(
    pty_pair: tuple[str, str],
) -> None:
    gw_port, dev_port = pty_pair
    a1, a2 = two_arrays()
    async with serve_serial([a1, a2], port=dev_port, baudrate=BAUD, line_timing=True):
        transport = StaleWhileOpening(line(gw_port, a1, a2))
        transport.dev_port = dev_port
        async with transport:
            assert transport.injected == STALE[:6]
            # nothing of it is left, neither in the kernel nor in pymodbus' receive buffer
            client: Any = transport._client
            assert (waiting_on_gateway_port(transport), client.ctx.recv_buffer) == (0, b"")
            ident = await transport.read_device_identification(DEVICE_ID)
    assert_is_the_simulators_identification(ident)


class StaleAfterRequest(ModbusTransport):
    """Puts the stale answer on the line as the first identification request goes out and
    counts the requests sent. The stale frame is written on the device end before the request
    leaves, so it is ahead of the simulator's answer in the same byte stream; pymodbus reads it
    only after it has sent the request (its reader runs on a later pass of the event loop)."""

    dev_port = ""
    sent: list[bytes]

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending:
            self.sent.append(bytes(data))
            if len(self.sent) == 1:
                write_to_line(self.dev_port, STALE)
        return super()._trace_packet(sending, data)


async def test_a_stale_answer_arriving_after_the_request_is_not_the_answer(
    pty_pair: tuple[str, str],
) -> None:
    gw_port, dev_port = pty_pair
    a1, a2 = two_arrays()
    async with serve_serial([a1, a2], port=dev_port, baudrate=BAUD, line_timing=True, turnaround_s=0.03):
        transport = StaleAfterRequest(line(gw_port, a1, a2))
        transport.dev_port, transport.sent = dev_port, []
        async with transport:
            ident = await transport.read_device_identification(DEVICE_ID)
    assert_is_the_simulators_identification(ident)
    # the stale frame was taken for the first answer and the request was asked once more
    assert len(transport.sent) == 2, transport.sent
    assert transport.sent[0] == transport.sent[1]
    assert transport.sent[0][:3] == bytes([DEVICE_ID, 0x2B, 0x0E])
