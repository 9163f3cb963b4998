"""The seam benchmark runs and reports what it measured (a small subset; the full run is `weldcell bench`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cell.cli import main


@pytest.mark.timeout(120)
def test_bench_subset_reports_tables_and_plot(tmp_path: Path, capsys) -> None:
    code = main(
        [
            "bench",
            "--scenes",
            "t_joint",
            "--noise",
            "structured",
            "--repeats",
            "1",
            "--sweep",
            "t_joint",
            "--quick",
            "--seeds",
            "1",
            "--methods",
            "refined,paper,surfaces",
            "--out",
            str(tmp_path),
            "--json",
        ]
    )
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert (tmp_path / "bench.png").stat().st_size > 20_000
    assert json.loads((tmp_path / "bench.json").read_text()) == doc
    t1 = {r["method"]: r for r in doc["table1"]}
    assert set(t1) == {"refined", "paper", "surfaces"}
    assert t1["refined"]["found"] == 1 and t1["refined"]["false"] == 0
    assert t1["refined"]["rmse_mm"] < 0.1
    # the surfaces method is measured beside them on the same capture
    assert t1["surfaces"]["found"] == 1 and t1["surfaces"]["false"] == 0 and t1["surfaces"]["rmse_mm"] < 0.1
    # the refinement is what beats the voxel: the plain paper method is several times worse
    assert t1["paper"]["rmse_mm"] > 3 * t1["refined"]["rmse_mm"]
    crop = {r["crop"]: r for r in doc["table2"]}
    assert crop[True]["points_cropped"] < 0.2 * crop[False]["points_cropped"]
    sweep = {(r["voxel_mm"], r["method"]): r for r in doc["voxel_sweep"]}
    # the refined method finds the seam at every voxel size, below 0.1 mm
    assert all(sweep[(v, "refined")]["found"] == 1 for v in (1, 3, 6, 10))
    assert max(sweep[(v, "refined")]["rmse_mm"] for v in (1, 3, 6, 10)) < 0.1
    # the paper's error grows with the voxel size (at stereo noise it fails outright at 1 and 10 mm)
    assert sweep[(3, "paper")]["rmse_mm"] < sweep[(6, "paper")]["rmse_mm"]
    # the sweep is over the voxel size: the surfaces method, which has no voxel grid, is not in it
    assert {m for _, m in sweep} == {"refined", "paper"}


def test_the_plot_is_drawn_without_a_sweep(tmp_path: Path) -> None:
    """``--sweep ''`` leaves the third panel empty; the figure is still written (rows made up: plotting only)."""
    from cell.seam_bench import BenchReport, RunResult, plot

    def row(method: str, crop: bool = True) -> RunResult:
        return RunResult("t_joint", "stereo", 1, method, crop, 3.0, 1, 1, 0, 1.0, 0.05, 0.1, 0.08, 0.05, 0.1,
                         float("nan"), 0.5, 0.3, 0.1, 1000, 100, 50)  # fmt: skip

    path = tmp_path / "bench.png"
    plot(BenchReport([row("refined"), row("paper")], [row("refined"), row("refined", crop=False)], []), str(path))
    assert path.stat().st_size > 20_000


def test_bench_refuses_an_unknown_method(capsys) -> None:
    assert main(["bench", "--methods", "magic"]) == 2
    assert "--methods" in capsys.readouterr().out
