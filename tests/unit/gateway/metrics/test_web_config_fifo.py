"""The web config is read without blocking, whatever its path names (issue 33 §6).

The gateway's parser checks that ``web_config`` names a regular file when it reads the
configuration, but ``load_web_config`` reads it again at start and at every reload: swapped
for a named pipe in between, a plain ``read_text`` would wait for a writer and stop the
reload (and with it the poll loop). A device file is never read either.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

from gateway.errors import ConfigError
from gateway.metrics.web_config import load_web_config

#: How long the reader may take to refuse the FIFO before it counts as blocked (a refusal
#: takes microseconds; generous for a busy machine).
BLOCKED_AFTER_S = 10.0


def test_a_fifo_as_the_web_config_is_refused_unopened(tmp_path: Path) -> None:
    fifo = tmp_path / "web.yml"
    os.mkfifo(fifo)
    outcome: list[BaseException | None] = []

    def read() -> None:
        try:
            load_web_config(fifo)
        except BaseException as exc:
            outcome.append(exc)
        else:
            outcome.append(None)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(BLOCKED_AFTER_S)
    blocked = reader.is_alive()
    if blocked:  # a writer lets the blocked open return, so the thread ends and nothing leaks
        with open(fifo, "wb"):
            pass
        reader.join()
    assert not blocked, "load_web_config waited on a named pipe"
    exc = outcome[0]
    assert isinstance(exc, ConfigError)
    assert str(exc) == f"{fifo}: not a regular file; a web config is a file"


def test_a_regular_web_config_still_reads(tmp_path: Path) -> None:
    path = tmp_path / "web.yml"
    path.write_text("http_server_config:\n  headers:\n    X-Frame-Options: DENY\n", encoding="utf-8")
    config = load_web_config(path)
    assert dict(config.headers) == {"X-Frame-Options": "DENY"}
