"""Atomic replacement of a file: readers see either the old or the new content, never a mix.

The new content goes to a temporary file in the same directory (same file system, so the
final ``os.replace`` is an atomic rename), is flushed and fsync'ed, gets its permission bits,
and then replaces the target. The directory is fsync'ed afterwards so that the rename itself
survives a crash. On any failure the temporary file is removed and the target is untouched.

``AtomicFile`` is the one implementation: a file written piece by piece (a record while its
samples arrive) that appears whole at ``commit`` or not at all; ``atomic_write_bytes`` and
``atomic_write_text`` write a whole content through it in one call.
"""

from __future__ import annotations

import contextlib
import io
import os
import stat
import tempfile
from pathlib import Path
from types import TracebackType
from typing import BinaryIO, TextIO

__all__ = ["AtomicFile", "atomic_write_bytes", "atomic_write_text"]


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


class AtomicFile:
    """A file that replaces ``path`` atomically once it is complete.

    Write through ``text`` (UTF-8, line endings exactly as given) or ``write_bytes``, then
    ``commit``: the content is fsync'ed and renamed over ``path``. Until then ``path`` is
    untouched; ``discard`` (or leaving the ``with`` block without ``commit``, by an exception
    or on purpose) removes the temporary file and leaves ``path`` as it was.

    ``mode`` gives the permission bits of the result. Without it an existing file keeps its
    bits, and a new file gets ``0o666`` minus the process umask (what ``open`` would give).
    A symbolic link is followed: the file it points to is replaced and the link stays.
    ``OSError`` when the temporary file cannot be created beside ``path``.
    """

    def __init__(self, path: Path | str, mode: int | None = None) -> None:
        target = Path(path)
        self.path = target.resolve() if target.is_symlink() else target
        self._mode = mode
        fd, tmp_name = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.", suffix=".tmp")
        self._tmp = Path(tmp_name)
        try:
            self._binary: BinaryIO = os.fdopen(fd, "wb")
        except BaseException:
            os.close(fd)
            self._tmp.unlink()
            raise
        # newline="": what is written is what the file holds, "\r\n" included
        self.text: TextIO = io.TextIOWrapper(self._binary, encoding="utf-8", newline="")
        self._open = True

    def write_bytes(self, data: bytes) -> None:
        """Append ``data`` (after anything written through ``text``)."""
        self.text.flush()
        self._binary.write(data)

    def commit(self) -> None:
        """Put the content in place of ``path`` (see the class); the file is closed after."""
        if not self._open:
            raise ValueError(f"{self.path}: this atomic file was already committed or discarded")
        self._open = False
        try:
            self.text.flush()  # and the binary file under it
            os.fsync(self._binary.fileno())
            self.text.close()
            mode = self._mode
            if mode is None:
                try:
                    mode = stat.S_IMODE(self.path.stat().st_mode)
                except FileNotFoundError:
                    mode = 0o666 & ~_current_umask()
            os.chmod(self._tmp, mode)
            os.replace(self._tmp, self.path)
        except BaseException:
            self._remove()
            raise
        _fsync_directory(self.path.parent)

    def discard(self) -> None:
        """Remove the temporary file; ``path`` stays as it was (nothing after ``commit``)."""
        if self._open:
            self._open = False
            self._remove()

    def _remove(self) -> None:
        for handle in (self.text, self._binary):
            with contextlib.suppress(OSError, ValueError):
                handle.close()
        with contextlib.suppress(OSError):
            self._tmp.unlink()

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.discard()


def atomic_write_bytes(path: Path | str, data: bytes, mode: int | None = None) -> None:
    """Replace ``path`` with ``data`` atomically (``AtomicFile`` for ``mode`` and links)."""
    with AtomicFile(path, mode) as out:
        out.write_bytes(data)
        out.commit()


def atomic_write_text(path: Path | str, text: str, mode: int | None = None) -> None:
    """Replace ``path`` with ``text`` (UTF-8, line endings written exactly as given) atomically
    (``AtomicFile`` for ``mode`` and links)."""
    with AtomicFile(path, mode) as out:
        out.text.write(text)
        out.commit()
