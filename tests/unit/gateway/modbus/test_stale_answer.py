"""A late answer on a line without transaction ids (RTU) is not taken for the answer.

The template method asks a device identification once more, after a quiet time, when an
answer on serial framing could not be used; the pymodbus backend names an answer to another
function as such and empties what waits on a serial port it has just opened."""

from __future__ import annotations

import asyncio
import re
import time
from dataclasses import dataclass
from typing import Any

import pytest
from pymodbus.pdu.mei_message import ReadDeviceInformationResponse
from pymodbus.pdu.register_message import ReadInputRegistersResponse

from gateway.errors import DecodeError, DeviceTimeoutError
from gateway.modbus.client import ModbusTransport
from gateway.modbus.endpoint import TlsSettings
from gateway.modbus.transport import Transport

IDENT = {"VendorName": "ACME", "ProductCode": "AT-6x6"}


class Scripted(Transport):
    """A backend whose identification answers are scripted: a dict is answered, an
    exception raised. Every call is logged in ``events`` with the time it was made."""

    def __init__(self, serial: bool, answers: list[object], timeout_s: float = 0.1) -> None:
        super().__init__("line", timeout_s)
        self.serial, self.answers, self._up = serial, list(answers), False
        self.events: list[tuple[str, float]] = []
        self.on_first_call: Any = None

    @property
    def target(self) -> str:
        return "scripted target"

    @property
    def connected(self) -> bool:
        return self._up

    @property
    def is_serial_framing(self) -> bool:
        return self.serial

    async def _connect(self) -> None:
        self._up = True

    async def _close(self) -> None:
        self._up = False

    async def _read(self, kind: str, device_id: int, address: int, count: int, what: str) -> list[int]:
        self.events.append(("read", time.monotonic()))
        return [0] * count

    async def _write(self, device_id: int, address: int, values: list[int], what: str) -> None:
        raise NotImplementedError

    async def _read_device_identification(self, device_id: int, what: str) -> dict[str, str]:
        self.events.append(("identification", time.monotonic()))
        if len(self.events) == 1 and self.on_first_call is not None:
            self.on_first_call()
        answer = self.answers.pop(0)
        if isinstance(answer, BaseException):
            raise answer
        assert isinstance(answer, dict)
        return answer


def stale(n: int = 1) -> DecodeError:
    return DecodeError(f"read device identification of device 2 on 'line': answer has function 4 ({n})")


def calls(t: Scripted) -> list[str]:
    return [name for name, _ in t.events]


async def test_on_serial_framing_an_unusable_answer_is_asked_once_more_after_a_quiet_time() -> None:
    t = Scripted(serial=True, answers=[stale(), dict(IDENT)], timeout_s=0.1)
    async with t:
        assert await t.read_device_identification(2) == IDENT
    assert calls(t) == ["identification", "identification"]
    gap = t.events[1][1] - t.events[0][1]
    assert t.late_answer_drain_s == pytest.approx(0.05)
    assert gap >= 0.05 - 0.005, f"asked again after {gap:.4f} s: a late answer had no time to drain"


async def test_a_second_unusable_answer_raises() -> None:
    t = Scripted(serial=True, answers=[stale(1), stale(2)], timeout_s=0.02)
    async with t:
        with pytest.raises(DecodeError, match=re.escape("answer has function 4 (2)")):
            await t.read_device_identification(2)
    assert calls(t) == ["identification", "identification"]


async def test_a_network_bus_does_not_ask_again() -> None:
    t = Scripted(serial=False, answers=[stale(), dict(IDENT)])
    async with t:
        with pytest.raises(DecodeError, match=re.escape("answer has function 4 (1)")):
            await t.read_device_identification(2)
    assert calls(t) == ["identification"]


async def test_no_answer_is_not_asked_again() -> None:
    timeout = DeviceTimeoutError("read device identification of device 2 on 'line': no answer")
    t = Scripted(serial=True, answers=[timeout, dict(IDENT)])
    async with t:
        with pytest.raises(DeviceTimeoutError):
            await t.read_device_identification(2)
    assert calls(t) == ["identification"]


async def test_the_line_stays_quiet_until_the_identification_was_asked_again() -> None:
    """Another request on the bus waits out the drain and the repeat (it would otherwise be
    the one to get the late answer)."""
    t = Scripted(serial=True, answers=[stale(), dict(IDENT)], timeout_s=0.04)
    others: list[asyncio.Task[list[int]]] = []
    t.on_first_call = lambda: others.append(asyncio.create_task(t.read_input_registers(2, 0, 1)))
    async with t:
        assert await t.read_device_identification(2) == IDENT
        assert await asyncio.wait_for(others[0], 1.0) == [0]
    assert calls(t) == ["identification", "identification", "read"]


