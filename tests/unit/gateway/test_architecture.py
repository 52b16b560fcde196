"""The layers of ``gateway/`` import one way only (an import-linter contract, as a test).

model -> modbus -> config -> runtime -> metrics / analysis -> cli, with ``errors`` and
``atomic`` and ``textfile`` usable by all, and ``keys`` (the unknown-key check) by all but ``model``. Only the
CLI may wire the library to the simulator. Every import counts, including those under
``TYPE_CHECKING`` and inside functions; and no modules of ``gateway/`` or ``sim_device/``
import each other round a loop.
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
    "textfile": {"errors"},
    "keys": set(),
    "model": set(),
    "modbus": {"errors", "keys"},
    "config": {"errors", "textfile", "atomic", "keys", "model", "modbus"},
    "runtime": {"errors", "textfile", "keys", "model", "modbus", "config"},
    "metrics": {"errors", "textfile", "keys", "runtime"},
    "web": {"errors", "textfile", "keys", "runtime"},
    "mqtt": {"errors", "textfile", "keys", "config", "runtime"},
    "foxglove": {"errors", "textfile", "keys", "config", "runtime"},
    "analysis": {"errors", "textfile", "atomic", "keys", "model", "config", "runtime"},
    "cli": {
        "errors",
        "atomic",
        "textfile",
        "keys",
        "model",
        "modbus",
        "config",
        "runtime",
        "metrics",
        "mqtt",
        "foxglove",
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


# ------------------------------------------------------------------------- import cycles
SIM_DEVICE = ROOT / "sim_device"


def _module_name(path: Path, root: Path = ROOT) -> str:
    """``gateway/model/__init__.py`` -> ``gateway.model``; ``sim_device/maps.py`` -> ``sim_device.maps``."""
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _import_graph(paths: list[Path], root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the modules of ``paths`` it imports (every import: at module level, inside
    functions, under ``TYPE_CHECKING``). ``from package import name`` counts as an import of
    the submodule ``package.name`` when that is one of ours, else of the package."""
    names = {_module_name(p, root): p for p in paths}
    graph: dict[str, set[str]] = {name: set() for name in names}
    for name, path in names.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    module = ".".join([*anchor, node.module] if node.module else anchor)
                else:
                    module = node.module or ""
                subs = [f"{module}.{a.name}" for a in node.names if f"{module}.{a.name}" in names]
                targets = subs if len(subs) == len(node.names) else [module, *subs]
            for target in targets:
                if target in names and target != name:
                    graph[name].add(target)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in sorted(graph[node]):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component: list[str] = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found)


def test_no_module_import_cycles() -> None:
    """No two modules of ``gateway/`` or ``sim_device/`` import each other, directly or round a
    loop, however the import is hidden (inside a function, under ``TYPE_CHECKING``): a design
    cycle is broken with a factory or loader module above its files, not by deferring an import."""
    paths = sorted([*GATEWAY.rglob("*.py"), *SIM_DEVICE.rglob("*.py")])
    cycles = _cycles(_import_graph(paths))
    assert not cycles, "module import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_checker_sees_hidden_cycles(tmp_path: Path) -> None:
    """A cycle hidden in a function and under ``TYPE_CHECKING`` is found; a one-way chain is not."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("", encoding="utf-8")
    (pkg / "a.py").write_text("def f():\n    from .b import g\n", encoding="utf-8")
    (pkg / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import c\n", encoding="utf-8"
    )
    (pkg / "c.py").write_text("from . import a\n", encoding="utf-8")
    (pkg / "d.py").write_text("from .a import f\nfrom . import c\n", encoding="utf-8")
    graph = _import_graph(sorted(pkg.glob("*.py")), root=tmp_path)
    assert graph["pkg.c"] == {"pkg.a"} and graph["pkg.b"] == {"pkg.c"}
    assert _cycles(graph) == [["pkg.a", "pkg.b", "pkg.c"]]
