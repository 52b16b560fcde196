"""gateway.model is a pure core: numpy and scipy only."""

from __future__ import annotations

import subprocess
import sys


def test_model_loads_neither_pymodbus_nor_prometheus_client() -> None:
    code = (
        "import sys, gateway.model, gateway.model.model, gateway.model.divider;"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "{'pymodbus', 'prometheus_client', 'click', 'serial', 'matplotlib'});"
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"gateway.model pulled in: {out.stdout.strip()}"
