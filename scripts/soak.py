"""Soak: many jobs back to back on a simulated cell; memory, threads, the journal and the shutdown are checked.

    .venv/bin/python scripts/soak.py                                   # 100 jobs through `weldcell serve` (FANUC)
    .venv/bin/python scripts/soak.py --config examples/sim-cell.toml   # the fake UR5 cell
    .venv/bin/python scripts/soak.py --jobs 30 --weld-every 0          # shorter: welds only to rerun a fault
    .venv/bin/python scripts/soak.py --in-process --jobs 100           # the job runner alone, in this process

The daemon soak (the default) runs ``weldcell serve --sim-faults --port 0`` on a copy of --config whose fakes take
free ports and whose journal and status image go to a temporary folder (--workdir keeps them), then submits --jobs
jobs over HTTP back to back, each a copy of --job (its workpiece renamed ``soak-NNN-<kind>-...`` so that the
journal names it):

- most are dry runs (``?dry_run=1``: captured where the robot stands, planned and validated, nothing moves); the
  robot stands at home, a view the job was not planned for, and on some of the simulated camera's noise draws the
  default detector finds no seam from there (a third of them): such a dry run ends ``no_seam``, an answer the soak
  accepts and counts (the job's own capture poses, which the welds use, find the seams every time);
- every --weld-every-th job welds, and so does the job after a fault that stopped the torch on the part (the
  operator runs the part again; it also brings the robot home for the dry runs) or left the robot at the first
  capture pose (a camera timeout);
- every --fault-every-th job is a fault, in turn from --faults: ``camera_timeout`` (the camera stops sending
  frames before the job), ``connection_drop`` (the robot controller drops its connection before the job),
  ``protective_stop`` and ``track_fault`` (injected once the arc of a welding job is on), ``no_answer`` and
  ``link_drop_arc`` (the robot controller stops answering / drops its connection once the arc is on: the cell
  must be in fault within 1 s and the simulated controller's own arc output, read through ``GET /sim/faults``,
  must read off within 1 s: its heartbeat watchdog, docs/controller-watchdogs.md), ``unreachable_pose`` (a
  capture pose 3 m away: refused at submission with a 400 naming the reach limit), ``malformed`` (a bad job
  file: answered 400, no record) and ``hostile`` (in turn: a job path outside the jobs directory, a cross-origin
  POST, a 5000-deep nested body, a 2 MiB body, a string ``dry_run``: each its 4xx naming the rule, no record).

Faults reach the simulators inside the daemon through its test-only ``/sim/faults`` endpoint (only served with
``--sim-faults``, which the daemon refuses unless every device is a simulator it started itself). Jobs queue behind
a faulted cell; the soak then plays the operator: it clears the simulated fault (``POST /sim/faults/clear``) and
acknowledges (``POST /acknowledge``), and the queue goes on. A fault injected before a job waits until every job
before it has finished (otherwise it would hit the wrong job).

After the last job it checks every submission against the API (``GET /jobs/{id}``: final state, outcome, error,
``/metrics`` counts) and, once the daemon has stopped, against the SQLite journal itself (one row per accepted
job, named by its workpiece, started once). Memory (scripts/soak_memory.py): the daemon runs with
``WELDCELL_MEMORY_SNAPSHOTS`` and records, after each job and its ``malloc_trim``, its live Python memory
(tracemalloc) and its resident size (memory.jsonl in the work folder); after the first --warmup jobs the traced
memory must be flat (the medians of the first and the last third within --traced-bound-mib) and the resident size on
a plateau (at most --rss-slope-mib per job over the last half). Its thread count when idle must stay the same. The
soak's own samples (VmRSS and threads as each job finishes) go to samples.json in the work folder. Finally a welding
job is submitted and the daemon gets SIGTERM once its arc is on
(--no-sigterm-probe: when idle): it must exit 0, print that the arc output reads off, and journal that job as
failed by SIGTERM.

Prints one line every --every finished jobs and a summary; exits 1 on any failure.

The in-process mode (--in-process) is the earlier soak: dry runs (or --weld) through one JobRunner in this
process, the robot parked at the job's first capture pose first.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import re
import sqlite3
import sys
import tempfile
import time
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from soak_daemon import Client, ServedDaemon  # noqa: E402
from soak_in_process import run_in_process_soak  # noqa: E402
from soak_memory import RSS_SLOPE_BOUND_MIB, TRACED_BOUND_MIB, MemoryVerdict, judge_memory, read_memory_log  # noqa: E402
from soak_plan import (  # noqa: E402
    ARC_OFF_WITHIN_S,
    DEFAULT_FAULTS,
    HOSTILE,
    FaultKind,
    PlannedJob,
    job_variant,
    plan_jobs,
    soak_config,
    toml_dumps,
)

__all__ = [
    "ARC_OFF_WITHIN_S",
    "DEFAULT_FAULTS",
    "HOSTILE",
    "Client",
    "FaultKind",
    "MemoryVerdict",
    "PlannedJob",
    "ServedDaemon",
    "job_variant",
    "judge_memory",
    "main",
    "plan_jobs",
    "print_summary",
    "read_memory_log",
    "run_daemon_soak",
    "run_in_process_soak",
    "soak_config",
    "toml_dumps",
]

OPERATOR = "soak"
FINAL_JOB_STATES = ("done", "failed", "cancelled", "dry_run", "interrupted")
DRY_NO_SEAM = ("failed", "no_seam")  # a dry run's other honest answer (check_api)


# ================================================================================================ the soak
@dataclass
class Submission:
    """One submission: its plan entry, the HTTP answer (``job_id`` None when refused) and what became of it."""

    planned: PlannedJob
    status: int
    job_id: int | None
    error: str | None = None
    injected: bool = False
    view: dict[str, Any] | None = None


@dataclass(frozen=True)
class Sample:
    """The daemon after ``finished`` jobs, ``t_s`` seconds into the soak: VmRSS (MiB) and threads."""

    finished: int
    t_s: float
    rss_mib: float
    threads: int


@dataclass
class SoakResult:
    """What a daemon soak saw; ``failures`` is empty when every check passed."""

    submissions: list[Submission] = field(default_factory=list)
    samples: list[Sample] = field(default_factory=list)
    idle_samples: list[Sample] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    acknowledged: int = 0
    injected: int = 0
    wall_s: float = 0.0
    api_records: int = 0
    db_rows: int = 0
    db_started_once: int = 0
    probe_id: int | None = None
    probe_error: str | None = None
    exit_code: int | None = None
    exit_s: float | None = None
    arc_line: str | None = None
    memory: MemoryVerdict | None = None
    hostile_ok: int = 0
    dry_no_seam: int = 0  # dry runs that found no seam from where the robot stood
    arc_off_s: dict[str, list[float]] = field(default_factory=dict)
    fault_s: dict[str, list[float]] = field(default_factory=dict)

    @property
    def accepted(self) -> list[Submission]:
        return [s for s in self.submissions if s.job_id is not None]

    def outcomes_by_kind(self) -> dict[str, collections.Counter[str]]:
        out: dict[str, collections.Counter[str]] = {}
        for s in self.submissions:
            if s.job_id is None:
                got = f"http {s.status}"
            elif s.view is None or s.view.get("report") is None:
                got = f"{(s.view or {}).get('state', '?')} (no report)"
            else:
                got = str(s.view["report"]["outcome"])
            out.setdefault(s.planned.kind, collections.Counter())[got] += 1
        return out


class DaemonSoak:
    """One soak run: see the module docstring. ``out``: where the progress lines go."""

    def __init__(
        self,
        client: Client,
        daemon: ServedDaemon,
        plan: list[PlannedJob],
        job: dict[str, Any],
        *,
        every: int,
        stall_s: float,
        out: TextIO,
    ) -> None:
        self.client = client
        self.daemon = daemon
        self.plan = plan
        self.job = job
        self.every = every
        self.stall_s = stall_s
        self.out = out
        self.result = SoakResult()
        self.outstanding: collections.deque[Submission] = collections.deque()
        self.t0 = time.monotonic()
        self.finished = 0
        self.outcomes: collections.Counter[str] = collections.Counter()

    def fail(self, text: str) -> None:
        self.result.failures.append(text)
        print(f"FAIL: {text}", file=self.out, flush=True)

    # ------------------------------------------------------------------------------------------ submitting
    def run(self) -> None:
        for planned in self.plan:
            fault = planned.fault
            if fault is not None and fault.when == "idle":
                self.drain()  # the fault must hit this job, not one queued before it
                self.inject(fault)
            if planned.kind == "hostile":
                self.hostile(planned)
            else:
                self.submit(planned)
            self.operate()
        self.drain()

    def submit(self, planned: PlannedJob) -> None:
        text = job_variant(self.job, planned).encode()
        query = "" if planned.weld else "?dry_run=1"
        status, answer = self.client.call("POST", f"/jobs{query}", text, content_type="application/toml")
        error = answer.get("error") if isinstance(answer, dict) else str(answer)
        if status == 201:
            sub = Submission(planned, status, int(answer["id"]))
            self.outstanding.append(sub)
        else:
            sub = Submission(planned, status, None, error)
            if planned.fault is None or planned.fault.outcome is not None:
                self.fail(f"job {planned.index} ({planned.kind}): POST /jobs answered {status}: {error}")
        self.result.submissions.append(sub)

    def hostile(self, planned: PlannedJob) -> None:
        """One hostile request (in turn from HOSTILE): it must get its 4xx, naming the rule, and queue nothing."""
        path, headers, body, want, words = HOSTILE[planned.occurrence % len(HOSTILE)]
        status, answer = self.client.call(
            "POST", path, body, content_type=headers.get("Content-Type", "text/plain"), extra_headers=headers
        )
        error = answer.get("error", "") if isinstance(answer, dict) else str(answer)
        sub = Submission(planned, status, None, error)
        self.result.submissions.append(sub)
        if status != want or words not in error or "root:" in error:
            self.fail(f"job {planned.index} (hostile {path}): want {want} naming {words!r}, got {status} {error!r}")
        else:
            self.result.hostile_ok += 1

    def inject(self, fault: FaultKind) -> None:
        status, answer = self.client.post(
            "/sim/faults", {"device": fault.device, "fault": fault.fault, "params": fault.params}
        )
        if status != 200:
            self.fail(f"injecting {fault.name}: {status} {answer}")
        else:
            self.result.injected += 1

    # ------------------------------------------------------------------------------------------ the operator
    def operate(self) -> None:
        """One look at the cell: acknowledge a fault (after clearing the simulated one), inject a fault due once a
        job's arc is on, and collect the jobs that finished (in order: the queue is FIFO)."""
        st = self.client.get("/status")
        if st["state"] == "fault":
            self.client.post("/sim/faults/clear", {})
            status, answer = self.client.post("/acknowledge", {"operator": OPERATOR})
            if status == 200 and answer.get("state") == "idle":
                self.result.acknowledged += 1
            else:
                self.fail(f"acknowledging {st['fault_reason']!r}: {status} {answer}")
            st = self.client.get("/status")
        current = st["current_job"]
        if current is not None and st["state"] == "welding":
            for sub in self.outstanding:
                fault = sub.planned.fault
                if sub.job_id == current["id"] and fault is not None and fault.when == "arc_on" and not sub.injected:
                    events = self.client.get(f"/jobs/{sub.job_id}")["events"]
                    if any(e["reason"].endswith(": arc on") for e in events):
                        self.inject(fault)
                        sub.injected = True
                        if fault.name in ("no_answer", "link_drop_arc"):
                            self.watch_arc_off(sub)
        while self.outstanding:
            sub = self.outstanding[0]
            view = self.client.get(f"/jobs/{sub.job_id}")
            if view["state"] not in FINAL_JOB_STATES:
                break
            if view["report"] is None:  # the report follows the final state, unless the runner never ran it
                now = self.client.get("/status")["current_job"]
                if now is not None and now["id"] == sub.job_id:
                    break
                view = self.client.get(f"/jobs/{sub.job_id}")  # the worker has let go of it: its last word
            self.outstanding.popleft()
            sub.view = view
            self.job_finished(sub)

    def watch_arc_off(self, sub: Submission) -> None:
        """After the link to the controller went away with the arc on: the simulated controller's own arc output
        (GET /sim/faults, the fake's state, not the driver's) must read off within ARC_OFF_WITHIN_S, and the cell
        must be in fault within 1 s."""
        t0 = time.monotonic()
        arc_off_s = fault_s = None
        while time.monotonic() - t0 < 5.0 and (arc_off_s is None or fault_s is None):
            view = self.client.get("/sim/faults")
            now = time.monotonic() - t0
            if arc_off_s is None and not view.get("arc_output_on", True):
                arc_off_s = now
            if fault_s is None and self.client.get("/status")["state"] == "fault":
                fault_s = now
            time.sleep(0.02)
        kind = sub.planned.kind
        self.result.arc_off_s.setdefault(kind, []).append(arc_off_s if arc_off_s is not None else math.inf)
        self.result.fault_s.setdefault(kind, []).append(fault_s if fault_s is not None else math.inf)
        if arc_off_s is None or arc_off_s > ARC_OFF_WITHIN_S:
            self.fail(f"job {sub.planned.index} ({kind}): the controller's arc output read on {arc_off_s} s after")
        if fault_s is None or fault_s > ARC_OFF_WITHIN_S:
            self.fail(f"job {sub.planned.index} ({kind}): the cell was in fault only after {fault_s} s")

    def job_finished(self, sub: Submission) -> None:
        self.finished += 1
        report = (sub.view or {}).get("report") or {}
        self.outcomes[str(report.get("outcome", sub.view and sub.view["state"]))] += 1
        rss, threads = self.daemon.proc_status()
        sample = Sample(self.finished, time.monotonic() - self.t0, rss, threads)
        self.result.samples.append(sample)
        if self.every and (self.finished % self.every == 0 or self.finished == len(self.result.accepted)):
            print(
                f"{self.finished:4d} jobs  {sample.t_s:7.1f} s  rss {rss:7.1f} MiB  threads {threads:3d}  "
                f"acks {self.result.acknowledged:2d}  {dict(sorted(self.outcomes.items()))}",
                file=self.out,
                flush=True,
            )

    def drain(self) -> None:
        """Operate until every submitted job has finished and the cell is idle, nothing queued; then sample the
        idle daemon."""
        last_progress, finished = time.monotonic(), self.finished
        while True:
            self.operate()
            if self.finished != finished:
                last_progress, finished = time.monotonic(), self.finished
            if not self.outstanding:
                st = self.client.get("/status")
                if st["current_job"] is None and not st["queued"] and st["state"] != "fault":
                    break
            if time.monotonic() - last_progress > self.stall_s:
                waiting = [s.job_id for s in self.outstanding]
                raise RuntimeError(f"no job finished for {self.stall_s:.0f} s; waiting for {waiting}")
            time.sleep(0.1)
        rss, threads = self.daemon.settled_status()
        self.result.idle_samples.append(Sample(self.finished, time.monotonic() - self.t0, rss, threads))

    # ------------------------------------------------------------------------------------------ checks
    def check_api(self) -> None:
        """Every submission's final state, outcome and error through the API, and the /metrics counters."""
        expected_outcomes: collections.Counter[str] = collections.Counter()
        for sub in self.result.submissions:
            p, f = sub.planned, sub.planned.fault
            if p.kind == "malformed":
                ok = 400 <= sub.status < 500 and any(k in (sub.error or "") for k in ("unknown key", "malformed TOML"))
                if not ok:
                    self.fail(f"job {p.index} (malformed): want a 4xx naming the problem, got {sub.status} {sub.error}")
                continue
            if p.kind == "hostile":
                continue  # checked as it was sent
            if f is not None and f.outcome is None:  # refused at submission (a job over the cell's limits)
                if not (400 <= sub.status < 500 and f.error in (sub.error or "")):
                    self.fail(f"job {p.index} ({p.kind}): want a 4xx naming {f.error!r}, got {sub.status} {sub.error}")
                continue
            if sub.job_id is None:
                continue  # already failed at submission
            view = self.client.get(f"/jobs/{sub.job_id}")
            sub.view = view
            self.result.api_records += 1
            report = view.get("report") or {}
            if f is not None:
                want = (f.state, f.outcome)
            else:
                want = ("done", "welded") if p.weld else ("dry_run", "dry_run")
            got = (view["state"], report.get("outcome"))
            if f is None and not p.weld and got == DRY_NO_SEAM and "no seam" in (view.get("error") or "").lower():
                # a dry run captures where the robot stands (home, after a weld), a view the job was not planned
                # for: the detector may find no seam there, and saying so is the right answer, counted apart
                want = DRY_NO_SEAM
                self.result.dry_no_seam += 1
            expected_outcomes[str(want[1])] += 1
            where = f"job {p.index} (id {sub.job_id}, {p.kind})"
            if got != want:
                self.fail(f"{where}: want {want}, got {got}: {view.get('error')}")
            elif f is not None and not any(w.lower() in (view.get("error") or "").lower() for w in f.error.split("|")):
                self.fail(f"{where}: the error does not say {f.error!r}: {view.get('error')}")
            elif p.weld and f is None and not report.get("seams_welded"):
                self.fail(f"{where}: welded no seam: {report}")
            elif f is not None and f.when == "arc_on" and not sub.injected:
                self.fail(f"{where}: the fault was never injected (no arc on seen)")
        metrics = str(self.client.get("/metrics"))
        for outcome, n in expected_outcomes.items():
            line = f'weldcell_jobs_finished_total{{outcome="{outcome}"}} {float(n)}'  # prometheus-client: 3.0
            if line not in metrics:
                found = re.findall(rf'weldcell_jobs_finished_total{{outcome="{outcome}"}} [\d.]+', metrics)
                self.fail(f"/metrics: want {line!r}, got {found}")

    def probe_sigterm(self, *, mid_weld: bool, timeout_s: float) -> None:
        """SIGTERM the daemon (once a welding job's arc is on when ``mid_weld``): exit 0, the arc reads off."""
        if mid_weld:
            planned = PlannedJob(len(self.plan) + 1, "sigterm_probe", True)
            status, answer = self.client.call(
                "POST", "/jobs", job_variant(self.job, planned).encode(), content_type="application/toml"
            )
            if status != 201:
                self.fail(f"the SIGTERM probe job was refused: {status} {answer}")
            else:
                self.result.probe_id = int(answer["id"])
                deadline = time.monotonic() + timeout_s
                while time.monotonic() < deadline:
                    events = self.client.get(f"/jobs/{self.result.probe_id}")["events"]
                    if any(e["reason"].endswith(": arc on") for e in events):
                        break
                    time.sleep(0.1)
                else:
                    self.fail(f"the SIGTERM probe job {self.result.probe_id} never switched the arc on")
        self.result.exit_code = self.daemon.stop()
        self.result.exit_s = self.daemon.exit_s
        try:
            found = self.daemon.wait_line(r"arc output \d+ .*", timeout_s=5)
            self.result.arc_line = found.group(0)
        except RuntimeError:
            self.result.arc_line = None
        if self.result.exit_code != 0:
            self.fail(f"the daemon exited with {self.result.exit_code} on SIGTERM")
        if self.result.arc_line is None or not self.result.arc_line.endswith("reads off"):
            self.fail(f"the daemon did not confirm the arc off at exit: {self.result.arc_line!r}")

    def check_journal(self, path: Path) -> None:
        """The SQLite journal itself: one row per accepted job (named by its workpiece), each started once."""
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            rows = db.execute("SELECT id, job_file, state, error FROM jobs ORDER BY id").fetchall()
            starts = dict(
                db.execute(
                    "SELECT job_id, COUNT(*) FROM events WHERE to_state = 'homing' AND from_state IN ('idle', 'done') "
                    "GROUP BY job_id"
                ).fetchall()
            )
        finally:
            db.close()
        self.result.db_rows = len(rows)
        by_id = {int(r[0]): r for r in rows}
        expected = {s.job_id: s for s in self.result.accepted if s.job_id is not None}
        if self.result.probe_id is not None:
            expected_ids = {*expected, self.result.probe_id}
        else:
            expected_ids = set(expected)
        if set(by_id) != expected_ids:
            self.fail(
                f"journal rows {sorted(set(by_id) - expected_ids)} were never submitted, "
                f"submitted jobs {sorted(expected_ids - set(by_id))} have no row"
            )
        names = collections.Counter(m.group(1) for r in rows if (m := re.search(r"soak-(\d{3})-", r[1])))
        twice = sorted(k for k, n in names.items() if n != 1)
        if twice:
            self.fail(f"soak jobs recorded more than once: {twice}")
        for job_id, sub in expected.items():
            row = by_id.get(job_id)
            if row is None:
                continue
            tag = f"soak-{sub.planned.index:03d}-{sub.planned.kind}-"
            if tag not in row[1]:
                self.fail(f"journal row {job_id} is {row[1]}, not {tag}...")
            if sub.view is not None and row[2] != sub.view["state"]:
                self.fail(f"journal row {job_id}: state {row[2]}, the API said {sub.view['state']}")
            if starts.get(job_id, 0) != 1:
                self.fail(f"journal: job {job_id} ({tag}) started {starts.get(job_id, 0)} times")
            else:
                self.result.db_started_once += 1
        if self.result.probe_id is not None:
            row = by_id.get(self.result.probe_id)
            self.result.probe_error = None if row is None else row[3]
            if row is None or row[2] != "failed" or "SIGTERM" not in (row[3] or ""):
                self.fail(f"the SIGTERM probe job {self.result.probe_id}: want failed by SIGTERM, got {row}")

    def check_resources(
        self, memory_log: Path, *, warmup: int, traced_bound_mib: float, rss_slope_bound_mib: float
    ) -> None:
        """The memory rule (scripts/soak_memory.py) on the daemon's ``memory_log``, and the idle thread count."""
        records = read_memory_log(memory_log)
        deadline = time.monotonic() + 10.0
        while len(records) < self.finished and time.monotonic() < deadline:
            time.sleep(0.2)  # the worker writes the last job's line once it has let go of that job
            records = read_memory_log(memory_log)
        verdict = judge_memory(
            records,
            warmup=warmup,
            traced_bound_mib=traced_bound_mib,
            rss_slope_bound_mib=rss_slope_bound_mib,
        )
        self.result.memory = verdict
        for text in verdict.failures:
            self.fail(text)
        idle = [s.threads for s in self.result.idle_samples if s.finished >= warmup] or [
            s.threads for s in self.result.idle_samples[-1:]
        ]
        if len(set(idle)) > 1:
            self.fail(f"the idle daemon's thread count changed: {idle}")


