"""Reading a small text file a user names (configuration, profile, calibration, web config,
password file) without ever blocking on it or reading a device.

``read_text_file`` opens the path non-blocking and checks that it is a regular file before
reading: a named pipe (FIFO) with no writer would otherwise hold ``open()`` until a writer
came (stopping the poll loop at a reload, issue 33 §6), and a device such as /dev/zero would
be read without end. Checking the type first and opening afterwards leaves a race (the path
can be swapped in between); checking the opened descriptor does not. Usable by every room,
like ``atomic``.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Final

from .errors import ConfigError

__all__ = ["MAX_FILE_BYTES", "read_text_file"]

#: A configuration, profile or calibration file larger than this is refused unread.
MAX_FILE_BYTES: Final = 4 * 1024 * 1024


def read_text_file(path: Path, what: str) -> str:
    """The UTF-8 text of a regular file of at most ``MAX_FILE_BYTES``; ``ConfigError`` naming
    the file and ``what`` it is otherwise (a device such as /dev/zero is never read, and a named
    pipe is refused, never waited on: the open does not block)."""
    try:
        # O_NONBLOCK: opening a FIFO with no writer would wait for one (stopping the poll loop
        # at a reload); it has no effect on a regular file
        with os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise ConfigError(f"{path}: not a regular file; a {what} is a file")
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    if len(data) > MAX_FILE_BYTES:
        raise ConfigError(
            f"{path}: larger than {MAX_FILE_BYTES // (1024 * 1024)} MiB; too large for a {what}"
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}): a {what} is UTF-8 text") from None
