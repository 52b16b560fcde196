"""A Modbus/TCP device that answers with random well-formed but wrong responses (issue 16 §3):
wrong byte counts, wrong function codes, exception codes, wrong transaction ids, frames
answering requests never sent, and correct answers in between. A ``Poller`` polls it for a
few seconds: the poll loop survives, every wrong answer is counted as a read error with a
reason, and no published snapshot carries a value decoded from a wrong answer (correct
answers carry ``GOOD`` counts in every register, wrong ones other values).
"""

from __future__ import annotations

import asyncio
import random
import struct
import time
from collections import Counter

import numpy as np

from gateway.config import RegisterMap, bus_config_for, device_config_for, gateway_config_for
from gateway.model import Divider, SensorParams
from gateway.runtime.poller import Poller, SnapshotHolder
from gateway.runtime.snapshot import GatewaySnapshot

GOOD = 30000  # the counts of every correct answer
N = 4
KINDS = ("correct", "byte count", "function", "exception", "transaction id", "unsolicited")
#: Wrong answers that must each cost the request it answers (a read error). An unsolicited
#: frame comes on top of the correct answer, so it must merely never be taken for one.
FAILING = ("byte count", "function", "exception", "transaction id")


class WrongDevice:
    """Raw MBAP framing: a 7-byte header (transaction id, protocol 0, length, unit) and the PDU."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        self.sent: Counter[str] = Counter()
        self.requests = 0
        self.server: asyncio.Server | None = None
        self.tasks: set[asyncio.Task[None]] = set()
        self.writers: set[asyncio.StreamWriter] = set()

    def _wrong_value(self) -> int:
        value = self.rng.randrange(0, 0x10000)
        return value if value != GOOD else GOOD + 1

    def _frame(self, tid: int, unit: int, pdu: bytes) -> bytes:
        return struct.pack(">HHHB", tid & 0xFFFF, 0, len(pdu) + 1, unit) + pdu

    def _registers(self, fc: int, values: list[int]) -> bytes:
        return struct.pack(">BB", fc, 2 * len(values)) + b"".join(struct.pack(">H", v) for v in values)

    async def handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self.tasks.add(task)
        self.writers.add(writer)
        try:
            while True:
                header = await reader.readexactly(7)
                tid, _, length, unit = struct.unpack(">HHHB", header)
                pdu = await reader.readexactly(length - 1)
                self.requests += 1
                fc, _address, count = struct.unpack(">BHH", pdu[:5])
                kind = self.rng.choice(KINDS)
                self.sent[kind] += 1
                wrong = [self._wrong_value()] * count
                if kind == "correct":
                    writer.write(self._frame(tid, unit, self._registers(fc, [GOOD] * count)))
                elif kind == "byte count":  # a well-formed frame with fewer or more registers
                    n = count + self.rng.choice([-1, 1]) if count > 1 else 2
                    writer.write(self._frame(tid, unit, self._registers(fc, [self._wrong_value()] * n)))
                elif kind == "function":  # the other read function
                    writer.write(self._frame(tid, unit, self._registers(fc ^ 0x07, wrong)))
                elif kind == "exception":
                    code = self.rng.choice([1, 2, 3, 4, 6, 11])
                    writer.write(self._frame(tid, unit, bytes([fc | 0x80, code])))
                elif kind == "transaction id":
                    writer.write(
                        self._frame(tid + self.rng.randrange(1, 50), unit, self._registers(fc, wrong))
                    )
                else:  # an answer to the next request, before it is sent; then the right one
                    writer.write(self._frame(tid + 1, unit, self._registers(fc, wrong)))
                    await writer.drain()
                    await asyncio.sleep(0.005)
                    writer.write(self._frame(tid, unit, self._registers(fc, [GOOD] * count)))
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()
            self.writers.discard(writer)
            self.tasks.discard(task)

    async def __aenter__(self) -> int:
        self.server = await asyncio.start_server(self.handle, "127.0.0.1", 0)
        return int(self.server.sockets[0].getsockname()[1])

    async def __aexit__(self, *exc: object) -> None:
        assert self.server is not None
        self.server.close()
        for writer in list(self.writers):  # the handlers end on the closed stream
            writer.close()
        if self.tasks:
            await asyncio.wait(set(self.tasks), timeout=2.0)
        await self.server.wait_closed()


async def test_wrong_answers_are_counted_and_never_published() -> None:
    good_ohm = float(Divider().resistance(np.array([GOOD]))[0][0])
    device = device_config_for(
        "arr",
        1,
        [SensorParams()] * N,
        2,
        2.5,
        front_end=Divider(),
        registers=RegisterMap(status_address=None, clock=None),
    )
    fake = WrongDevice(seed=16)
    published: list[GatewaySnapshot] = []
    holder = SnapshotHolder()
    holder.subscribe(published.append)
    async with fake as port:
        bus = bus_config_for(
            "wrong",
            "tcp",
            [device],
            host="127.0.0.1",
            port=port,
            timeout_s=0.15,
            retries=1,
            poll_interval_s=0.02,
            backoff_initial_s=0.02,
            backoff_max_s=0.1,
        )
        poller = Poller(gateway_config_for([bus]), holder)
        async with poller:
            start = time.monotonic()
            while time.monotonic() < start + 8.0:  # 3 s at least, until every kind was sent 5 times
                if time.monotonic() > start + 3.0 and min(fake.sent[k] for k in KINDS) >= 5:
                    break
                await asyncio.sleep(0.05)
            before = poller.snapshot().counters["arr"].reads_total
            await asyncio.sleep(0.5)
            after = poller.snapshot().counters["arr"].reads_total
            task = poller.workers[0].task
            assert task is not None and not task.done(), "the poll loop ended"
        counters = poller.snapshot().counters["arr"]

    errors = dict(counters.read_errors_total)
    failing = sum(fake.sent[k] for k in FAILING)
    line = (
        f"FUZZ modbus wrong answers: {fake.requests} requests answered ({dict(fake.sent)}); "
        f"reads {counters.reads_total}, errors {errors}, polls {counters.polls_total}, "
        f"{len(published)} snapshots published"
    )
    print(line)
    assert after > before, f"no reads in the last 0.5 s: {line}"
    assert min(fake.sent[k] for k in KINDS) >= 5, f"not every kind of answer was sent: {line}"
    # every wrong answer cost its request: counted, by reason
    # (less the few answers still in flight when the poller stopped: requests the device
    # answered that the gateway never counted as reads)
    in_flight = max(0, fake.requests - counters.reads_total)
    assert in_flight <= 3, line
    assert sum(errors.values()) >= failing - in_flight, line
    assert errors["exception"] >= 1 and errors["decode"] >= 1, line
    assert errors["timeout"] + errors["decode"] >= fake.sent["transaction id"], line
    # every published value is the correct answer's (or absent)
    up = 0
    for snap in published:
        dev = snap.devices.get("arr")
        if dev is None:
            continue
        r = np.asarray(dev.resistance_ohm)
        shown = r[np.isfinite(r)]
        assert np.allclose(shown, good_ohm, rtol=1e-12), f"published {shown.tolist()}, not {good_ohm}: {line}"
        up += int(dev.up)
    assert up >= 5, f"only {up} good polls were published: {line}"
    assert counters.polls_total >= 5, line
