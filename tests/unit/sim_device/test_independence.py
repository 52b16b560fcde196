"""The simulated array is an independent witness: it imports nothing of ``gateway``."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

SIM = Path(__file__).resolve().parents[3] / "sim_device"


def _gateway_imports(path: Path) -> list[str]:
    found: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found += [f"{path.name}:{node.lineno} imports {n}" for n in names if n.split(".")[0] == "gateway"]
    return found


def test_no_sim_device_module_imports_gateway() -> None:
    modules = sorted(SIM.rglob("*.py"))
    assert len(modules) >= 10
    bad = [line for path in modules for line in _gateway_imports(path)]
    assert not bad, "\n".join(bad)


def test_the_scan_sees_a_gateway_import(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import numpy\nfrom gateway.model import SensorModel\nimport gateway\n", encoding="utf-8"
    )
    assert _gateway_imports(probe) == ["probe.py:2 imports gateway.model", "probe.py:3 imports gateway"]


def test_running_the_simulator_loads_no_gateway_module() -> None:
    code = (
        "import sys, sim_device, sim_device.cli;"
        "from sim_device import ArrayConfig, SimArray, record_offline;"
        "a = SimArray(ArrayConfig(scenario='indentation', world_effects=('creep2', 'hysteresis',"
        " 'temperature', 'series_resistance', 'leakage')));"
        "a.advance(30.0); a.input_registers(); a.holding_registers();"
        "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] == 'gateway')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "", f"sim_device pulled in: {out.stdout.strip()}"
