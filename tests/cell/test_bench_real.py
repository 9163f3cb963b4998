"""``weldcell bench real`` (cell/commands/bench_real.py): without data, the JSON and bench.json, the table's counts.

The bench (cell/real_bench.py) is tested in tests/cell/test_real_bench.py on the real data; here it is replaced by
three known items, so that the counts the command prints can be compared to them exactly."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

import cell.real_bench
from cell.cli import main
from cell.commands.bench_real import _default_realdata
from cell.real_bench import RealItem

REPO = Path(__file__).resolve().parents[2]

SCAN = RealItem("a/scan.ply", "cloud", points=1200, seams=[{"kind": "linear", "joint": "fillet", "length_m": 0.25}],
                outcome="seams", time_s=0.5, reference="a.json", tolerance_m=0.005, coverage=[0.9],
                false_seams=0)  # fmt: skip
FRAME = RealItem("b/frame", "rgbd frame", points=300, outcome="no_seam", reason="no two surfaces meet",
                 reference="b.json", tolerance_m=0.01, coverage=[0.0])  # fmt: skip
ITEMS = [SCAN, FRAME, RealItem("c/photos", "photos", outcome="not_run", reason="photos without depth")]


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> list[tuple[Any, ...]]:
    seen: list[tuple[Any, ...]] = []

    def fake_run_real(realdata: Path, out: Path | None = None, method: str = "refined", *, draws: int = 0,
                      dropout: float = 0.02) -> list[RealItem]:  # fmt: skip
        seen.append((realdata, out, method) if not draws else (realdata, out, method, draws, dropout))
        if not draws:
            return ITEMS
        return [replace(SCAN, perturbed=[True, False, True]), replace(FRAME), ITEMS[2]]

    monkeypatch.setattr(cell.real_bench, "run_real", fake_run_real)
    return seen


def test_the_default_data_is_shared_realdata_beside_the_checkout() -> None:
    assert _default_realdata() == REPO.parent / "shared" / "realdata"


def test_without_real_data_there_is_nothing_to_do_and_that_is_no_failure(
    calls: list[Any], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["bench", "real", "--realdata", str(tmp_path / "absent")]) == 0
    assert capsys.readouterr().out == (
        f"weldcell bench real: no real data at {tmp_path / 'absent'} (give --realdata); nothing to do\n"
    )
    assert calls == []


def test_the_json_counts_the_referenced_items_and_those_that_pass(
    calls: list[Any], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    argv = ["bench", "real", "--realdata", str(tmp_path), "--json", "--out", str(out), "--method", "surfaces"]
    assert main(argv) == 0
    assert calls == [(tmp_path, out, "surfaces")]
    doc = json.loads(capsys.readouterr().out)
    assert (doc["realdata"], doc["scored"], doc["passed"]) == (str(tmp_path), 2, 1)
    assert [(i["item"], i["passed"]) for i in doc["items"]] == [("a/scan.ply", True), ("b/frame", False),
                                                                  ("c/photos", None)]  # fmt: skip
    assert json.loads((out / "bench.json").read_text()) == doc


def test_the_table_lists_every_item_and_ends_with_the_count(
    calls: list[Any], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["bench", "real", "--realdata", str(tmp_path)]) == 0
    assert calls == [(tmp_path, None, "surfaces")]
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == "1 of 2 referenced items pass; 3 items in all"
    rows = [[c.strip() for c in line.split("│")[1:-1]] for line in lines if line.startswith("│")]
    by_item = {r[0]: r for r in rows if r[0]}
    # item, kind, points, seams, time s, reference, coverage, false, pass, notes
    assert by_item["a/scan.ply"][1:9] == ["cloud", "1200", "l250 fillet", "0.50", "tol 5 mm", "90%", "0", "yes"]
    assert by_item["b/frame"][1:] == ["rgbd frame", "300", "0", "0.00", "tol 10 mm", "0%", "0", "no",
                                      "no two surfaces meet"]  # fmt: skip
    assert by_item["c/photos"][5:] == ["-", "-", "-", "-", "photos without depth"]


def test_the_dropout_draws_are_counted_per_item_and_in_all(
    calls: list[Any], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["bench", "real", "--realdata", str(tmp_path), "--draws", "3", "--dropout", "0.05"]) == 0
    assert calls == [(tmp_path, None, "surfaces", 3, 0.05)]
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == "with 5% of the points dropped: 2 of 3 draws pass (3 per referenced cloud)"
    rows = [[c.strip() for c in line.split("│")[1:-1]] for line in lines if line.startswith("│")]
    by_item = {r[0]: r for r in rows if r[0]}
    assert by_item["a/scan.ply"][8:10] == ["yes", "2/3"] and by_item["b/frame"][9] == "-"


@pytest.mark.parametrize("argv", [["--draws", "-1"], ["--dropout", "1.0"], ["--dropout", "-0.1"]])
def test_a_bad_draw_count_or_dropout_share_is_refused(
    argv: list[str], calls: list[Any], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["bench", "real", "--realdata", str(tmp_path), *argv]) == 2
    assert "--draws must be >= 0 and --dropout in [0, 1)" in capsys.readouterr().out
    assert calls == []
