"""``tactile-gateway model ...`` through click's runner."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from gateway.cli import main


def test_eval_json_has_exactly_the_contract_keys() -> None:
    result = CliRunner().invoke(main, ["model", "eval", "--force", "0.5,2,5", "--time", "0,600", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)
    assert len(rows) == 6
    assert all(
        set(r) == {"force_n", "time_s", "resistance_ohm", "contact_ohm", "polymer_ohm", "strain"}
        for r in rows
    )
    first = rows[0]
    assert (first["force_n"], first["time_s"]) == (0.5, 0.0)
    assert first["resistance_ohm"] == pytest.approx(138.5e3, rel=1e-3)
    assert rows[-1]["resistance_ohm"] < rows[-2]["resistance_ohm"]


def test_eval_param_override_and_effects() -> None:
    base = CliRunner().invoke(main, ["model", "eval", "--force", "2", "--effects", "tunneling", "--json"])
    over = CliRunner().invoke(
        main,
        ["model", "eval", "--force", "2", "--effects", "tunneling", "--param", "r0_ohm=100000", "--json"],
    )
    r_base = json.loads(base.stdout)[0]
    r_over = json.loads(over.stdout)[0]
    assert r_base["contact_ohm"] == 0.0
    assert r_over["resistance_ohm"] == pytest.approx(r_base["resistance_ohm"] / 2, rel=1e-12)


def test_invert_json() -> None:
    result = CliRunner().invoke(main, ["model", "invert", "--resistance", "9980,46900,1e9,0,inf", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)
    assert [r["status"] for r in rows] == ["ok", "ok", "no_contact", "invalid", "no_contact"]
    assert rows[0]["force_n"] == pytest.approx(5.0, abs=0.005)
    assert rows[1]["force_n"] == pytest.approx(2.0, abs=0.005)
    assert rows[3]["force_n"] is None


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["model", "eval", "--force", "1", "--effects", "contcat"], "did you mean 'contact'"),
        (["model", "eval", "--force", "x"], "'x' is not a number"),
        (["model", "eval", "--force", "-1"], "forces must be in [0, 1e+06] N"),
        (["model", "eval", "--force", "1e300"], "forces must be in [0, 1e+06] N"),
        (["model", "invert", "--resistance", "-5"], "-5.0 ohm: a resistance is >= 0 ohm"),
        (["model", "invert", "--resistance", "nan"], "nan ohm: a resistance is >= 0 ohm"),
        (["model", "eval", "--force", "1", "--param", "r0_ohm=-5"], "outside its allowed range"),
        (["model", "eval", "--force", "1", "--param", "r0"], "is not NAME=VALUE"),
        (["model", "invert", "--resistance", "1e4", "--param", "r0_ohms=5"], "did you mean 'r0_ohm'"),
    ],
)
def test_bad_input_is_a_clear_usage_error(args: list[str], message: str) -> None:
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2
    assert message in result.output
    assert "Traceback" not in result.output


def test_plot_writes_the_paper_figures(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["model", "plot", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["fig10_surface.png", "fig5_force_resistance.png", "fig9b_resistance_time.png"]
    for p in tmp_path.iterdir():
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert p.stat().st_size > 10_000


def test_eval_table_shows_an_open_contact_as_inf() -> None:
    """At 0 N the contact is open (eq. 12): R = inf; the table prints the word, no traceback."""
    result = CliRunner().invoke(main, ["model", "eval", "--force", "0"])
    assert result.exit_code == 0, result.output
    row = result.stdout.splitlines()[1].split()
    assert row[:3] == ["0", "0", "inf"] and row[4] == "200000"  # polymer: r0 at zero strain


def test_eval_of_a_huge_force_prints_no_numpy_warning() -> None:
    result = CliRunner().invoke(main, ["model", "eval", "--force", "1e6", "--json"])
    assert result.exit_code == 0 and "RuntimeWarning" not in result.output
    assert json.loads(result.stdout)[0]["force_n"] == 1e6


def test_plot_where_no_folder_can_be_made_is_one_line(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder\n")
    result = CliRunner().invoke(main, ["model", "plot", "--out", str(blocker / "figures")])
    assert result.exit_code == 1 and "cannot write the figures" in result.output, result.output
    assert "Traceback" not in result.output
