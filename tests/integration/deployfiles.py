"""Paths of the deployment files and the helpers the deploy tests share."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
PROM_DIR = DEPLOY / "prometheus"
PROM_CONFIG = PROM_DIR / "prometheus.yml"
COMPOSE_PROM_CONFIG = DEPLOY / "container" / "prometheus.yml"
RECORDING_RULES = PROM_DIR / "recording_rules.yml"
ALERTS = PROM_DIR / "alerts.yml"
ALERT_TESTS = PROM_DIR / "tests" / "alerts_test.yml"
DASHBOARD = DEPLOY / "grafana" / "dashboard.json"
DATASOURCES = DEPLOY / "grafana" / "provisioning" / "datasources" / "prometheus.yml"
DASHBOARD_PROVIDERS = DEPLOY / "grafana" / "provisioning" / "dashboards" / "tactile.yml"
K8S = DEPLOY / "kubernetes"
CONTAINER = DEPLOY / "container"
UNIT = DEPLOY / "systemd" / "tactile-gateway.service"

JOB = "tactile-gateway"
METRICS_PORT = 9830


def require_tool(name: str, package: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.fail(
            f"`{name}` is not on PATH. Run `make test`, which installs Debian's "
            f"`{package}` package (apt-get install -y {package}); these tests never skip."
        )
    return path


def run(cmd: list[str], cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=300, check=False)


def load_yaml(path: Path) -> Any:
    with path.open(encoding="utf-8") as fh:
        return yaml.safe_load(fh)
