"""Soak: run many jobs back to back on a simulated cell and watch memory, threads and the journal.

    .venv/bin/python scripts/soak.py                                   # 100 dry runs on the fake FANUC cell
    .venv/bin/python scripts/soak.py --jobs 20 --weld                  # 20 welded jobs (slow: the fakes move)
    .venv/bin/python scripts/soak.py --config examples/sim-cell.toml   # the fake UR5 cell

The robot is parked at the job's first capture pose first, so that dry runs (which move nothing) see the part.
Prints one line every ``--every`` jobs (resident memory, its growth since the first job, threads, outcomes) and
exits 1 when a job does not end as expected (done for welded jobs, a planned and validated path for dry runs).
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def rss_mb() -> float:
    """Resident set size of this process now, MiB (Linux /proc; 0 elsewhere)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPO / "examples" / "sim-cell-fanuc.toml"))
    parser.add_argument("--job", default=str(REPO / "examples" / "jobs" / "ribs.toml"))
    parser.add_argument("--jobs", type=int, default=100, help="how many jobs (default 100)")
    parser.add_argument("--weld", action="store_true", help="weld every job instead of dry runs")
    parser.add_argument("--every", type=int, default=10, help="print a line every N jobs")
    args = parser.parse_args(argv)

    from cell.config import load_config
    from cell.factory import build_cell
    from cell.job import load_job
    from cell.journal import Journal
    from cell.runner import JobRunner

    config = load_config(args.config)
    job = load_job(args.job)
    outcomes: collections.Counter[str] = collections.Counter()
    failures = 0
    with (
        tempfile.TemporaryDirectory() as tmp,
        Journal(Path(tmp) / "soak.sqlite3") as journal,
        build_cell(config, start_simulators=True) as cell,
    ):
        cell.connect()
        runner = JobRunner(cell, journal=journal)
        cell.robot.move_linear(runner.capture_pose(job, 0), speed_m_s=config.robot.speed_m_s)
        t0 = time.monotonic()
        rss0 = 0.0
        for n in range(1, args.jobs + 1):
            report = runner.run(job, dry_run=not args.weld)
            outcomes[report.outcome] += 1
            expected = "welded" if args.weld else "dry_run"
            if report.outcome != expected:
                failures += 1
                print(f"job {n}: {report.outcome}: {report.reason}", flush=True)
                if report.state == "fault":
                    runner.acknowledge("soak")
            if n == 1:
                rss0 = rss_mb()
            if n % args.every == 0 or n == args.jobs:
                rss = rss_mb()
                print(
                    f"{n:4d} jobs  {time.monotonic() - t0:7.1f} s  rss {rss:7.1f} MiB "
                    f"(+{rss - rss0:5.1f} since job 1)"
                    f"  threads {threading.active_count():3d}  {dict(outcomes)}",
                    flush=True,
                )
        print(f"journal: {len(journal.recent_jobs(args.jobs + 1))} jobs recorded; failures: {failures}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
