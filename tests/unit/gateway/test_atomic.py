"""``gateway.atomic``: atomic replacement of text files."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from gateway.atomic import AtomicFile, atomic_write_bytes, atomic_write_text


@pytest.fixture
def umask_022() -> Iterator[None]:
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_new_file_gets_content_and_umask_mode(tmp_path: Path, umask_022: None) -> None:
    target = tmp_path / "new.toml"
    atomic_write_text(target, "a = 1\n")
    assert target.read_text() == "a = 1\n"
    assert _mode(target) == 0o644


def test_existing_file_keeps_its_mode(tmp_path: Path) -> None:
    target = tmp_path / "gateway.toml"
    target.write_text("old\n")
    target.chmod(0o640)
    atomic_write_text(target, "new\n")
    assert target.read_text() == "new\n"
    assert _mode(target) == 0o640


def test_explicit_mode_wins(tmp_path: Path) -> None:
    target = tmp_path / "secret.yml"
    target.write_text("old\n")
    target.chmod(0o644)
    atomic_write_text(target, "new\n", mode=0o600)
    assert _mode(target) == 0o600


def test_text_is_written_exactly(tmp_path: Path) -> None:
    target = tmp_path / "t.toml"
    text = 'name = "Kraftsensor µ"\r\nx = 1\n\n'
    atomic_write_text(target, text)
    assert target.read_bytes() == text.encode("utf-8")


def test_no_temporary_files_are_left(tmp_path: Path) -> None:
    target = tmp_path / "gateway.toml"
    for i in range(3):
        atomic_write_text(target, f"n = {i}\n")
    assert [p.name for p in tmp_path.iterdir()] == ["gateway.toml"]


def test_failure_leaves_the_target_and_no_temporary_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "gateway.toml"
    target.write_text("original\n")

    def broken_replace(src: object, dst: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="No space left"):
        atomic_write_text(target, "replacement\n")
    assert target.read_text() == "original\n"
    assert [p.name for p in tmp_path.iterdir()] == ["gateway.toml"]


def test_content_is_fsynced_before_the_rename(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    events: list[str] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append("fsync")
        real_fsync(fd)

    def replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        events.append("replace")
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    atomic_write_text(tmp_path / "f.txt", "x\n")
    assert "replace" in events
    assert events.index("fsync") < events.index("replace")


def test_symlink_is_followed_and_kept(tmp_path: Path) -> None:
    real = tmp_path / "real.toml"
    real.write_text("old\n")
    link = tmp_path / "link.toml"
    link.symlink_to(real)
    atomic_write_text(link, "new\n")
    assert link.is_symlink()
    assert real.read_text() == "new\n"


def test_bytes_variant(tmp_path: Path) -> None:
    target = tmp_path / "b.bin"
    atomic_write_bytes(target, b"\x00\x01\xff")
    assert target.read_bytes() == b"\x00\x01\xff"


def test_a_streamed_file_appears_whole_at_commit_and_not_before(tmp_path: Path) -> None:
    target = tmp_path / "rec.csv"
    target.write_text("old record\n")
    with AtomicFile(target) as out:
        out.text.write("time_s,resistance_ohm\r\n")
        out.text.flush()  # flushed pieces are still not the target's
        assert target.read_text() == "old record\n"
        out.write_bytes(b"0.0,inf\n")
        out.text.write("0.5,1000.0\n")
        out.commit()
    assert target.read_bytes() == b"time_s,resistance_ohm\r\n0.0,inf\n0.5,1000.0\n"
    assert [p.name for p in tmp_path.iterdir()] == ["rec.csv"]


def test_a_discarded_or_abandoned_file_leaves_the_target_and_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "rec.csv"
    target.write_text("old record\n")
    with AtomicFile(target) as out:
        out.text.write("half a record")
        out.discard()
    with pytest.raises(KeyboardInterrupt), AtomicFile(target) as out:
        out.text.write("half a record")
        raise KeyboardInterrupt
    with AtomicFile(tmp_path / "new.csv") as out:
        out.text.write("never committed")
    assert target.read_text() == "old record\n"
    assert [p.name for p in tmp_path.iterdir()] == ["rec.csv"]


def test_a_file_is_committed_once(tmp_path: Path) -> None:
    out = AtomicFile(tmp_path / "a.txt")
    out.commit()
    with pytest.raises(ValueError, match="already committed or discarded"):
        out.commit()
    assert (tmp_path / "a.txt").read_bytes() == b""
