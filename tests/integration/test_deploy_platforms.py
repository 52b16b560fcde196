"""Checks of the deployment files for the platforms: Kubernetes, the container stack, systemd.

These run the real tools where there is one (``systemd-analyze``, Debian package ``systemd``;
``make test`` installs it). A missing tool is a test failure, never a skip. The Prometheus
rules, configuration and Grafana dashboard are checked in ``test_deploy_prometheus.py``.
"""

from __future__ import annotations

import re
import shutil
import tomllib
from pathlib import Path

import yaml
from deployfiles import CONTAINER, JOB, K8S, METRICS_PORT, UNIT, load_yaml, require_tool, run


def k8s_docs() -> dict[str, dict]:
    docs = {}
    for path in sorted(K8S.glob("*.yaml")):
        for doc in yaml.safe_load_all(path.read_text(encoding="utf-8")):
            docs[doc["kind"]] = doc
    return docs


def test_kustomization_lists_all_manifests() -> None:
    kustomization = load_yaml(K8S / "kustomization.yaml")
    resources = set(kustomization["resources"])
    assert resources == {
        "deployment.yaml",
        "service.yaml",
        "configmap.yaml",
        "servicemonitor.yaml",
    }
    for resource in resources:
        assert (K8S / resource).is_file(), resource


def test_deployment_is_locked_down() -> None:
    deployment = k8s_docs()["Deployment"]
    assert deployment["spec"]["replicas"] == 1
    assert deployment["spec"]["strategy"]["type"] == "Recreate"
    pod = deployment["spec"]["template"]["spec"]
    assert pod["securityContext"]["runAsNonRoot"] is True
    assert pod["securityContext"]["runAsUser"] != 0
    assert pod["automountServiceAccountToken"] is False
    (container,) = pod["containers"]
    sc = container["securityContext"]
    assert sc["runAsNonRoot"] is True
    assert sc["readOnlyRootFilesystem"] is True
    assert sc["allowPrivilegeEscalation"] is False
    assert sc["capabilities"]["drop"] == ["ALL"]
    assert "add" not in sc["capabilities"]
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    assert ports == {"metrics": METRICS_PORT}
    for probe in ("livenessProbe", "readinessProbe"):
        http = container[probe]["httpGet"]
        assert http["path"] == "/metrics", probe
        assert http["port"] in ("metrics", METRICS_PORT), probe
    for kind in ("requests", "limits"):
        assert {"cpu", "memory"} <= set(container["resources"][kind]), kind
    mounts = {m["mountPath"]: m for m in container["volumeMounts"]}
    assert mounts["/etc/tactile-gateway"]["readOnly"] is True
    assert container["args"] == ["run", "-c", "/etc/tactile-gateway/gateway.toml"]


def test_configmap_holds_a_valid_gateway_config() -> None:
    docs = k8s_docs()
    configmap = docs["ConfigMap"]
    volumes = docs["Deployment"]["spec"]["template"]["spec"]["volumes"]
    assert {"name": configmap["metadata"]["name"]} == {
        "name": next(v["configMap"]["name"] for v in volumes if "configMap" in v)
    }
    config = tomllib.loads(configmap["data"]["gateway.toml"])
    assert config["metrics"]["address"] == f"0.0.0.0:{METRICS_PORT}"
    assert config["bus"] and all(bus["device"] for bus in config["bus"])


def test_service_and_servicemonitor_scrape_metrics() -> None:
    docs = k8s_docs()
    service, monitor = docs["Service"], docs["ServiceMonitor"]
    pod_labels = docs["Deployment"]["spec"]["template"]["metadata"]["labels"]
    assert service["spec"]["selector"].items() <= pod_labels.items()
    (port,) = service["spec"]["ports"]
    assert (port["name"], port["port"]) == ("metrics", METRICS_PORT)
    assert monitor["apiVersion"] == "monitoring.coreos.com/v1"
    assert monitor["spec"]["selector"]["matchLabels"].items() <= service["metadata"]["labels"].items()
    assert service["metadata"]["labels"][monitor["spec"]["jobLabel"]] == JOB
    (endpoint,) = monitor["spec"]["endpoints"]
    assert (endpoint["port"], endpoint["path"]) == ("metrics", "/metrics")


# -------------------------------------------------------------------------- container