@contextmanager
def _workdir(path: str | None) -> Iterator[Path]:
    if path is not None:
        Path(path).mkdir(parents=True, exist_ok=True)
        yield Path(path).resolve()
    else:
        with tempfile.TemporaryDirectory(prefix="weldcell-soak-") as tmp:
            yield Path(tmp)


def run_daemon_soak(
    *,
    config: str | os.PathLike[str],
    job: str | os.PathLike[str],
    jobs: int = 100,
    fault_every: int = 7,
    weld_every: int = 10,
    faults: tuple[str, ...] = DEFAULT_FAULTS,
    warmup: int = 20,
    traced_bound_mib: float = TRACED_BOUND_MIB,
    rss_slope_bound_mib: float = RSS_SLOPE_BOUND_MIB,
    sigterm_mid_weld: bool = True,
    every: int = 10,
    stall_s: float = 300.0,
    workdir: str | None = None,
    out: TextIO = sys.stdout,
) -> SoakResult:
    """Run the daemon soak (see the module docstring) and return what it saw; prints progress to ``out``."""
    plan = plan_jobs(jobs, fault_every=fault_every, weld_every=weld_every, faults=faults)
    job_data = tomllib.loads(Path(job).read_text(encoding="utf-8"))
    t0 = time.monotonic()
    with _workdir(workdir) as wd:
        config_path, config_data = soak_config(Path(config), wd)
        daemon = ServedDaemon(config_path, wd / "daemon.log", memory_log=wd / "memory.jsonl")
        try:
            found = daemon.wait_line(r"listening on (http://\S+)", timeout_s=120)
            client = Client(found.group(1), config_data.get("daemon", {}).get("token"))
            soak = DaemonSoak(client, daemon, plan, job_data, every=every, stall_s=stall_s, out=out)
            soak.t0 = t0
            print(
                f"soak: daemon pid {daemon.pid} at {client.base}, {len(plan)} jobs planned: "
                f"{dict(collections.Counter(p.kind for p in plan))}; work folder {wd}",
                file=out,
                flush=True,
            )
            try:
                soak.run()
                soak.check_api()
                soak.check_resources(
                    wd / "memory.jsonl",
                    warmup=warmup,
                    traced_bound_mib=traced_bound_mib,
                    rss_slope_bound_mib=rss_slope_bound_mib,
                )
            except (RuntimeError, OSError) as err:
                soak.fail(f"the soak stopped: {err}")
            soak.probe_sigterm(mid_weld=sigterm_mid_weld, timeout_s=stall_s)
            soak.result.wall_s = time.monotonic() - t0
            soak.check_journal(wd / "journal.sqlite3")
            samples = {
                "jobs": [s.__dict__ for s in soak.result.samples],
                "idle": [s.__dict__ for s in soak.result.idle_samples],
            }
            (wd / "samples.json").write_text(json.dumps(samples, indent=1), encoding="utf-8")
        finally:
            daemon.close()
    return soak.result