@pytest.mark.parametrize(("timeout_s", "drain_s"), [(0.1, 0.05), (0.4, 0.2), (2.0, 0.2)])
def test_the_drain_is_half_the_timeout_at_most_0_2_s(timeout_s: float, drain_s: float) -> None:
    assert Scripted(serial=True, answers=[], timeout_s=timeout_s).late_answer_drain_s == pytest.approx(
        drain_s
    )


# ---------------------------------------------------------------------- pymodbus backend
@dataclass(frozen=True)
class Bus:
    name: str = "line"
    kind: str = "rtu"
    host: str | None = None
    port: int | None = None
    serial_port: str | None = "/dev/ttyUSB9"
    baudrate: int = 115200
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8
    tls: TlsSettings | None = None
    timeout_s: float = 0.02


class FakeClient:
    """Stands in for the pymodbus client: answers identification requests from a script."""

    connected = True

    def __init__(self, answers: list[Any]) -> None:
        self.answers = answers
        self.asked = 0

    async def read_device_information(self, read_code: int, object_id: int, device_id: int) -> Any:
        self.asked += 1
        return self.answers.pop(0)


def identification_answer(device_id: int = 2) -> ReadDeviceInformationResponse:
    return ReadDeviceInformationResponse(
        read_code=0x02, information={0: b"ACME", 1: b"AT-6x6"}, dev_id=device_id
    )


def with_client(kind: str, answers: list[Any]) -> tuple[ModbusTransport, FakeClient]:
    transport = ModbusTransport(Bus(kind=kind, host=None if kind == "rtu" else "127.0.0.1"))
    client = FakeClient(answers)
    transport._client = client  # type: ignore[assignment]
    return transport, client


async def test_an_answer_to_another_function_is_named_as_such() -> None:
    stale_answer = ReadInputRegistersResponse(registers=[0x1234, 0], dev_id=2)
    transport, client = with_client("tcp", [stale_answer])
    with pytest.raises(DecodeError) as err:
        await transport.read_device_identification(2)
    assert str(err.value) == "read device identification of device 2 on 'line': answer has function 4"
    assert client.asked == 1


async def test_on_rtu_an_answer_to_another_function_is_followed_by_the_real_one() -> None:
    transport, client = with_client(
        "rtu", [ReadInputRegistersResponse(registers=[7], dev_id=2), identification_answer()]
    )
    assert await transport.read_device_identification(2) == IDENT
    assert client.asked == 2


async def test_an_identification_answer_without_objects_says_so() -> None:
    empty = identification_answer()
    empty.information = None  # type: ignore[assignment]
    transport, _ = with_client("tcp", [empty])
    with pytest.raises(DecodeError, match=re.escape("device 2 on 'line': answer carries no objects")):
        await transport.read_device_identification(2)


class FakeSerial:
    def __init__(self, fails: bool = False) -> None:
        self.resets, self.fails, self.port = 0, fails, "/dev/ttyUSB9"

    def reset_input_buffer(self) -> None:
        self.resets += 1
        if self.fails:
            raise OSError(5, "Input/output error")


def fake_serial_client(port: Any, recv_buffer: Any = b"\x02\x04\x08\x12") -> Any:
    transport = type("T", (), {"sync_serial": port})()
    ctx = type("Ctx", (), {"transport": transport, "recv_buffer": recv_buffer})()
    return type("Client", (), {"ctx": ctx})()


def test_what_waits_on_a_serial_port_just_opened_is_discarded() -> None:
    port = FakeSerial()
    client = fake_serial_client(port)
    ModbusTransport._discard_waiting_input(client)
    assert port.resets == 1
    assert client.ctx.recv_buffer == b""


def test_discarding_is_skipped_quietly_where_the_transport_is_not_the_one_expected() -> None:
    ModbusTransport._discard_waiting_input(object())  # no ctx at all
    client = fake_serial_client(None, recv_buffer=None)  # no pyserial object, no buffer
    ModbusTransport._discard_waiting_input(client)
    assert client.ctx.recv_buffer is None
    failing = FakeSerial(fails=True)
    client = fake_serial_client(failing)
    ModbusTransport._discard_waiting_input(client)  # a port that cannot be flushed: no error
    assert failing.resets == 1
    assert client.ctx.recv_buffer == b""
