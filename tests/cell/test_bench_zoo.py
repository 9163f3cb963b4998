"""``weldcell bench zoo`` (cell/commands/bench_zoo.py): its refusals, what it hands the bench, the table and the JSON.

The bench (cell/zoo_bench.py) is tested in tests/cell/test_zoo_bench.py; here it is replaced by a report of two
known captures, so that the printed numbers can be compared to them exactly."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

import cell.zoo_bench
from cell.cli import main
from cell.zoo_bench import CaptureScore, ZooReport


def score(family: str, seed: int, **kw: Any) -> CaptureScore:
    values: dict[str, Any] = dict(family=family, seed=seed, sensor="oakd", prompted=False, clutter=0,
                                  camera_distance_m=0.8, gt_seams=2, found=2, reported=2, false_seams=0,
                                  split_seams=0, rmse_mm=0.1, p95_mm=0.2, max_mm=0.3, time_s=1.0,
                                  outcome="seams")  # fmt: skip
    return CaptureScore(**{**values, **kw})


REPORT = ZooReport(
    "dev",
    [
        score("tee", 1, point_error_mm=[0.1, 0.1, 0.1, 0.1], time_s=0.5),
        score("tee", 2, found=1, false_seams=1, reported=2, point_error_mm=[0.5, 0.5, 0.5, 0.5], time_s=1.5),
        score("pipe", 3, gt_seams=1, found=0, reported=0, outcome="no_seam", rmse_mm=float("nan"), time_s=2.5),
    ],
    12.3,
)


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> list[dict[str, Any]]:
    seen: list[dict[str, Any]] = []

    def fake_run_zoo(split: str, n: int, **kw: Any) -> ZooReport:
        seen.append({"split": split, "n": n, **kw})
        return REPORT

    monkeypatch.setattr(cell.zoo_bench, "run_zoo", fake_run_zoo)
    return seen


def test_unknown_families_and_counts_under_one_are_refused_before_anything_runs(
    calls: list[dict[str, Any]], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "zoo", "--families", "tee,teapot"]) == 2
    assert main(["bench", "zoo", "--families", "kettle,teapot"]) == 2
    assert main(["bench", "zoo", "--n", "0"]) == 2
    assert main(["bench", "zoo", "--jobs", "0"]) == 2
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("weldcell bench zoo: unknown family ['teapot']; choose from ['")
    assert lines[1].startswith("weldcell bench zoo: unknown families ['kettle', 'teapot']; choose from")
    assert lines[2:] == ["weldcell bench zoo: --n and --jobs must be at least 1"] * 2
    assert calls == []


def test_the_json_is_the_reports_summary(
    calls: list[dict[str, Any]], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    argv = ["bench", "zoo", "--split", "test", "--n", "3", "--families", "tee,pipe", "--jobs", "2", "--json"]
    assert main([*argv, "--cache", str(tmp_path), "--method", "surfaces", "--sensor", "oakd_median"]) == 0
    [call] = calls
    assert {k: v for k, v in call.items() if k != "progress"} == {
        "split": "test", "n": 3, "families": ["tee", "pipe"], "jobs": 2, "cache": tmp_path, "method": "surfaces",
        "sensor": "oakd_median",
    }  # fmt: skip
    doc = json.loads(capsys.readouterr().out)
    assert doc == json.loads(json.dumps(REPORT.to_json()))
    tee, overall = doc["families"]["tee"], doc["overall"]
    assert (tee["captures"], tee["passed"], tee["found"], tee["false_seams"], tee["recall"]) == (2, 1, 3, 1, 0.75)
    assert tee["rmse_mm"] == pytest.approx(0.361, abs=5e-4)  # sqrt((4 * 0.01 + 4 * 0.25) / 8)
    assert (overall["captures"], overall["no_seam"], overall["gt_seams"], overall["time_s_median"]) == (3, 1, 5, 1.5)


def test_the_table_has_a_row_per_family_and_one_overall(
    calls: list[dict[str, Any]], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "zoo", "--n", "3"]) == 0
    assert calls[0]["cache"] == cell.zoo_bench.default_cache_dir() and calls[0]["families"] is None
    out = capsys.readouterr().out
    assert "zoo, dev split: 3 captures in 12 s" in " ".join(out.split())
    rows = {c[0]: c[1:] for c in ([x.strip() for x in line.split("│")[1:-1]] for line in out.splitlines()) if c}
    #      captures passed GT found recall false reported split unseen joint-named no-seam errors over RMSE p95 max
    assert rows["tee"][:10] == ["2", "1", "4", "3", "0.750", "1", "4", "0", "0", "0/3"]
    assert rows["pipe"][:12] == ["1", "0", "1", "0", "0.000", "0", "0", "0", "0", "0/0", "1", "0"]
    assert rows["pipe"][13:16] == ["-", "-", "-"]  # no point errors: a dash, not zero
    assert rows["overall"][:4] == ["3", "1", "5", "3"] and rows["overall"][-2:] == ["1.500", "2.400"]


def test_the_sensor_choices_are_the_zoos_sensors(capsys: pytest.CaptureFixture[str]) -> None:
    """The parser names the sensors without importing the renderer (``weldcell --help`` stays fast); they must
    be exactly the ones the zoo renders, so that none is offered that does not exist or left out."""
    import argparse
    import re

    from cell.commands.bench_zoo import add_parser
    from sim_fakes.zoo import SENSORS

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    for name in SENSORS:
        assert parser.parse_args(["zoo", "--sensor", name]).sensor == name
    with pytest.raises(SystemExit):
        parser.parse_args(["zoo", "--sensor", "no_such_sensor"])
    offered = re.search(r"choose from (.*)\)", capsys.readouterr().err)
    assert offered is not None
    assert sorted(re.findall(r"'?(\w+)'?", offered.group(1))) == sorted(SENSORS)
