"""cell.cli: the documented exit codes, one line of reason on failure, and every subcommand registered."""

from __future__ import annotations

import argparse
import json

import pytest

from calibration.errors import CalibrationError
from cell import cli
from cell.errors import ConfigError, SafetyViolation
from drivers.errors import ConnectionLost
from perception.errors import BadCapture, NoSeamFound


def test_errors_map_to_the_documented_exit_codes() -> None:
    assert (cli.EXIT_OK, cli.EXIT_FAILURE, cli.EXIT_BAD_INPUT, cli.EXIT_NO_SEAM, cli.EXIT_INTERRUPTED) == (
        0,
        1,
        2,
        3,
        130,
    )
    assert cli.exit_code_for(NoSeamFound("nothing")) == 3
    assert cli.exit_code_for(BadCapture("bad")) == cli.exit_code_for(ConfigError("bad")) == 2
    for err in (SafetyViolation("x"), CalibrationError("x"), ConnectionLost("x"), RuntimeError("x")):
        assert cli.exit_code_for(err) == 1


def test_every_command_module_registers_its_subcommand() -> None:
    parser = cli.build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    names = set(sub.choices)
    assert {"simulate", "evaluate", "detect", "bench", "sim", "calibrate", "run", "serve", "schema", "export"} <= names


def test_a_weldcell_error_is_one_line_on_stderr_with_its_exit_code(
    tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "nothing-here"
    assert cli.main(["evaluate", str(missing), str(missing / "seams.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("weldcell evaluate: ")


def test_schema_prints_the_seams_json_schema(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["schema", "seams"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema["type"] == "object" and "seams" in schema["properties"]
