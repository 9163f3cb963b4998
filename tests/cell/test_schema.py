"""``weldcell schema`` (cell/commands/schema.py): the printed schema is the model's, --check reads every file and
stops at the first that cannot be read or does not conform, naming it. (tests/perception/test_seams_schema.py
checks the schema's content and each kind of non-conforming file.)"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cell.cli import main
from perception.seams import write_seams_json
from perception.seams_schema import seams_json_schema
from tests.perception.test_seams_schema import _result

ON_PURPOSE = "invalid-on-purpose"  # the suite-wide seams.json check skips such folders (tests/conftest.py)


def test_the_schema_printed_is_the_models_as_indented_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema", "seams"]) == 0
    out = capsys.readouterr().out
    assert out == json.dumps(seams_json_schema(), indent=2) + "\n"


def test_every_file_checked_says_ok_on_a_line_of_its_own(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = write_seams_json(_result(), tmp_path / "a" / "seams.json")
    b = write_seams_json(_result(), tmp_path / "b" / "seams.json")
    assert main(["schema", "seams", "--check", str(a), str(b)]) == 0
    assert capsys.readouterr().out == f"{a}: ok\n{b}: ok\n"


def test_a_missing_or_broken_file_exits_2_with_one_line_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = write_seams_json(_result(), tmp_path / "seams.json")
    missing = tmp_path / "nowhere.json"
    assert main(["schema", "seams", "--check", str(good), str(missing), str(good)]) == 2
    captured = capsys.readouterr()
    assert captured.out == f"{good}: ok\n"  # checked in order, stopped at the missing one
    assert captured.err.count("\n") == 1 and str(missing) in captured.err
    assert "cannot read it: No such file or directory" in captured.err
    broken = tmp_path / ON_PURPOSE / "seams.json"
    broken.parent.mkdir()
    broken.write_text('{"format_version": "1.1", "units": "m"')  # cut short
    assert main(["schema", "seams", "--check", str(broken)]) == 2
    err = capsys.readouterr().err
    assert "does not conform to seams.json 1.1: (top level): Invalid JSON" in err and "1 problem(s)" in err


def test_an_unknown_format_is_refused_by_the_parser(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["schema", "yaml"])
    assert stop.value.code == 2
    assert "argument format: invalid choice: 'yaml'" in capsys.readouterr().err
