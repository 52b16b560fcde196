"""Checks of the operator-facing deployment files under deploy/.

These run the real tools: ``promtool`` (Debian package ``prometheus``) and
``systemd-analyze`` (Debian package ``systemd``). ``make test`` installs both. A missing
tool is a test failure, never a skip: a green run must mean the files were checked.
"""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from deployfiles import (
    ALERT_TESTS,
    ALERTS,
    COMPOSE_PROM_CONFIG,
    CONTAINER,
    DASHBOARD,
    DASHBOARD_PROVIDERS,
    DATASOURCES,
    JOB,
    METRICS_PORT,
    PROM_CONFIG,
    RECORDING_RULES,
    load_yaml,
    require_tool,
    run,
)

# The gateway's metrics, as documented. Histograms are queried through their series.
GAUGES_AND_COUNTERS = frozenset(
    {
        "tactile_force_newtons",
        "tactile_force_static_newtons",
        "tactile_resistance_ohms",
        "tactile_channel_status",
        "tactile_device_up",
        "tactile_last_poll_success_timestamp_seconds",
        "tactile_poll_interval_seconds",
        "tactile_reads_total",
        "tactile_read_errors_total",
        "tactile_array_total_force_newtons",
        "tactile_array_center_of_pressure_mm",
        "tactile_array_contact_area_square_mm",
        "tactile_channel_position_mm",
    }
)
HISTOGRAMS = frozenset({"tactile_poll_duration_seconds"})
GATEWAY_SERIES = GAUGES_AND_COUNTERS | {
    f"{h}{suffix}" for h in HISTOGRAMS for suffix in ("_bucket", "_sum", "_count")
}

PROMQL_KEYWORDS = frozenset(
    {"by", "without", "on", "ignoring", "group_left", "group_right", "bool", "offset"}
    | {"and", "or", "unless", "atan2", "inf", "nan"}
)


def promtool() -> str:
    return require_tool("promtool", "prometheus")


def alert_rules() -> list[dict]:
    return [r for g in load_yaml(ALERTS)["groups"] for r in g["rules"] if "alert" in r]


def recording_rules() -> list[dict]:
    return [r for g in load_yaml(RECORDING_RULES)["groups"] for r in g["rules"] if "record" in r]


def series_names(expr: str) -> set[str]:
    """Metric names a PromQL expression selects (good enough for our own expressions).

    Strings, label matchers, ranges and grouping clauses are removed first; what is left
    that looks like an identifier and is neither a function call nor a keyword is a
    metric name.
    """
    text = re.sub(r'"(?:[^"\\]|\\.)*"', '""', expr)
    text = re.sub(r"\{[^{}]*\}", " ", text)
    text = re.sub(r"\[[^\[\]]*\]", " ", text)
    text = re.sub(r"\b(?:by|without|on|ignoring|group_left|group_right)\s*\([^()]*\)", " ", text)
    names = set()
    for match in re.finditer(r"(?<![\w.])([A-Za-z_:][A-Za-z0-9_:]*)(\s*\()?", text):
        name, call = match.group(1), match.group(2)
        if call or name.lower() in PROMQL_KEYWORDS:
            continue
        names.add(name)
    return names


def test_series_names_parser() -> None:
    expr = (
        'sum by (job, device) (rate(tactile_reads_total{device="a",status=~"x|y"}[5m]))'
        " / on (device) group_left (axis) max(tactile_channel_position_mm) > 0.8 * up"
    )
    assert series_names(expr) == {"tactile_reads_total", "tactile_channel_position_mm", "up"}
    assert series_names("histogram_quantile(0.99, sum by (le) (rate(x_bucket[1m])))") == {"x_bucket"}
    assert series_names('label_replace(a, "axis", "force", "", "") or b') == {"a", "b"}


# --------------------------------------------------------------------------- promtool


@pytest.mark.parametrize("config", [PROM_CONFIG, COMPOSE_PROM_CONFIG], ids=["host", "compose"])
def test_promtool_check_config(config: Path) -> None:
    result = run([promtool(), "check", "config", str(config)], cwd=config.parent)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "SUCCESS" in result.stdout + result.stderr


@pytest.mark.parametrize("rules", [RECORDING_RULES, ALERTS], ids=["recording", "alerts"])
def test_promtool_check_rules(rules: Path) -> None:
    result = run([promtool(), "check", "rules", str(rules)])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "SUCCESS" in result.stdout + result.stderr


def test_promtool_test_rules() -> None:
    result = run([promtool(), "test", "rules", str(ALERT_TESTS)], cwd=ALERT_TESTS.parent)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "SUCCESS" in result.stdout + result.stderr


