"""cell.commands.bench_seams: the command's checks and the summary line the issue's targets are stated in."""

from __future__ import annotations

import argparse
import math

import pytest

from cell.commands import bench_seams
from cell.seam_bench import BenchReport, RunResult

NAN = float("nan")


def row(scene: str, noise: str, method: str, *, crop: bool = True, **values: float) -> RunResult:
    v = {"truth": 2, "found": 2, "false": 0, "lin": 0.1, "lin_max": 0.2, "cur": NAN, "time": 1.0, "fine": 0.5,
         "raw": 1000, "cropped": 100} | values  # fmt: skip
    return RunResult(scene, noise, 1, method, crop, 3.0, int(v["truth"]), int(v["found"]), int(v["false"]), 1.0,
                     v["lin"], v["lin_max"], v["lin_max"], v["lin"], v["lin_max"], v["cur"], v["time"], v["fine"],
                     0.1, int(v["raw"]), int(v["cropped"]), 50, named=int(v.get("named", v["found"])))  # fmt: skip


def test_the_summary_pools_every_run_of_a_method_and_takes_the_worst_stereo_errors() -> None:
    report = BenchReport(
        table1=[
            row("t_joint", "stereo", "refined", lin=0.12, lin_max=0.25),
            row("ribs", "stereo", "refined", found=9, truth=10, false=1, lin=0.185, lin_max=0.266, cur=0.05, named=8),
            row("ribs", "structured", "refined", lin=0.9, lin_max=2.0),  # not stereo: no part in the worst errors
            row("ribs", "stereo", "paper", lin=1.5, lin_max=3.0),  # the baseline has no summary of its own
        ],
        table2=[
            row("ribs", "stereo", "refined", crop=True, time=0.8, fine=0.2, raw=1000, cropped=120),
            row("ribs", "stereo", "refined", crop=False, time=2.0, fine=1.0),
        ],
        sweep=[],
    )
    assert bench_seams.summary_lines(report, ["refined", "paper"]) == [
        "summary (refined): 13/14 seams found, 1 false, 12/13 joints named right; stereo linear RMSE worst "
        "0.185 mm, max 0.266 mm; curved RMSE 0.050 mm",
        "ribs (10 seams, 1280x720, stereo): median 0.800 s; crop removes 88.0% of the points; fine stage "
        "5.0x faster than --no-crop",
    ]
    # no stereo run with a linear seam: the worst errors are unknown, not zero
    only_structured = BenchReport([row("ribs", "structured", "surfaces", lin=NAN, lin_max=NAN)], [], [])
    assert bench_seams.summary_lines(only_structured, ["surfaces"]) == [
        "summary (surfaces): 2/2 seams found, 0 false, 2/2 joints named right; stereo linear RMSE worst - mm, "
        "max - mm; curved RMSE - mm"
    ]


def test_numbers_print_with_their_decimals_and_unknown_ones_as_a_dash() -> None:
    assert [bench_seams._f(0.18549), bench_seams._f(2.0, 1), bench_seams._f(NAN), bench_seams._f(math.inf)] == [
        "0.185", "2.0", "-", "-"
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--scenes", "t_joint,teapot"], "weldcell bench: unknown scene(s) ['teapot']"),
        (["--methods", "refined,magic"], "weldcell bench: --methods takes refined, paper and surfaces"),
        (["--methods", ","], "weldcell bench: --methods takes refined, paper and surfaces"),
    ],
)
def test_unknown_scenes_and_methods_exit_2_before_any_work(argv, message, capsys) -> None:
    parser = argparse.ArgumentParser()
    bench_seams.add_options(parser)
    assert bench_seams.run(parser.parse_args(argv)) == 2
    assert capsys.readouterr().out.startswith(message)
