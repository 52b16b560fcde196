"""Issue 31 §6: one owner for each policy. A copy elsewhere is what these tests catch."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
GATEWAY = ROOT / "gateway"


def _calls(path: Path, names: set[str]) -> list[str]:
    """The calls in ``path`` of a function or method whose name is in ``names``, as file:line."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
            if name in names:
                found.append(f"{path.name}:{node.lineno} {name}")
    return found


def test_only_the_atomic_module_writes_files_atomically() -> None:
    # a temporary file beside the target, fsync'ed and renamed: gateway.atomic.AtomicFile
    found = [
        call
        for path in sorted(GATEWAY.rglob("*.py"))
        if path != GATEWAY / "atomic.py"
        for call in _calls(path, {"mkstemp", "NamedTemporaryFile", "fsync"})
    ]
    assert found == []


def test_the_checker_sees_a_copy(tmp_path: Path) -> None:
    copy = tmp_path / "copy.py"
    copy.write_text("import os, tempfile\nfd, name = tempfile.mkstemp()\nos.fsync(fd)\n")
    assert _calls(copy, {"mkstemp", "fsync"}) == ["copy.py:2 mkstemp", "copy.py:3 fsync"]