def test_promtool_rule_tests_catch_a_broken_alert(tmp_path: Path) -> None:
    """The rule tests must fail when an alert changes (here: a longer `for:`)."""
    (tmp_path / "tests").mkdir()
    shutil.copy(ALERT_TESTS, tmp_path / "tests" / ALERT_TESTS.name)
    shutil.copy(RECORDING_RULES, tmp_path / RECORDING_RULES.name)
    text = ALERTS.read_text(encoding="utf-8")
    broken = re.sub(r"(alert: TactileDeviceDown\n\s+expr: .*\n\s+for: )30s", r"\g<1>10m", text, count=1)
    assert broken != text, "could not find TactileDeviceDown's `for: 30s` to alter"
    (tmp_path / ALERTS.name).write_text(broken, encoding="utf-8")
    result = run([promtool(), "test", "rules", f"tests/{ALERT_TESTS.name}"], cwd=tmp_path)
    assert result.returncode != 0, result.stdout + result.stderr
    assert "TactileDeviceDown" in result.stdout + result.stderr


# ------------------------------------------------------------------ alerts and rules


def test_expected_alerts_are_defined() -> None:
    expected = {
        "TactileDeviceDown": ("tactile_device_up", "30s"),
        "TactileSamplesStale": ("tactile_last_poll_success_timestamp_seconds", "1m"),
        "TactileChannelOpen": ('status="open"', "1m"),
        "TactileChannelShorted": ('status="short"', "1m"),
        "TactileChannelSaturated": ('status="saturated"', "5m"),
        "TactileReadErrorRatioHigh": ("tactile_read_errors_total", "5m"),
        "TactilePollDurationNearInterval": ("tactile_poll_interval_seconds", "10m"),
    }
    rules = {r["alert"]: r for r in alert_rules()}
    for name, (fragment, duration) in expected.items():
        assert name in rules, f"alert {name} missing from {ALERTS}"
        assert fragment in rules[name]["expr"], (name, rules[name]["expr"])
        assert rules[name].get("for") == duration, (name, rules[name].get("for"))


def test_every_alert_has_summary_description_and_runbook() -> None:
    rules = alert_rules()
    assert rules
    for rule in rules:
        annotations = rule.get("annotations", {})
        for key in ("summary", "description", "runbook"):
            assert str(annotations.get(key, "")).strip(), f"{rule['alert']}: no {key}"
        runbook = annotations["runbook"]
        assert "Check:" in runbook and "Do:" in runbook, f"{rule['alert']}: runbook sections"
        assert rule.get("labels", {}).get("severity") in {"critical", "warning", "info"}


def test_rule_tests_show_every_alert_firing_and_not_firing() -> None:
    defined = {r["alert"] for r in alert_rules()}
    firing: set[str] = set()
    silent: set[str] = set()
    for case in load_yaml(ALERT_TESTS)["tests"]:
        for check in case.get("alert_rule_test", []):
            name = check["alertname"]
            assert name in defined, f"test for unknown alert {name}"
            (firing if check.get("exp_alerts") else silent).add(name)
    assert defined - firing == set(), f"never shown firing: {sorted(defined - firing)}"
    assert defined - silent == set(), f"never shown not firing: {sorted(defined - silent)}"


def test_rule_tests_check_recording_rules() -> None:
    recorded = {r["record"] for r in recording_rules()}
    checked = set()
    for case in load_yaml(ALERT_TESTS)["tests"]:
        for check in case.get("promql_expr_test", []):
            assert check.get("exp_samples"), check
            checked |= series_names(check["expr"]) & recorded
    assert checked, "no promql_expr_test checks a recording rule"


def test_rule_files_use_only_gateway_metrics() -> None:
    recorded = {r["record"] for r in recording_rules()}
    for rule in recording_rules() + alert_rules():
        names = series_names(rule["expr"])
        assert names, rule
        unknown = names - GATEWAY_SERIES - recorded - {"up"}
        assert not unknown, f"{rule.get('alert') or rule.get('record')}: unknown {unknown}"


def test_prometheus_config_scrapes_the_gateway() -> None:
    config = load_yaml(PROM_CONFIG)
    jobs = {job["job_name"]: job for job in config["scrape_configs"]}
    job = jobs[JOB]
    assert job.get("scrape_interval", config["global"]["scrape_interval"]) == "5s"
    assert job.get("metrics_path", "/metrics") == "/metrics"
    targets = [t for sc in job["static_configs"] for t in sc["targets"]]
    assert targets == [f"127.0.0.1:{METRICS_PORT}"]
    rule_files = config["rule_files"]
    assert {Path(f).name for f in rule_files} == {RECORDING_RULES.name, ALERTS.name}
    for rule_file in rule_files:
        assert not Path(rule_file).is_absolute(), rule_file
        assert (PROM_CONFIG.parent / rule_file).is_file(), rule_file