def test_compose_stack_is_wired_together() -> None:
    compose = load_yaml(CONTAINER / "compose.yaml")
    services = compose["services"]
    assert set(services) == {"sim", "gateway", "prometheus", "grafana", "mosquitto"}
    assert services["sim"]["entrypoint"] == ["tactile-sim"]
    assert services["sim"]["command"][:3] == ["run", "--tcp", "0.0.0.0:5020"]
    assert "./gateway.toml:/etc/tactile-gateway/gateway.toml:ro" in services["gateway"]["volumes"]
    for name, service in services.items():
        for volume in service.get("volumes", []):
            source = volume.split(":")[0]
            if source.startswith("."):
                assert (CONTAINER / source).exists(), f"{name}: {source} does not exist"
    prometheus_sources = [v.split(":")[0] for v in services["prometheus"]["volumes"]]
    assert "../prometheus" in prometheus_sources
    config = tomllib.loads((CONTAINER / "gateway.toml").read_text(encoding="utf-8"))
    assert config["metrics"]["address"] == f"0.0.0.0:{METRICS_PORT}"
    (bus,) = config["bus"]
    assert (bus["kind"], bus["host"], bus["port"]) == ("tcp", "sim", 5020)


def test_dockerfile_builds_small_non_root_image() -> None:
    text = (CONTAINER / "Dockerfile").read_text(encoding="utf-8")
    assert "python:3.11-slim" in text
    assert len(re.findall(r"^FROM ", text, flags=re.M)) >= 2, "not multi-stage"
    (user,) = re.findall(r"^USER (\S+)", text, flags=re.M)
    assert user.split(":")[0] not in {"root", "0"}
    assert re.search(rf"^EXPOSE {METRICS_PORT}$", text, flags=re.M)
    healthcheck = " ".join(re.findall(r"^HEALTHCHECK.*(?:\n\s+.*)*", text, flags=re.M))
    assert "urllib" in healthcheck and f"127.0.0.1:{METRICS_PORT}/metrics" in healthcheck
    assert "curl" not in healthcheck


# ---------------------------------------------------------------------------- systemd


def unit_entries(text: str) -> dict[str, list[tuple[str, str]]]:
    sections: dict[str, list[tuple[str, str]]] = {}
    current = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], [])
            continue
        assert current is not None, f"entry outside a section: {line}"
        key, sep, value = line.partition("=")
        assert sep, f"not a key=value line: {line}"
        current.append((key.strip(), value.strip()))
    return sections


def test_systemd_unit_is_hardened() -> None:
    service = unit_entries(UNIT.read_text(encoding="utf-8"))["Service"]
    values: dict[str, list[str]] = {}
    for key, value in service:
        values.setdefault(key, []).append(value)

    def single(key: str) -> str:
        assert key in values, f"{key} missing"
        return values[key][-1]

    assert single("DynamicUser") == "no"
    assert single("User") == "tactile"
    assert single("Group") == "tactile"
    assert "dialout" in single("SupplementaryGroups").split()
    assert single("NoNewPrivileges") == "yes"
    assert single("ProtectSystem") == "strict"
    assert single("ProtectHome") == "yes"
    assert single("PrivateTmp") == "yes"
    assert single("CapabilityBoundingSet") == ""
    assert "/etc/tactile-gateway" in " ".join(values["ReadOnlyPaths"]).split()
    assert set(single("RestrictAddressFamilies").split()) == {"AF_INET", "AF_INET6", "AF_UNIX"}
    assert single("Restart") == "on-failure"
    assert single("ExecReload") == "/bin/kill -HUP $MAINPID"
    assert single("ExecStart").endswith(" run -c /etc/tactile-gateway/gateway.toml")
    assert single("ExecStart").split()[0].endswith("/tactile-gateway")
    assert "PrivateDevices" not in values, "would hide the serial ports"
    assert "PrivateUsers" not in values, "would unmap the dialout group"


def verifiable_unit_copy(tmp_path: Path) -> Path:
    true_binary = shutil.which("true")
    assert true_binary, "no `true` binary on PATH"
    text = UNIT.read_text(encoding="utf-8")
    text, count = re.subn(r"^ExecStart=\S+", f"ExecStart={true_binary}", text, flags=re.M)
    assert count == 1
    copy = tmp_path / UNIT.name
    copy.write_text(text, encoding="utf-8")
    return copy


def test_systemd_analyze_verify(tmp_path: Path) -> None:
    tool = require_tool("systemd-analyze", "systemd")
    copy = verifiable_unit_copy(tmp_path)
    result = run([tool, "verify", str(copy)], cwd=tmp_path)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    # verify exits 0 on unknown keys and bad values, so its warnings must be checked too
    complaints = [line for line in output.splitlines() if UNIT.name in line]
    assert complaints == [], output


def test_systemd_analyze_security_exposure(tmp_path: Path) -> None:
    tool = require_tool("systemd-analyze", "systemd")
    copy = verifiable_unit_copy(tmp_path)
    result = run([tool, "security", "--offline=yes", "--no-pager", str(copy)], cwd=tmp_path)
    output = result.stdout + result.stderr
    match = re.search(r"Overall exposure level for \S+: ([0-9.]+)", output)
    assert match, output
    # 1.5 with systemd 252 (Debian 12); dropping e.g. SystemCallFilter= gives 1.9.
    assert float(match.group(1)) <= 1.7, output
