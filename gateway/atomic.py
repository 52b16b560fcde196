"""Atomic replacement of a text file: readers see either the old or the new content, never a mix.

The new content goes to a temporary file in the same directory (same file system, so the
final ``os.replace`` is an atomic rename), is flushed and fsync'ed, gets its permission bits,
and then replaces the target. The directory is fsync'ed afterwards so that the rename itself
survives a crash. On any failure the temporary file is removed and the target is untouched.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes", "atomic_write_text"]


def _current_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync_directory(directory: Path) -> None:
    """Persist a rename in ``directory``; not every platform can open a directory."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path | str, data: bytes, mode: int | None = None) -> None:
    """Replace ``path`` with ``data`` atomically.

    ``mode`` gives the permission bits of the result. Without it an existing file keeps its
    bits, and a new file gets ``0o666`` minus the process umask (what ``open`` would give).
    A symbolic link is followed: the file it points to is replaced and the link stays.
    """
    target = Path(path)
    if target.is_symlink():
        target = target.resolve()
    if mode is None:
        try:
            mode = stat.S_IMODE(target.stat().st_mode)
        except FileNotFoundError:
            mode = 0o666 & ~_current_umask()
    directory = target.parent
    fd, tmp_name = tempfile.mkstemp(dir=directory, prefix=f".{target.name}.", suffix=".tmp")
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync_directory(directory)


def atomic_write_text(path: Path | str, text: str, mode: int | None = None) -> None:
    """Replace ``path`` with ``text`` (UTF-8, line endings written exactly as given) atomically.

    See ``atomic_write_bytes`` for ``mode`` and symbolic links.
    """
    atomic_write_bytes(path, text.encode("utf-8"), mode)
