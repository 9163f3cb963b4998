"""``weldcell evaluate``: score a seams.json against a capture's ground truth."""

from __future__ import annotations

import argparse
import json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="compare detected seams with a capture's ground truth",
        description="Ground-truth seams, seams found, false seams, coverage and RMSE / 95th percentile / max "
        "error (mm) of every path point to the true centre line. Matching rules: docs/evaluation.md.",
    )
    p.add_argument("capture", help="capture folder with ground_truth.json")
    p.add_argument("seams_json", help="seams.json written by 'weldcell detect'")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from perception.capture import load_capture
    from perception.errors import BadCapture
    from perception.evaluate import evaluate_seams
    from perception.seams import read_seams_json

    capture = load_capture(args.capture)
    if capture.ground_truth is None:
        raise BadCapture("no ground_truth.json: nothing to evaluate against", path=args.capture)
    found = read_seams_json(args.seams_json)
    report = evaluate_seams(found.points_in_camera(capture.X_base_camera), capture.ground_truth)
    if args.json:
        print(json.dumps({"capture": str(args.capture), **report.to_json()}, indent=1))
        return 0

    def mm(x: float) -> str:
        return "-" if x != x else f"{x * 1000:.3f}"

    console = Console()
    table = Table(title=f"{args.capture}")
    for col in ("truth seams", "found", "false seams", "coverage", "RMSE mm", "p95 mm", "max mm", "points"):
        table.add_column(col, justify="right")
    table.add_row(
        str(report.n_truth),
        f"{report.n_found}/{report.n_truth}",
        str(len(report.false_seams)),
        f"{report.coverage * 100:.1f}%",
        mm(report.rmse_m),
        mm(report.p95_m),
        mm(report.max_m),
        str(report.n_points),
    )
    console.print(table)
    per = Table(title="per ground-truth seam")
    for col in ("#", "kind", "length mm", "found by", "coverage", "RMSE mm", "p95 mm", "max mm"):
        per.add_column(col, justify="right")
    for s in report.seams:
        per.add_row(
            str(s.index),
            s.kind,
            f"{s.length_m * 1000:.1f}",
            ",".join(map(str, s.detected_ids)) or "-",
            f"{s.coverage * 100:.1f}%",
            mm(s.rmse_m),
            mm(s.p95_m),
            mm(s.max_m),
        )
    console.print(per)
    return 0
