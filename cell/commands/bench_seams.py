"""``weldcell bench`` / ``weldcell bench seams``: the seam-detection benchmark (paper's Tables I and II,
voxel-size sweep, refined vs paper method) on the simulator's scenes."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

    from cell.seam_bench import BenchReport


def add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", help="comma-separated scene names (default: all)")
    p.add_argument("--noise", default="stereo,structured", help="noise levels (default: stereo,structured)")
    p.add_argument("--repeats", type=int, default=3, help="timing repeats per run (median is reported)")
    p.add_argument("--seeds", default="1,2,3", help="noise seeds, comma-separated (default 1,2,3)")
    p.add_argument("--sweep", default="ribs,pipe_on_plate", help="scenes for the voxel sweep ('' to skip)")
    p.add_argument("--quick", action="store_true", help="one repeat, sweep at 1, 3, 6, 10 mm only")
    p.add_argument("--methods", default="surfaces,refined,paper",
                   help="detector methods, comma-separated: refined, paper, surfaces")  # fmt: skip
    p.add_argument("--out", default="bench-out", help="folder for bench.json and bench.png")
    p.add_argument("--json", action="store_true", help="print the results as JSON")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("seams", help="seam detection: accuracy and speed on synthetic scenes (the default)")
    add_options(p)
    p.set_defaults(func=run)


def _f(x: float, nd: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{nd}f}"


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cell.seam_bench import SWEEP_VOXELS_MM, plot, run_bench
    from sim_fakes.scenes import SCENES

    scenes = [s for s in (args.scenes.split(",") if args.scenes else SCENES) if s]
    unknown = [s for s in scenes if s not in SCENES]
    if unknown:
        print(f"weldcell bench: unknown scene(s) {unknown}; choose from {list(SCENES)}")
        return 2
    methods = [m for m in args.methods.split(",") if m]
    if not methods or any(m not in ("refined", "paper", "surfaces") for m in methods):
        print(f"weldcell bench: --methods takes refined, paper and surfaces, got {args.methods!r}")
        return 2
    console = Console(stderr=args.json, width=170)
    with console.status("benchmarking") as status:
        report = run_bench(
            scenes,
            noises=[n for n in args.noise.split(",") if n],
            repeats=1 if args.quick else max(1, args.repeats),
            seeds=[int(x) for x in args.seeds.split(",") if x],
            sweep_scenes=[s for s in args.sweep.split(",") if s],
            sweep_voxels_mm=(1, 3, 6, 10) if args.quick else SWEEP_VOXELS_MM,
            methods=methods,
            progress=lambda m: status.update(f"benchmarking: {m}"),
        )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(report.to_json(), indent=1))
    plot(report, str(out / "bench.png"))
    if args.json:
        print(json.dumps(report.to_json(), indent=1))
        return 0

    _print_tables(console, report)
    for line in summary_lines(report, methods):
        console.print(line)
    console.print(f"wrote {out / 'bench.json'} and {out / 'bench.png'}")
    return 0


def _print_tables(console: Console, report: BenchReport) -> None:
    """Tables I and II and the voxel sweep."""
    from rich.table import Table

    t1 = Table(title="Table I: seams, compute time, time per seam, accuracy (mm)")
    for c in ("scene", "noise", "seed", "method", "seams found", "false", "coverage", "time s", "s/seam", "RMSE",
              "p95", "max"):  # fmt: skip
        t1.add_column(c, justify="right")
    for r in report.table1:
        t1.add_row(r.scene, r.noise, str(r.seed), r.method, f"{r.found}/{r.truth}", str(r.false), _f(r.coverage, 2),
                   _f(r.time_s), _f(r.time_s / max(r.found, 1)), _f(r.rmse_mm), _f(r.p95_mm), _f(r.max_mm))  # fmt: skip
    console.print(t1)
    t2 = Table(title="Table II: points and time with and without the ROI crop (refined)")
    for c in ("scene", "noise", "crop", "raw points", "kept", "removed", "downsampled", "fine s", "total s",
              "RMSE"):  # fmt: skip
        t2.add_column(c, justify="right")
    for r in report.table2:
        removed = 1 - r.points_cropped / max(r.points_raw, 1)
        t2.add_row(r.scene, r.noise, "yes" if r.crop else "no", str(r.points_raw), str(r.points_cropped),
                   f"{removed * 100:.1f}%", str(r.points_down), _f(r.fine_s), _f(r.time_s), _f(r.rmse_mm))  # fmt: skip
    console.print(t2)
    t3 = Table(title="Voxel-size sweep (stereo noise)")
    for c in ("scene", "voxel mm", "method", "downsampled", "found", "RMSE", "max", "time s"):
        t3.add_column(c, justify="right")
    for r in report.sweep:
        t3.add_row(r.scene, f"{r.voxel_mm:g}", r.method, str(r.points_down), f"{r.found}/{r.truth}",
                   _f(r.rmse_mm), _f(r.max_mm), _f(r.time_s))  # fmt: skip
    console.print(t3)


def summary_lines(report: BenchReport, methods: list[str]) -> list[str]:
    """The figures the issue's targets are stated in, one line per method but the paper's (the baseline), and the
    crop's effect on ribs under stereo noise when both crop rows are there."""
    lines: list[str] = []
    for method in [m for m in methods if m != "paper"]:
        ref = [r for r in report.table1 if r.method == method]
        stereo = [r for r in ref if r.noise == "stereo"]
        found = sum(r.found for r in ref)
        truth = sum(r.truth for r in ref)
        false = sum(r.false for r in ref)
        named = sum(r.named for r in ref)
        lin = [r.linear_rmse_mm for r in stereo if math.isfinite(r.linear_rmse_mm)]
        lin_max = [r.linear_max_mm for r in stereo if math.isfinite(r.linear_max_mm)]
        cur = [r.curved_rmse_mm for r in stereo if math.isfinite(r.curved_rmse_mm)]
        lines.append(
            f"summary ({method}): {found}/{truth} seams found, {false} false, {named}/{found} joints named right; "
            f"stereo linear RMSE worst "
            f"{_f(max(lin) if lin else float('nan'))} mm, max {_f(max(lin_max) if lin_max else float('nan'))} mm; "
            f"curved RMSE {_f(max(cur) if cur else float('nan'))} mm"
        )
    ribs = [r for r in report.table2 if r.scene == "ribs" and r.noise == "stereo"]
    if len(ribs) == 2:
        cropped = next(r for r in ribs if r.crop)
        uncropped = next(r for r in ribs if not r.crop)
        lines.append(
            f"ribs (10 seams, 1280x720, stereo): median {_f(cropped.time_s)} s; crop removes "
            f"{(1 - cropped.points_cropped / max(cropped.points_raw, 1)) * 100:.1f}% of the points; fine stage "
            f"{_f(uncropped.fine_s / max(cropped.fine_s, 1e-9), 1)}x faster than --no-crop"
        )
    return lines
