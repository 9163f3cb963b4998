"""``weldcell serve``: the cell as a small HTTP service, running jobs one at a time.

This module is the service itself: the job queue and its worker, approvals, the operator commands (acknowledge,
pause, resume, abort), the status the page and clients read, and a safe shutdown. Around it, each in a module of
its own: the HTTP layer and its guards (:mod:`cell.http_api`), the operator page (:mod:`cell.operator_page`, what it
shows: :mod:`cell.operator_view`, :mod:`cell.fault_text`), the metrics (:mod:`cell.metrics`), the test-only fault
switches (:mod:`cell.sim_fault_api`), the exports of finished jobs (:mod:`cell.job_exports`) and the allocator tuning
(:mod:`cell.memory`).

Endpoints (JSON unless said otherwise; ``GET /openapi.json`` describes them; with ``[daemon] token`` every request
but the page's own HTML needs ``Authorization: Bearer <token>``, and the config refuses a non-loopback ``host``
without a token; Host, Origin, size and time checks in :mod:`cell.http_api`)::

    POST /jobs                   body: a job's TOML text, or JSON {"path": "job.toml"} (in the jobs directory) or
                                 {"toml": "..."}; checked against the cell's limits before it is queued;
                                 ?dry_run=1 (or "dry_run": true) plans and validates only -> 201 {"id", "state"}
    GET  /jobs                   the recent jobs, newest first
    GET  /jobs/{id}              one job: state, report, error and its journaled events
    GET  /jobs/{id}/export/{fmt} a finished job's seams and path as urscript, ls, rosbag2 (zip), gltf or html
    POST /jobs/{id}/approve      {"operator": "name"}: approve the planned path of a job awaiting approval
    POST /jobs/{id}/reject       {"operator": "name"}: refuse it (the job ends cancelled, nothing moves)
    POST /acknowledge            {"operator": "name"}: leave fault (latched device faults are cleared)
    POST /pause, /resume, /abort {"operator": "name"}: pause (motion stopped, arc off), resume where it stopped,
                                 or give the paused job up (the torch retracts, the job ends cancelled)
    GET  /status                 {"state", "fault_reason", "fault", "last_fault", "current_job" (with its
                                 progress), "queued", "recent_jobs", "interrupted", "devices", "overlay", ...}
    GET  /                       the operator page (docs/operator-page.md)
    GET  /status.png             the overlay of the last capture (PNG)
    GET  /metrics                Prometheus text format

Test only, with ``weldcell serve --sim-faults`` (``Daemon(sim_faults=True)``; :mod:`cell.sim_fault_api`), which is
refused unless every device is a simulator this daemon started itself::

    GET  /sim/faults             the simulated devices, the faults each supports and the faults injected
    POST /sim/faults             {"device": "robot" | "track" | "camera", "fault": "...", "params": {...}}
    POST /sim/faults/clear       {"device": ...} or {}: switch that simulator's (every simulator's) faults off; a
                                 latched stop or drive fault stays latched until POST /acknowledge clears it

Without the switch these paths answer 404 and no fault switch exists in the process.

Jobs wait in a FIFO queue; while the cell is in fault they wait for the acknowledgement. Everything goes to the
journal (cell.journal); a job found queued or running when the daemon starts (it was killed) is reported as
``interrupted`` and never resumed, and when one was running the cell starts in ``fault`` ("unclean stop"): no
motion before an operator's acknowledgement. That fault is journaled: a daemon restarted again before anyone
acknowledged starts in it too (:meth:`cell.journal.Journal.unclean_stop`, as ``weldcell run`` checks).
:meth:`Daemon.shutdown` (SIGTERM, Ctrl-C) stops the motion and switches the arc off through the state machine's
``fault_now`` before anything else, cancels the queued jobs, then closes the devices and the journal; the arc output
is then switched off once more and read back (:attr:`Daemon.arc_on_at_exit`).

Pause and resume: a pause stops the robot and the track where they are and switches the arc off at once (the
state machine's ``request_pause``: the arm stands still, the arc is off, the job waits in ``paused``). Resume goes
back to the paused state; a seam paused while welding is welded on from the last travel pose the robot reached
(the torch comes down onto that pose from above along its own axis, the arc comes on there), the seams before it
stay welded and the ones after follow. Abort (from ``paused``) retracts the torch and ends the job cancelled.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import re
import threading
import time
from dataclasses import dataclass
from http import HTTPStatus
from pathlib import Path
from typing import Any

from cell.config import CellConfig
from cell.errors import ConfigError, WeldcellError
from cell.factory import Cell, build_cell, real_devices
from cell.fault_text import explain_fault
from cell.http_api import HttpServer, build_app, listen
from cell.job import FileRules, Job, job_from_text, load_job
from cell.job_exports import Exported, export_job, save_job_result
from cell.job_report import CYCLE_PHASES, JobReport
from cell.journal import JobRecord, Journal
from cell.machine import PAUSABLE, CellState
from cell.memory import MemoryLog, limit_malloc_arenas, memory_log_from_env, release_freed_memory
from cell.metrics import CellMetrics, DaemonSnapshot
from cell.operator_view import devices_view, job_view, overlay_view, progress_view
from cell.planning import WeldPath
from cell.request_parsing import body_text, parse_flag, parse_json_object
from cell.runner import CellBusy, JobRunner
from cell.sim_fault_api import SimFaultSwitch
from perception.helper_process import HelperProcess

logger = logging.getLogger(__name__)


def _warm_detector() -> None:
    """Import the detector and run its compiled kernels once (the first job would wait for it: about a second,
    7 s on a machine's first run); a failure here is only logged (the job then loads them itself)."""
    try:
        from perception.helper_process import preload

        preload()
    except Exception as err:  # never fatal: the job loads what it needs
        logger.warning("could not warm up the detector: %s", err)

ACTIVE_STATES = frozenset(CellState) - {CellState.IDLE, CellState.DONE, CellState.FAULT}
FINAL_JOB_STATES = ("done", "failed", "cancelled", "dry_run", "interrupted")


@dataclass(frozen=True)
class _Queued:
    job_id: int
    job: Job
    dry_run: bool


class _Approval:
    """A pending approval of the running job's path: the HTTP thread answers, the runner's thread waits."""

    def __init__(self, job_id: int) -> None:
        self.job_id = job_id
        self.event = threading.Event()
        self.operator: str | None = None


class Daemon:
    """The cell service. ``cell``: devices to use (None: built from ``config``, starting its simulators when
    ``start_simulators``). ``sim_faults``: serve the test-only ``/sim/faults`` endpoints (ConfigError unless every
    device is a simulator started here). Call :meth:`start`, then :meth:`shutdown` (or use it as a context
    manager)."""

    def __init__(
        self,
        config: CellConfig,
        *,
        start_simulators: bool = True,
        cell: Cell | None = None,
        sim_faults: bool = False,
    ) -> None:
        if sim_faults:  # refused before anything is opened or connected
            _check_sim_faults_allowed(config, own_simulators=cell is not None or start_simulators)
        self.config = config
        dc = config.daemon
        self.journal = Journal(config.resolve(dc.journal))
        self.interrupted: tuple[JobRecord, ...] = self.journal.interrupted
        self.submitted_dir = (self.journal.path.parent / "jobs").resolve()  # copies of the jobs sent as text
        self.results_dir = (self.journal.path.parent / "results").resolve()  # what each job's exports need
        self.jobs_dir = config.resolve(dc.jobs_dir).resolve() if dc.jobs_dir is not None else self.submitted_dir
        self.captures_dir = (
            config.resolve(dc.captures_dir) if dc.captures_dir is not None else self.journal.path.parent / "captures"
        ).resolve()
        self.status_image = config.resolve(dc.status_image)
        self._own_cell = cell is None
        self.sim: SimFaultSwitch | None = None
        try:
            self.cell = cell if cell is not None else build_cell(config, start_simulators=start_simulators)
            if self._own_cell:
                self.cell.connect()
            # the surfaces method's second process starts now and warms up while the daemon waits for its first job
            uses_helper = config.detection.helper_process and config.detection.method == "surfaces"
            self.helper = HelperProcess() if uses_helper else None
            if config.detection.method == "surfaces":  # the detector's modules and compiled kernels, loaded meanwhile
                threading.Thread(target=_warm_detector, name="detector-warm-up", daemon=True).start()
            self.runner = JobRunner(self.cell, journal=self.journal, status_image=self.status_image,
                                    helper=self.helper)  # fmt: skip
            self.runner.switch_arc_off()  # the previous process may have died with the arc on
            if sim_faults:
                self.sim = SimFaultSwitch(
                    self.cell.fault_injectors(), note=self._journal_note, arc_output=lambda: self.runner.arc_output
                )
        except BaseException:
            if self._own_cell and cell is None and hasattr(self, "cell"):
                self.cell.close()
            helper = getattr(self, "helper", None)
            if helper is not None:
                helper.close()
            self.journal.close()
            raise
        self._queue: queue.Queue[_Queued | None] = queue.Queue()
        self._queued: dict[int, _Queued] = {}
        self._lock = threading.Lock()
        self._current: _Queued | None = None
        self._approval: _Approval | None = None
        self._stopping = threading.Event()
        self._totals = {"seams_welded": 0, "poses_sent": 0, "arc_time_s": 0.0}
        self._outcomes: dict[str, int] = {}
        self._last_cycle: dict[str, float] = {}
        self._last_fault: dict[str, Any] | None = None
        self.metrics_registry = CellMetrics(snapshot=self._snapshot)
        self.arc_on_at_exit: bool | None = None
        """After :meth:`shutdown`: whether the arc output read on (None: it could not be read back)."""
        self._memory_log: MemoryLog | None = None
        self._worker = threading.Thread(target=self._work, name="weldcell-jobs", daemon=True)
        self._serve(dc)
        self._report_previous_run()

    def _serve(self, dc: Any) -> None:
        try:
            sock = listen(dc.host, dc.port)
        except OSError:
            if self.helper is not None:
                self.helper.close()
            if self._own_cell:
                self.cell.close()
            self.journal.close()
            raise
        self._address = sock.getsockname()[:2]
        self.app = build_app(self, int(self._address[1]))
        self.http = HttpServer(self.app, sock, timeout_s=dc.request_timeout_s, max_connections=dc.max_connections)

    def _report_previous_run(self) -> None:
        for record in self.interrupted:
            logger.warning(
                "job %d (%s) was interrupted by the previous daemon: not resumed", record.id, record.job_file
            )
        # a job was running when the previous process stopped (this start found it, or an earlier one did and nobody
        # acknowledged since): the torch may stand on the part, nothing moves before an operator has looked
        unclean = self.journal.unclean_stop(then="acknowledge (POST /acknowledge)")
        if unclean is not None:
            self.runner.machine.fault_now(unclean)
        if self.sim is not None:
            logger.warning(
                "test-only fault injection is on (/sim/faults) for the simulated %s", ", ".join(self.sim.injectors)
            )

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._address
        return str(host), int(port)

    @property
    def sim_faults(self) -> bool:
        """Whether the test-only ``/sim/faults`` endpoints are served."""
        return self.sim is not None

    def start(self) -> Daemon:
        limit_malloc_arenas()  # before the worker and HTTP threads exist
        self._memory_log = memory_log_from_env()  # WELDCELL_MEMORY_SNAPSHOTS: the soak's leak figures
        self._worker.start()
        self.http.start()
        host, port = self.address
        logger.info("weldcell daemon listening on http://%s:%d", host, port)
        return self

    def __enter__(self) -> Daemon:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.shutdown("daemon closed")

    # ------------------------------------------------------------------------------------------ jobs
    def submit(self, job: Job, *, dry_run: bool = False) -> int:
        """Queue ``job`` (journaled as queued); returns its id."""
        if self._stopping.is_set():
            raise WeldcellError("the daemon is stopping: no new jobs")
        job_id = self.journal.submit(job.source)
        item = _Queued(job_id, job, dry_run)
        with self._lock:
            self._queued[job_id] = item
        self._queue.put(item)
        logger.info("job %d (%s) queued%s", job_id, job.workpiece, " (dry run)" if dry_run else "")
        return job_id

    def job_from_request(self, body: bytes, content_type: str, dry_run_query: str | None = None) -> tuple[Job, bool]:
        """A job from a POST /jobs body (ConfigError for a bad one, checked against the cell's limits). Returns
        (job, dry_run): ``dry_run`` from the JSON body's ``"dry_run"`` (a JSON boolean) or the ``?dry_run=``
        query (``1|true|yes`` or ``0|false|no``). Files named by the job must be inside the configured directories
        (:attr:`jobs_dir` for job files, it, :attr:`captures_dir` or :attr:`submitted_dir` for prompts files); a
        job sent as text is kept in :attr:`submitted_dir` (``jobs`` next to the journal), never in jobs_dir."""
        dry_run = parse_flag(dry_run_query, "?dry_run") if dry_run_query is not None else False
        text = body_text(body)
        roots = tuple(dict.fromkeys((self.jobs_dir, self.captures_dir, self.submitted_dir)))
        rules = FileRules(roots, self.config.daemon.max_file_bytes)
        if "json" in content_type.lower():
            obj = parse_json_object(text)
            unknown = sorted(set(obj) - {"path", "toml", "dry_run"})
            if unknown or ("path" in obj) == ("toml" in obj):
                raise ConfigError('send {"path": "job.toml"} or {"toml": "<job text>"} (one of them), and "dry_run"')
            if "dry_run" in obj:
                if not isinstance(obj["dry_run"], bool):
                    raise ConfigError('"dry_run" must be a JSON boolean (true or false)')
                dry_run = dry_run or obj["dry_run"]
            if "path" in obj:
                if not isinstance(obj["path"], str) or not obj["path"] or "\x00" in obj["path"]:
                    raise ConfigError('"path" must be a file name in the jobs directory')
                given = Path(obj["path"])
                path = FileRules((self.jobs_dir,), rules.max_bytes).check(
                    given if given.is_absolute() else self.jobs_dir / given, f"job file {obj['path']!r}"
                )
                job = load_job(path, rules=rules)
                self.runner.check_job(job)
                return job, dry_run
            if not isinstance(obj["toml"], str):
                raise ConfigError('"toml" must be the job file\'s text (a JSON string)')
            text = obj["toml"]
        if len(text.encode("utf-8")) > rules.max_bytes:
            raise ConfigError(f"the job is larger than the {rules.max_bytes} bytes allowed")
        job = job_from_text(text, source="<http job>", base_dir=self.jobs_dir, rules=rules)
        self.runner.check_job(job)
        self.submitted_dir.mkdir(parents=True, exist_ok=True)
        name = re.sub(r"[^A-Za-z0-9_.-]+", "-", job.workpiece)[:40] or "job"
        path = self.submitted_dir / f"{time.strftime('%Y%m%d-%H%M%S')}-{time.monotonic_ns() % 10**9:09d}-{name}.toml"
        path.write_text(text, encoding="utf-8")
        return job_from_text(text, source=str(path), base_dir=self.jobs_dir, rules=rules), dry_run

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is None or self._stopping.is_set():
                return
            while self.runner.machine.state is CellState.FAULT and not self._stopping.is_set():
                time.sleep(0.1)  # the queue waits for an operator's acknowledgement
            if self._stopping.is_set():
                return
            with self._lock:
                self._queued.pop(item.job_id, None)
                self._current = item
            try:
                report = self.runner.run(
                    item.job, job_id=item.job_id, dry_run=item.dry_run, approve=self._wait_approval
                )
                self._count(report)
                self._keep_result(item.job_id)
            except WeldcellError as err:
                logger.error("job %d could not run: %s", item.job_id, err)
                self.journal.record_state_change(
                    item.job_id, "queued", "failed", str(err), job_state="failed", error=str(err)
                )
            except Exception as err:  # the worker must survive one bad job
                logger.exception("job %d crashed the runner", item.job_id)
                self.journal.record_state_change(
                    item.job_id, "queued", "failed", f"runner error: {err}", job_state="failed", error=str(err)
                )
            finally:
                with self._lock:
                    self._current = None
                release_freed_memory()
                self._record_memory(item.job_id)

    def _record_memory(self, job_id: int) -> None:
        """The memory figures after a job, once its memory is released (with WELDCELL_MEMORY_SNAPSHOTS only)."""
        if self._memory_log is None:
            return
        try:
            self._memory_log.record(job_id)
        except Exception:  # a measurement must never stop the cell
            logger.exception("job %d: cannot record the memory figures", job_id)

    def _count(self, report: JobReport) -> None:
        with self._lock:
            self._outcomes[report.outcome] = self._outcomes.get(report.outcome, 0) + 1
            self._totals["seams_welded"] += report.seams_welded
            self._totals["poses_sent"] += report.poses_sent
            self._totals["arc_time_s"] += report.arc_time_s
            self._last_cycle = dict(report.cycle_s)
        self.metrics_registry.observe_job(report.cycle_s.get("total", 0.0), report.outcome)

    def _keep_result(self, job_id: int) -> None:
        data = self.runner.current
        if data is None or data.job_id != job_id:
            return
        try:
            save_job_result(self.results_dir / str(job_id), data)
        except Exception:  # the exports are a convenience: the job's outcome stands
            logger.exception("job %d: cannot keep its result for the exports", job_id)

    def _wait_approval(self, path: WeldPath) -> str | None:
        current = self._current
        if current is None:
            return None
        approval = _Approval(current.job_id)
        with self._lock:
            self._approval = approval
        logger.info("job %d: %d pass(es) planned, waiting for approval", current.job_id, len(path.passes))
        while not approval.event.wait(0.2):
            if self._stopping.is_set():
                break
        with self._lock:
            self._approval = None
        return approval.operator

    def answer_approval(self, job_id: int, operator: str | None) -> bool:
        """Approve (``operator``) or reject (None) the path of job ``job_id``; False when it is not waiting."""
        with self._lock:
            approval = self._approval
        if approval is None or approval.job_id != job_id:
            return False
        approval.operator = operator
        approval.event.set()
        return True

    # ------------------------------------------------------------------------------------------ views
    def status(self) -> dict[str, Any]:
        """GET /status: the cell's state and fault, the current job and its progress, the queue, the recent and
        interrupted jobs, the devices and the arc, and the seams of the capture being welded."""
        m = self.runner.machine
        state = m.state
        with self._lock:
            current = self._current
            queued = sorted(self._queued)
            awaiting = self._approval.job_id if self._approval is not None else None
            last_fault = dict(self._last_fault) if self._last_fault is not None else None
        data = self.runner.current
        ours = data if data is not None and current is not None and data.job_id == current.job_id else None
        current_view = None
        if current is not None:
            current_view = {
                "id": current.job_id,
                "workpiece": current.job.workpiece,
                "dry_run": current.dry_run,
                "awaiting_approval": awaiting == current.job_id,
                "seams_welded": ours.seams_welded if ours is not None else 0,
                "progress": progress_view(ours, state) if ours is not None else {"phase": state.value},
            }
        fault_reason = m.fault_reason if state is CellState.FAULT else None
        fault = explain_fault(fault_reason)
        if fault is not None:
            last_fault = {"reason": fault_reason, **fault.to_dict(), "acknowledged_by": None}
        return {
            "state": state.value,
            "fault_reason": fault_reason,
            "fault": fault.to_dict() if fault is not None else None,
            "last_fault": last_fault,
            "current_job": current_view,
            "queued": queued,
            "recent_jobs": [job_view(r) for r in self.journal.recent_jobs(self.config.daemon.recent_jobs)],
            "interrupted": [job_view(r) for r in self.interrupted],
            "sim_faults": self.sim is not None,
            "devices": self.devices(),
            "overlay": self._overlay(state),
            "token_required": self.config.daemon.token is not None,
        }

    def devices(self) -> dict[str, Any]:
        """The robot, the track, the camera and the arc output (readings at most 0.5 s old)."""
        try:
            readings = self.runner.watchdog.read()
        except Exception:  # a driver bug must not take the status page down
            logger.exception("cannot read the devices for the status")
            readings = None
        track = self.cell.track
        return devices_view(
            readings,
            robot=self.cell.robot.name,
            track=track.name if track is not None else None,
            camera=getattr(self.cell.camera, "name", self.config.camera.kind),
            arc_output=self.runner.arc_output,
        )

    def _overlay(self, state: CellState) -> dict[str, Any] | None:
        if not self.status_image.is_file():
            return None
        data = self.runner.current
        view = overlay_view(data, state) if data is not None else None
        out = {"url": "/status.png", "version": self.status_image.stat().st_mtime_ns}
        out.update({"job_id": data.job_id} if data is not None else {})
        return {**out, **view} if view is not None else out

    def jobs_view(self) -> dict[str, Any]:
        return {"jobs": [job_view(r) for r in self.journal.recent_jobs(self.config.daemon.recent_jobs)]}

    def job_view(self, job_id: int) -> dict[str, Any]:
        view = job_view(self.journal.job(job_id))
        view["events"] = [
            {"time_s": e.time_s, "from": e.from_state, "to": e.to_state, "reason": e.reason}
            for e in self.journal.events(job_id)
        ]
        return view

    def export(self, job_id: int, fmt: str) -> Exported:
        """Job ``job_id`` (finished) as ``fmt``: KeyError for an unknown job, CellBusy for one not finished,
        :class:`cell.job_exports.NothingToExport` for one that planned no path."""
        record = self.journal.job(job_id)
        if record.state not in FINAL_JOB_STATES:
            raise CellBusy(f"job {job_id} is {record.state}: its exports are there once it has finished")
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:  # the worker keeps the result just after the job's report is stored
            with self._lock:
                if self._current is None or self._current.job_id != job_id:
                    break
            time.sleep(0.05)
        return export_job(self.results_dir / str(job_id), self.config, fmt, job_id=job_id)

    def metrics(self) -> bytes:
        """The Prometheus text exposition (format 0.0.4): build info, the job-duration histogram, the counters."""
        return self.metrics_registry.render()

    def _snapshot(self) -> DaemonSnapshot:
        with self._lock:
            return DaemonSnapshot(
                states=tuple(s.value for s in CellState),
                state=self.runner.machine.state.value,
                outcomes=dict(self._outcomes),
                queued=len(self._queued),
                seams_welded=int(self._totals["seams_welded"]),
                poses_sent=int(self._totals["poses_sent"]),
                arc_time_s=float(self._totals["arc_time_s"]),
                cycle_phases=CYCLE_PHASES,
                last_cycle_s=dict(self._last_cycle),
            )

    def _journal_note(self, text: str) -> None:
        state = self.runner.machine.state.value
        self.journal.record_state_change(self.runner.machine.job_id, state, state, text)

    # ------------------------------------------------------------------------------------------ commands
    def acknowledge(self, operator: str) -> tuple[int, dict[str, Any]]:
        """POST /acknowledge: (HTTP status, answer). Waits for the runner to finish a job that faulted."""
        machine = self.runner.machine
        if machine.state is not CellState.FAULT:
            return HTTPStatus.CONFLICT, {"error": f"the cell is {machine.state.value}, not in fault"}
        reason = machine.fault_reason
        try:
            ok = self.runner.acknowledge(operator)
        except CellBusy as err:
            return HTTPStatus.CONFLICT, {"error": str(err)}
        fault = explain_fault(reason)
        if ok and fault is not None:
            with self._lock:
                self._last_fault = {
                    "reason": reason,
                    **fault.to_dict(),
                    "acknowledged_by": operator,
                    "acknowledged_s": time.time(),
                }
        status = HTTPStatus.OK if ok else HTTPStatus.CONFLICT
        return status, {"state": machine.state.value, "fault_reason": machine.fault_reason}

    def motion_command(self, command: str, operator: str) -> tuple[int, dict[str, Any]]:
        """pause (motion stopped and arc off now), resume (back to the paused state), abort (retract, the job
        ends cancelled): (HTTP status, answer); the state machine decides what is allowed."""
        machine = self.runner.machine
        state = machine.state
        if command == "pause":
            if state not in PAUSABLE:
                return HTTPStatus.CONFLICT, {"error": f"nothing to pause: the cell is {state.value}"}
            machine.request_pause(f"paused by {operator} over HTTP")
            ok = machine.state is CellState.PAUSED
        elif state is not CellState.PAUSED:
            return HTTPStatus.CONFLICT, {"error": f"the cell is {state.value}, not paused"}
        else:
            ok = machine.resume() if command == "resume" else machine.abort(operator)
        status = HTTPStatus.OK if ok else HTTPStatus.CONFLICT
        return status, {"state": machine.state.value, "fault_reason": machine.fault_reason}

    # ------------------------------------------------------------------------------------------ shutdown
    def shutdown(self, reason: str) -> None:
        """Stop safely: motion stopped and arc off first (fault_now when a job moves), then no more jobs, then close.
        Safe to call twice."""
        if self._stopping.is_set():
            return
        self._stopping.set()
        m = self.runner.machine
        if m.state in ACTIVE_STATES:
            logger.warning("%s: stopping the running job (motion stop, arc off)", reason)
            m.fault_now(f"{reason}: the daemon is stopping")
        with self._lock:
            queued = sorted(self._queued)
            self._queued.clear()
            approval = self._approval
        if approval is not None:
            approval.event.set()
        for job_id in queued:
            self.journal.record_state_change(
                job_id, "queued", "cancelled", f"{reason}: the daemon stopped before the job started",
                job_state="cancelled", error=f"{reason} before the job started",
            )  # fmt: skip
        self._queue.put(None)
        self._worker.join(timeout=30.0)
        self.arc_on_at_exit = self._confirm_arc_off()
        if self._memory_log is not None:
            with contextlib.suppress(Exception):  # a measurement must never stop the shutdown
                self._memory_log.close()
        self.http.stop()
        if self.helper is not None:
            self.helper.close()
        if self._own_cell:
            self.cell.close()
        self.journal.close()
        logger.info("weldcell daemon stopped (%s)", reason)

    def _confirm_arc_off(self) -> bool | None:
        """Switch the arc output off once more and read it back: False (off), True (still on), None (unreadable)."""
        try:
            self.runner.switch_arc_off()
            on = self.runner.arc_reads_on()
        except Exception as err:  # a robot that dropped off: say so, the process must still stop
            logger.error("cannot read the arc output %d back at shutdown: %s", self.runner.arc_output, err)
            return None
        if on:
            logger.critical("the arc output %d still reads on after switching it off", self.runner.arc_output)
        return on


def _check_sim_faults_allowed(config: CellConfig, *, own_simulators: bool) -> None:
    real = real_devices(config)
    if real:
        raise ConfigError(
            f"{config.source or 'the config'}: --sim-faults is for simulated cells only, and "
            f"{', '.join(real)} is real hardware"
        )
    if not own_simulators:
        raise ConfigError("--sim-faults needs the simulators this daemon starts: it cannot be combined with --no-sims")
