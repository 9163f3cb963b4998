"""The soak's in-process mode (scripts/soak.py --in-process): the job runner alone, no daemon; memory per job."""

from __future__ import annotations

import collections
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


# ================================================================================================ in-process
def rss_mb() -> float:
    """Resident set size of this process now, MiB (Linux /proc; 0 elsewhere)."""
    from cell.memory import resident_mib

    return resident_mib() or 0.0


def run_in_process_soak(config_path: str, job_path: str, *, jobs: int, weld: bool, every: int) -> int:
    """The earlier soak: ``jobs`` dry runs (or welds) through one JobRunner in this process."""
    from cell.config import load_config
    from cell.factory import build_cell
    from cell.job import load_job
    from cell.journal import Journal
    from cell.runner import JobRunner

    config = load_config(config_path)
    job = load_job(job_path)
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
        for n in range(1, jobs + 1):
            report = runner.run(job, dry_run=not weld)
            outcomes[report.outcome] += 1
            expected = "welded" if weld else "dry_run"
            if report.outcome != expected:
                failures += 1
                print(f"job {n}: {report.outcome}: {report.reason}", flush=True)
                if report.state == "fault":
                    runner.acknowledge("soak")
            if n == 1:
                rss0 = rss_mb()
            if n % every == 0 or n == jobs:
                rss = rss_mb()
                print(
                    f"{n:4d} jobs  {time.monotonic() - t0:7.1f} s  rss {rss:7.1f} MiB "
                    f"(+{rss - rss0:5.1f} since job 1)"
                    f"  threads {threading.active_count():3d}  {dict(outcomes)}",
                    flush=True,
                )
        print(f"journal: {len(journal.recent_jobs(jobs + 1))} jobs recorded; failures: {failures}")
    return 1 if failures else 0
