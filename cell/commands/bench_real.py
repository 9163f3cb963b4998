"""``weldcell bench real``: the detector on the real scans and frames in ../shared/realdata."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import cast


def _default_realdata() -> Path:
    return Path(__file__).resolve().parents[2].parent / "shared" / "realdata"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "real",
        help="seam detection on real scans and frames, scored against independent references",
        description="Run the detector on every real scan and frame in the folder (read in place, nothing "
        "copied), score it against references/*.json where one exists (coverage of each reference seam within "
        "its tolerance, false seams), and list the others with their seams or the reason none could be found.",
    )
    p.add_argument("--realdata", help="the real-data folder (default: ../shared/realdata beside the checkout)")
    p.add_argument("--out", help="write one picture per item (cloud, reference, detected seams) and bench.json here")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument(
        "--method",
        choices=("refined", "surfaces", "paper"),
        default="surfaces",
        help="the fine stage (clouds go through a range image from their viewpoint for surfaces)",
    )
    p.add_argument("--draws", type=int, default=0,
                   help="also detect each referenced cloud this many times with points dropped at random, and "
                   "show how often it still passes (default 0: not run)")  # fmt: skip
    p.add_argument("--dropout", type=float, default=0.02,
                   help="the share of points each such draw drops (default 0.02)")  # fmt: skip
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cell.real_bench import COVER_SHARE, Method, run_real

    realdata = Path(args.realdata) if args.realdata else _default_realdata()
    if not realdata.is_dir():
        print(f"weldcell bench real: no real data at {realdata} (give --realdata); nothing to do")
        return 0
    out = Path(args.out) if args.out else None
    if args.draws < 0 or not 0.0 <= args.dropout < 1.0:
        print("weldcell bench real: --draws must be >= 0 and --dropout in [0, 1)")
        return 2
    console = Console(stderr=True)
    with console.status("detecting on the real items"):
        items = run_real(realdata, out, cast(Method, args.method), draws=args.draws, dropout=args.dropout)
    doc = {"realdata": str(realdata), "items": [i.to_json() for i in items],
           "scored": sum(i.scored for i in items), "passed": sum(bool(i.passed) for i in items),
           "draws": args.draws, "dropout": args.dropout}  # fmt: skip
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "bench.json").write_text(json.dumps(doc, indent=1))
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    t = Table(title=f"real data ({realdata}): a referenced item passes when every reference seam is >= "
                    f"{COVER_SHARE:.0%} covered within its tolerance and no detected seam is far from all")  # fmt: skip
    columns = ["item", "kind", "points", "seams", "time s", "reference", "coverage", "false", "pass"]
    if args.draws:
        columns.append(f"pass, {args.dropout:.0%} dropped")
    for c in [*columns, "notes"]:
        t.add_column(c, overflow="fold")
    for i in items:
        # l250 fillet: a linear seam 250 mm long, and its joint
        seams = ", ".join(f"{s['kind'][0]}{s['length_m'] * 1000:.0f} {s.get('joint', '')}".strip()
                          for s in i.seams) or "0"  # fmt: skip
        notes = i.reason if i.outcome != "seams" else i.note
        row = [i.item, i.kind, str(i.points), seams, f"{i.time_s:.2f}",
               f"tol {i.tolerance_m * 1000:.0f} mm" if i.tolerance_m else "-",
               ", ".join(f"{c:.0%}" for c in i.coverage) or "-", str(i.false_seams) if i.scored else "-",
               "-" if i.passed is None else ("yes" if i.passed else "no")]  # fmt: skip
        if args.draws:
            row.append(f"{sum(i.perturbed)}/{len(i.perturbed)}" if i.perturbed else "-")
        t.add_row(*row, notes)
    Console(width=200).print(t)
    print(f"{doc['passed']} of {doc['scored']} referenced items pass; {len(items)} items in all")
    if args.draws:
        runs = [p for i in items for p in i.perturbed]
        print(f"with {args.dropout:.0%} of the points dropped: {sum(runs)} of {len(runs)} draws pass "
              f"({args.draws} per referenced cloud)")
    return 0
