"""``weldcell run JOB --config cell.toml``: run one job on the cell and print its report.

Exit codes: 0 the job is done (or a dry run planned and validated its path); 1 the job ended in fault (the reason
on stderr) or was not approved, or the journal shows an unclean stop nobody has acknowledged; 2 a bad job or config
file; 3 no seam found.

After an unclean stop (the journal shows a job that was running when its process stopped: the torch may stand on
the part), the cell starts in ``fault``, as ``weldcell serve`` does: nothing moves until an operator acknowledges
(``--acknowledge``, with ``--operator``). The fault is journaled, so it holds for every later run until then.
"""

from __future__ import annotations

import argparse
import getpass
import json
import logging
import sys
from typing import Any, TextIO


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="run a welding job on the cell",
        description="Run JOB (a job TOML file, see examples/jobs/ribs.toml) on the cell of --config: home, move to "
        "each capture pose, capture, detect, plan, validate, (approve,) weld every seam, retract. Simulated devices "
        "(kind = fake-*) are started in this process. Every step goes to the journal. Exit code 0 done, 1 fault "
        "(with the reason), 2 bad job or config, 3 no seam found.",
    )
    p.add_argument("job", metavar="JOB", help="job file (TOML)")
    p.add_argument("--config", required=True, help="cell config file (TOML), e.g. examples/sim-cell.toml")
    p.add_argument(
        "--dry-run", action="store_true", help="capture where the robot stands, plan and validate; move nothing"
    )
    p.add_argument("--json", action="store_true", help="print the job report as JSON")
    p.add_argument("--yes", action="store_true", help="approve the planned path without asking (approval = true jobs)")
    p.add_argument("--operator", default=None, help="the approving operator's name (default: the login name)")
    p.add_argument("--journal", default=None, help="journal file (default: [daemon] journal of the config)")
    p.add_argument(
        "--acknowledge",
        action="store_true",
        help="after an unclean stop: the operator (--operator) has checked the torch and the part; leave fault",
    )
    p.set_defaults(func=run_job)


def run_job(args: argparse.Namespace) -> int:
    from cell.cli import EXIT_FAILURE, EXIT_NO_SEAM, EXIT_OK
    from cell.config import load_config
    from cell.factory import build_cell
    from cell.job import load_job
    from cell.journal import Journal
    from cell.runner import JobRunner, safety_limits

    if args.verbose < 2:  # pymodbus logs a refused connection at ERROR; the job's reason says it once
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    config = load_config(args.config)
    job = load_job(args.job)
    safety_limits(config)  # a missing [safety] is a bad config: refuse before starting anything
    journal_path = config.resolve(args.journal or config.daemon.journal)
    operator = args.operator or _login()
    out: TextIO = sys.stderr if args.json else sys.stdout
    show = _Progress(out)

    def approve(path: Any) -> str | None:
        if args.yes:
            return operator
        print(json.dumps(path.summary(), indent=1), file=out)
        if not sys.stdin.isatty():
            print("weldcell run: the job needs approval: pass --yes (or answer on a terminal)", file=sys.stderr)
            return None
        answer = input(f"weld {len(path.passes)} seam(s)? approve as {operator} [y/N] ")
        return operator if answer.strip().lower() in ("y", "yes") else None

    with Journal(journal_path) as journal, build_cell(config, start_simulators=True) as cell:
        unclean = journal.unclean_stop(then="run again with --acknowledge --operator NAME")
        cell.connect()
        runner = JobRunner(cell, journal=journal, on_progress=show)
        if unclean is not None:
            runner.machine.fault_now(unclean)  # stops and switches off first; journaled until acknowledged
            if not args.acknowledge:
                print(f"weldcell run: the cell is in fault: {unclean}", file=sys.stderr)
                return EXIT_FAILURE
            runner.acknowledge(operator)
        for i in range(len(job.captures)):
            runner.capture_pose(job, i)  # a fixture-relative job on a cell without [fixture]: ConfigError, exit 2
        report = runner.run(job, dry_run=args.dry_run, approve=approve)
        show.finish()
    data = report.to_dict()
    if args.json:
        print(json.dumps(data))
    else:
        _print_report(data)
    if report.outcome in ("welded", "dry_run"):
        return EXIT_OK
    if report.outcome == "no_seam":
        print(f"weldcell run: no seam found: {report.reason}", file=sys.stderr)
        return EXIT_NO_SEAM
    print(f"weldcell run: job {report.job_id} {report.outcome}: {report.reason}", file=sys.stderr)
    return EXIT_FAILURE


def _login() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return "operator"


def _print_report(data: dict[str, Any]) -> None:
    cycle = data["cycle_s"]
    print(f"job {data['job_id']} ({data['workpiece']}): {data['state']} ({data['outcome']})")
    if data["reason"]:
        print(f"  reason: {data['reason']}")
    print(
        f"  seams found {data['seams_found']}, planned {data['seams_planned']}, welded {data['seams_welded']}; "
        f"poses sent {data['poses_sent']}; arc on {data['arc_time_s']:.1f} s"
    )
    print("  cycle " + ", ".join(f"{k} {v:.1f} s" for k, v in cycle.items()))


class _Progress:
    """One line per state change and step; a progress bar while a pass is welded (on a terminal)."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.tty = out.isatty()
        self._bar_open = False

    def __call__(self, kind: str, data: dict[str, Any]) -> None:
        if kind == "weld":
            if not self.tty:
                return
            done, total = int(data["pose"]), max(int(data["poses"]), 1)
            width = 30
            filled = round(width * done / total)
            bar = "#" * filled + "-" * (width - filled)
            self.out.write(f"\r  pass {data['pass']}/{data['passes']} seam {data['seam_id']} [{bar}] {done}/{total}")
            self.out.flush()
            self._bar_open = True
            return
        self._close_bar()
        if kind == "state":
            print(f"[{data['state']}] {data['reason']}", file=self.out, flush=True)
        else:
            print(f"  {data['text']}", file=self.out, flush=True)

    def _close_bar(self) -> None:
        if self._bar_open:
            self.out.write("\n")
            self._bar_open = False

    def finish(self) -> None:
        self._close_bar()
