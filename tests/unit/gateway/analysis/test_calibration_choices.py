"""Issue 31 §6: the calibration's models, objectives and offset modes have one owner each, an
enum; the command line's choices and every check are derived from it."""

from __future__ import annotations

from typing import Any

import click
import pytest

from gateway.analysis import calibration, calibration_result
from gateway.analysis.calibration_result import CalibrationModel, OffsetMode
from gateway.analysis.calibration_writer import calibration_file
from gateway.analysis.objectives import FIT_OBJECTIVES, Objective, check_objective
from gateway.cli.calibrate_cmd import calibrate_cmd
from gateway.keys import choice_of


def _choices(name: str) -> list[str]:
    (option,) = [p for p in calibrate_cmd.params if p.name == name]
    assert isinstance(option.type, click.Choice)
    return [str(c) for c in option.type.choices]


def test_the_command_line_offers_each_enum_value_in_its_spelling() -> None:
    assert _choices("model") == ["physics", "line", "lookup", "curve", "auto"]
    assert _choices("objective") == ["auto", "log-r", "force"]
    assert _choices("force_offset") == ["auto", "fit", "none"]
    assert [m.value for m in CalibrationModel] == _choices("model")
    assert [o.option for o in Objective] == _choices("objective")


def test_no_tuple_copies_of_the_enums_remain() -> None:
    for module in (calibration, calibration_result):
        for name in ("MODELS", "OBJECTIVE_CHOICES", "OFFSET_CHOICES"):
            assert not hasattr(module, name), f"{module.__name__}.{name}"


def test_a_fit_objective_is_an_enum_member_and_auto_is_not_one() -> None:
    assert check_objective("log_r") is Objective.LOG_R
    assert check_objective(Objective.FORCE) is Objective.FORCE
    assert FIT_OBJECTIVES == (Objective.LOG_R, Objective.FORCE)
    with pytest.raises(ValueError, match="objective must be one of log_r, force, got 'auto'"):
        check_objective("auto")


@pytest.mark.parametrize(
    ("kind", "value", "message"),
    [
        (
            Objective,
            "logr",
            "objective: 'logr' is not allowed; did you mean 'log_r'?; allowed: 'auto', 'log_r', 'force'",
        ),
        (OffsetMode, "yes", "objective: 'yes' is not allowed; allowed: 'auto', 'fit', 'none'"),
        (OffsetMode, 1, "objective: 1 is not allowed; allowed: 'auto', 'fit', 'none'"),
        (
            CalibrationModel,
            "phys",
            "objective: 'phys' is not allowed; did you mean 'physics'?; allowed: 'physics', 'line', "
            "'lookup', 'curve', 'auto'",
        ),
    ],
)
def test_a_misspelt_value_names_the_closest_and_every_allowed_one(
    kind: Any, value: object, message: str
) -> None:
    with pytest.raises(ValueError) as exc:
        choice_of(kind, value, "objective")
    assert str(exc.value) == message
    first = next(iter(kind))
    assert choice_of(kind, first.value, "objective") is first
    assert repr(first) == repr(first.value)


def test_the_writer_refuses_a_misspelt_model() -> None:
    with pytest.raises(ValueError, match=r"model: 'phys' is not allowed; did you mean 'physics'\?"):
        calibration_file([], "phys")