def print_summary(result: SoakResult, out: TextIO = sys.stdout) -> None:
    def p(text: str) -> None:
        print(text, file=out)

    refused = [s for s in result.submissions if s.job_id is None]
    p(f"\nsoak summary ({result.wall_s:.1f} s wall)")
    p(
        f"  submissions {len(result.submissions)}: {len(result.accepted)} accepted, "
        f"{len(refused)} refused ({', '.join(f'{s.planned.index}: {s.status}' for s in refused) or '-'})"
    )
    for kind, counts in sorted(result.outcomes_by_kind().items()):
        p(f"    {kind:<17} {sum(counts.values()):3d}  {dict(counts)}")
    p(f"  faults injected {result.injected}, acknowledged {result.acknowledged}")
    for kind in sorted(result.arc_off_s):
        arcs, faults = result.arc_off_s[kind], result.fault_s.get(kind, [])
        p(
            f"    {kind}: arc off (the controller's output) after {', '.join(f'{t:.2f}' for t in arcs)} s; "
            f"cell in fault after {', '.join(f'{t:.2f}' for t in faults)} s"
        )
    p(f"  hostile requests answered as they must: {result.hostile_ok}")
    p(f"  dry runs with no seam from where the robot stood (home): {result.dry_no_seam}")
    p(
        f"  records: API {result.api_records}/{len(result.accepted)}; SQLite {result.db_rows} rows "
        f"({len(result.accepted)} jobs{' + the SIGTERM probe' if result.probe_id is not None else ''}), "
        f"{result.db_started_once} started exactly once"
    )
    s = result.samples
    if s:
        top = max(s, key=lambda x: x.rss_mib)
        p(
            f"  rss MiB: first {s[0].rss_mib:.1f} (job {s[0].finished}), last {s[-1].rss_mib:.1f} "
            f"(job {s[-1].finished}), max {top.rss_mib:.1f} (job {top.finished})"
        )
        m = result.memory
        if m is not None and m.samples:
            p(
                f"  memory after warm-up ({m.samples} samples, idle after malloc_trim): traced (tracemalloc) median "
                f"{m.traced_first_mib:.1f} MiB first third, {m.traced_last_mib:.1f} MiB last third "
                f"({m.traced_growth_mib:+.1f}); resident {m.rss_first_mib:.1f} -> {m.rss_last_mib:.1f} MiB, "
                f"{m.rss_slope_mib:+.2f} MiB per job from job {m.rss_from_n}"
            )
        p("  rss when idle (jobs: MiB): " + ", ".join(f"{x.finished}: {x.rss_mib:.1f}" for x in result.idle_samples))
        step = max(1, len(s) // 20)
        series = list(s[::step]) + ([s[-1]] if (len(s) - 1) % step else [])
        p("  rss series (jobs: MiB): " + ", ".join(f"{x.finished}: {x.rss_mib:.1f}" for x in series))
        p(
            f"  threads at job ends: min {min(x.threads for x in s)}, max {max(x.threads for x in s)}; when idle: "
            + ", ".join(f"{x.finished}: {x.threads}" for x in result.idle_samples)
        )
    took = f" after {result.exit_s:.1f} s" if result.exit_s is not None else ""
    p(f"  SIGTERM: exit code {result.exit_code}{took}, {result.arc_line!r}")
    if result.probe_id is not None:
        p(f"    probe job {result.probe_id}: {result.probe_error}")
    p(f"  failures: {len(result.failures)}")
    for f in result.failures:
        p(f"    - {f}")


# ================================================================================================ main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPO / "examples" / "sim-cell-fanuc.toml"))
    parser.add_argument("--job", default=str(REPO / "examples" / "jobs" / "ribs.toml"))
    parser.add_argument("--jobs", type=int, default=100, help="how many jobs (default 100)")
    parser.add_argument("--every", type=int, default=10, help="print a line every N finished jobs")
    parser.add_argument("--fault-every", type=int, default=7, help="every Nth job is a fault (0: none)")
    parser.add_argument("--weld-every", type=int, default=10, help="every Nth job welds (0: only after faults)")
    parser.add_argument(
        "--faults",
        default=",".join(DEFAULT_FAULTS),
        help=f"the fault kinds, in turn (default {','.join(DEFAULT_FAULTS)})",
    )
    parser.add_argument("--warmup", type=int, default=20, help="jobs before memory growth counts (default 20)")
    parser.add_argument(
        "--traced-bound-mib",
        type=float,
        default=TRACED_BOUND_MIB,
        help=f"allowed growth of live Python memory after warm-up, MiB (default {TRACED_BOUND_MIB:g})",
    )
    parser.add_argument(
        "--rss-slope-mib",
        type=float,
        default=RSS_SLOPE_BOUND_MIB,
        help=f"allowed resident growth per job over the last half, MiB (default {RSS_SLOPE_BOUND_MIB:g})",
    )
    parser.add_argument("--no-sigterm-probe", action="store_true", help="SIGTERM the idle daemon, not mid-weld")
    parser.add_argument("--workdir", default=None, help="keep the config copy, journal and daemon log here")
    parser.add_argument("--in-process", action="store_true", help="the runner alone in this process (no daemon)")
    parser.add_argument("--weld", action="store_true", help="--in-process: weld every job instead of dry runs")
    args = parser.parse_args(argv)

    if args.in_process:
        return run_in_process_soak(args.config, args.job, jobs=args.jobs, weld=args.weld, every=args.every)
    result = run_daemon_soak(
        config=args.config,
        job=args.job,
        jobs=args.jobs,
        fault_every=args.fault_every,
        weld_every=args.weld_every,
        faults=tuple(f.strip() for f in args.faults.split(",") if f.strip()),
        warmup=args.warmup,
        traced_bound_mib=args.traced_bound_mib,
        rss_slope_bound_mib=args.rss_slope_mib,
        sigterm_mid_weld=not args.no_sigterm_probe,
        every=args.every,
        workdir=args.workdir,
    )
    print_summary(result)
    return 1 if result.failures else 0


if __name__ == "__main__":
    sys.exit(main())
