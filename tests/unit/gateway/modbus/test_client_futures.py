"""A pymodbus request the client fails on its own (a connection lost, an undecodable answer)
reaches its awaiter as that error, and one nobody awaits any more (a poll cancelled when the
gateway stops) leaves no "Future exception was never retrieved" traceback in the log."""

from __future__ import annotations

import asyncio
import gc
import logging

import pytest
from pymodbus.exceptions import ConnectionException

from gateway.modbus.client import _fail_quietly


async def test_an_awaited_request_gets_the_error() -> None:
    future: asyncio.Future[object] = asyncio.get_running_loop().create_future()
    _fail_quietly(future, ConnectionException("connection to x lost"))
    with pytest.raises(ConnectionException, match="connection to x lost"):
        await future


async def test_a_request_nobody_awaits_is_collected_without_a_traceback(
    caplog: pytest.LogCaptureFixture,
) -> None:
    def abandoned(fail: bool) -> None:
        future: asyncio.Future[object] = asyncio.get_running_loop().create_future()
        exc = ConnectionException("connection to x lost")
        if fail:
            _fail_quietly(future, exc)
        else:
            future.set_exception(exc)  # what pymodbus' own hook did: logged when collected

    with caplog.at_level(logging.ERROR, logger="asyncio"):
        abandoned(fail=False)
        gc.collect()
        assert "Future exception was never retrieved" in caplog.text  # the check can fail
        caplog.clear()
        abandoned(fail=True)
        gc.collect()
    assert "never retrieved" not in caplog.text, caplog.text
