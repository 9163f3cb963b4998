"""``weldcell bench``: benchmarks, one sub-subcommand per topic (``weldcell bench calibration``, ...).

To add a benchmark, write a module in ``cell/commands/`` whose ``add_parser(subparsers)`` registers
its parser under the ``bench`` group and sets ``func``, and list it in :data:`BENCH_MODULES`.
"""

from __future__ import annotations

import argparse
import importlib

# Benchmark subcommand modules, imported when the parser is built; each keeps heavy imports inside
# its handler so that `weldcell --help` stays fast.
BENCH_MODULES: tuple[str, ...] = (
    "cell.commands.bench_seams",
    "cell.commands.bench_calibration",
    "cell.commands.bench_zoo",
    "cell.commands.bench_real",
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "bench",
        help="accuracy and speed benchmarks on synthetic data with known truth",
        description="Benchmarks on synthetic data with known truth. Each prints a table, or JSON with --json.",
    )
    bench_sub = parser.add_subparsers(dest="bench_command", metavar="BENCHMARK")
    bench_sub.required = False
    for name in BENCH_MODULES:
        importlib.import_module(name).add_parser(bench_sub)
    # plain `weldcell bench` is the seam-detection benchmark with its default options
    from cell.commands import bench_seams

    bench_seams.add_options(parser)
    parser.set_defaults(func=bench_seams.run)