def test_compose_prometheus_config_differs_only_in_target() -> None:
    host, compose = load_yaml(PROM_CONFIG), load_yaml(COMPOSE_PROM_CONFIG)
    assert host["global"] == compose["global"]
    assert [(COMPOSE_PROM_CONFIG.parent / f).resolve() for f in compose["rule_files"]] == [
        (PROM_CONFIG.parent / f).resolve() for f in host["rule_files"]
    ]
    host_job, compose_job = host["scrape_configs"][0], compose["scrape_configs"][0]
    assert compose_job["static_configs"][0]["targets"] == [f"gateway:{METRICS_PORT}"]
    strip = {"static_configs"}
    assert {k: v for k, v in host_job.items() if k not in strip} == {
        k: v for k, v in compose_job.items() if k not in strip
    }


# ---------------------------------------------------------------------------- grafana


def dashboard_panels(panels: list[dict]) -> Iterator[dict]:
    for panel in panels:
        yield panel
        yield from dashboard_panels(panel.get("panels", []))


def dashboard_exprs() -> list[tuple[str, str]]:
    dash = json.loads(DASHBOARD.read_text(encoding="utf-8"))
    exprs = []
    for panel in dashboard_panels(dash["panels"]):
        for target in panel.get("targets", []):
            exprs.append((panel["title"], target["expr"]))
    return exprs


def grafana_to_promql(expr: str) -> str:
    expr = re.sub(r"\$__(rate_interval|interval|range)\b", "1m", expr)
    return re.sub(r"\$\{?device\}?", "array1", expr)


def test_dashboard_uses_only_gateway_metrics() -> None:
    exprs = dashboard_exprs()
    assert len(exprs) >= 10
    used: set[str] = set()
    for title, expr in exprs:
        names = series_names(grafana_to_promql(expr))
        assert names, f"{title}: no metric in {expr!r}"
        assert names <= GATEWAY_SERIES, f"{title}: unknown metrics {names - GATEWAY_SERIES}"
        used |= names
    dash = json.loads(DASHBOARD.read_text(encoding="utf-8"))
    for variable in dash["templating"]["list"]:
        query = variable["query"]["query"] if isinstance(variable["query"], dict) else ""
        match = re.fullmatch(r"label_values\((\w+),\s*(\w+)\)", query)
        assert match, query
        assert match.group(1) in GATEWAY_SERIES
    for needed in (
        "tactile_channel_position_mm",
        "tactile_force_newtons",
        "tactile_array_total_force_newtons",
        "tactile_array_center_of_pressure_mm",
        "tactile_device_up",
        "tactile_read_errors_total",
        "tactile_reads_total",
        "tactile_poll_duration_seconds_bucket",
    ):
        assert needed in used, f"dashboard does not show {needed}"


def test_dashboard_has_positioned_force_map() -> None:
    dash = json.loads(DASHBOARD.read_text(encoding="utf-8"))
    maps = [
        p
        for p in dashboard_panels(dash["panels"])
        if p["type"] == "xychart"
        and any("tactile_channel_position_mm" in t["expr"] for t in p["targets"])
        and any("tactile_force_newtons" in t["expr"] for t in p["targets"])
    ]
    assert len(maps) == 1
    (series,) = maps[0]["options"]["series"]
    assert {series[k]["matcher"]["options"] for k in ("x", "y", "color")} == {"x", "y", "force"}


def test_dashboard_expressions_are_valid_promql(tmp_path: Path) -> None:
    rules = [
        {"record": f"dashboard:expr_{i}", "expr": grafana_to_promql(expr)}
        for i, (_, expr) in enumerate(dashboard_exprs())
    ]
    rule_file = tmp_path / "dashboard_exprs.yml"
    rule_file.write_text(yaml.safe_dump({"groups": [{"name": "dash", "rules": rules}]}))
    result = run([promtool(), "check", "rules", str(rule_file)])
    assert result.returncode == 0, result.stdout + result.stderr


def test_grafana_provisioning_matches_dashboard() -> None:
    datasources = load_yaml(DATASOURCES)["datasources"]
    assert [d["type"] for d in datasources] == ["prometheus"]
    uid = datasources[0]["uid"]
    dash = json.loads(DASHBOARD.read_text(encoding="utf-8"))
    for panel in dashboard_panels(dash["panels"]):
        if panel["type"] == "row":
            continue
        assert panel["datasource"]["uid"] == uid, panel["title"]
        for target in panel["targets"]:
            assert target["datasource"]["uid"] == uid, panel["title"]
    (provider,) = load_yaml(DASHBOARD_PROVIDERS)["providers"]
    compose = load_yaml(CONTAINER / "compose.yaml")
    mounts = compose["services"]["grafana"]["volumes"]
    dashboard_mount = next(m for m in mounts if m.split(":")[0].endswith("dashboard.json"))
    assert Path(dashboard_mount.split(":")[1]).parent == Path(provider["options"]["path"])


# ------------------------------------------------------------------------- kubernetes
