"""``weldcell bench calibration`` (cell/commands/bench_calibration.py): its arguments, the table, --check.

The bench itself (calibration/bench.py) is tested in tests/calibration/test_bench.py; here it is replaced by a
report of known numbers, so that what the command prints can be compared to them exactly."""

from __future__ import annotations

import argparse

import pytest

import calibration.bench
from calibration.bench import METHODS, BenchConfig
from cell.cli import main
from cell.commands.bench_calibration import _pose_counts, _positive_int


def known_report(refined_mm: float = 0.14) -> calibration.bench.Report:
    rows: dict[str, dict[str, float | None]] = {
        m: {"translation_mm": 0.5 + i, "rotation_deg": 0.05 + i / 100} for i, m in enumerate(METHODS)
    }
    rows["refined"] = {"translation_mm": refined_mm, "rotation_deg": 0.0281}
    rows[METHODS[-1]] = {"translation_mm": None, "rotation_deg": None}  # a method that failed in every trial
    return {"15": rows}


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> list[tuple[BenchConfig, bool]]:
    seen: list[tuple[BenchConfig, bool]] = []

    def fake_run_bench(config: BenchConfig, *, on_trial: object = None, render: object = None) -> object:
        seen.append((config, render is not None))
        return known_report(1.6 if config.seed == 13 else 0.14)

    monkeypatch.setattr(calibration.bench, "run_bench", fake_run_bench)
    return seen


def test_pose_counts_and_trials_are_checked_with_the_reason() -> None:
    assert _pose_counts("8,15,25") == (8, 15, 25)
    for text, why in (("8,x", "expected comma-separated integers, got '8,x'"), ("2,15", "pose counts must be >= 3")):
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            _pose_counts(text)
    assert _positive_int("20") == 20
    with pytest.raises(argparse.ArgumentTypeError, match="must be >= 1, got 0"):
        _positive_int("0")
    with pytest.raises(argparse.ArgumentTypeError, match="expected an integer, got 'many'"):
        _positive_int("many")


def test_the_table_prints_the_reports_medians_and_failed_where_a_method_failed(
    calls: list[tuple[BenchConfig, bool]], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "calibration", "--poses", "15", "--trials", "3", "--seed", "7"]) == 0
    [(config, rendered)] = calls
    assert (config.pose_counts, config.trials, config.seed, rendered) == ((15,), 3, 7, False)
    out = capsys.readouterr().out
    title = " ".join(out.split("┏")[0].split())  # the title, wrapped to the table's width
    assert title == "hand-eye error vs truth, median of 3 trials (corners 0.3 px, robot 0.05 mm, seed 7)"
    lines = {line.split("│")[1].strip(): line for line in out.splitlines() if line.count("│") == 4}
    assert "0.140" in lines["refined"] and "0.0281" in lines["refined"]
    assert "1.500" in lines[METHODS[1]] and "0.0600" in lines[METHODS[1]]
    assert lines[METHODS[-1]].count("failed") == 2


def test_check_exits_1_naming_what_missed_the_target(
    calls: list[tuple[BenchConfig, bool]], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "calibration", "--poses", "15", "--trials", "1", "--check", "--json"]) == 0
    assert main(["bench", "calibration", "--poses", "15", "--trials", "1", "--check", "--json", "--seed", "13"]) == 1
    err = capsys.readouterr().err
    assert err.strip() == (
        "weldcell bench calibration: target missed: refined translation 1.600 mm > 0.5 mm; "
        "tsai (1.500 mm, 0.0600 deg) is not worse than refined"
    )
    assert main(["bench", "calibration", "--poses", "15", "--trials", "1", "--images", "--json"]) == 0
    assert [rendered for _, rendered in calls] == [False, False, True]  # --images hands the bench a renderer
