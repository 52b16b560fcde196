"""The layers of ``gateway/`` import one way only (an import-linter contract, as a test).

model -> modbus -> config -> runtime -> metrics / analysis -> cli, with ``errors`` and
``atomic`` usable by all. Only the CLI may wire the library to the simulator. Every import
counts, including those under ``TYPE_CHECKING`` and inside functions.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
GATEWAY = ROOT / "gateway"

#: What each room may import of ours (besides itself). Anything else is a violation.
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "atomic": set(),
    "model": set(),
    "modbus": {"errors"},
    "config": {"errors", "atomic", "model", "modbus"},
    "runtime": {"errors", "model", "modbus", "config"},
    "metrics": {"errors", "runtime"},
    "web": {"errors", "runtime"},
    "mqtt": {"errors", "config", "runtime"},
    "analysis": {"errors", "atomic", "model", "config", "runtime"},
    "cli": {
        "errors",
        "atomic",
        "model",
        "modbus",
        "config",
        "runtime",
        "metrics",
        "mqtt",
        "web",
        "analysis",
        "sim_device",
    },
}


def _room(module: str) -> str | None:
    """The room of an absolute module name (``gateway.runtime.bus`` -> ``runtime``)."""
    parts = module.split(".")
    if parts[0] == "sim_device":
        return "sim_device"
    if parts[0] != "gateway" or len(parts) < 2:
        return None
    return parts[1]


def _imports(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """Absolute names of every module ``path`` imports, with line numbers."""
    package = ".".join(path.relative_to(root).with_suffix("").parts)
    if path.name == "__init__.py":
        package = package.rsplit(".", 1)[0] + ".__init__"
    base = package.split(".")[:-1]
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = base[: len(base) - (node.level - 1)]
                module = ".".join([*anchor, node.module] if node.module else anchor)
            else:
                module = node.module or ""
            found.append((node.lineno, module))
            # ``from gateway import model`` imports the room named by the alias
            if module == "gateway":
                found.extend((node.lineno, f"gateway.{a.name}") for a in node.names)
    return found


def _modules() -> list[Path]:
    return sorted(p for p in GATEWAY.rglob("*.py") if p.parent != GATEWAY or p.name != "__init__.py")


def test_every_module_lives_in_a_known_room() -> None:
    rooms = {_room(".".join(p.relative_to(ROOT).with_suffix("").parts)) for p in _modules()}
    assert rooms <= set(ALLOWED), f"modules outside the known rooms: {rooms - set(ALLOWED)}"


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_follow_the_layers(path: Path) -> None:
    own = _room(".".join(path.relative_to(ROOT).with_suffix("").parts))
    assert own is not None
    bad = [
        f"{path.relative_to(ROOT)}:{line} imports {module} ({own} may import {sorted(ALLOWED[own])})"
        for line, module in _imports(path)
        if (room := _room(module)) is not None and room != own and room not in ALLOWED[own]
    ]
    assert not bad, "\n".join(bad)


def test_the_checker_sees_a_violation(tmp_path: Path) -> None:
    """The contract can fail: a relative import two levels up is resolved to its room."""
    fake = tmp_path / "gateway" / "model" / "probe.py"
    fake.parent.mkdir(parents=True)
    fake.write_text("from ..runtime import snapshot\nfrom gateway import metrics\n", encoding="utf-8")
    found = _imports(fake, root=tmp_path)
    assert (1, "gateway.runtime") in found and (2, "gateway.metrics") in found
    assert {_room(m) for _, m in found} - {None, "model"} - ALLOWED["model"] == {"runtime", "metrics"}
