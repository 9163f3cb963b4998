"""``weldcell serve``: the cell as a small HTTP service (FastAPI on uvicorn, :mod:`cell.http_api`), running jobs
one at a time.

Endpoints (JSON unless said otherwise; ``GET /openapi.json`` describes them; with ``[daemon] token`` every request
needs ``Authorization: Bearer <token>``, and the config refuses a non-loopback ``host`` without a token; Host,
Origin, size and time checks in :mod:`cell.http_api`)::

    POST /jobs                   body: a job's TOML text, or JSON {"path": "job.toml"} (in the jobs directory) or
                                 {"toml": "..."}; checked against the cell's limits before it is queued;
                                 ?dry_run=1 (or "dry_run": true) plans and validates only -> 201 {"id", "state"}
    GET  /jobs                   the recent jobs, newest first
    GET  /jobs/{id}              one job: state, report, error and its journaled events
    POST /jobs/{id}/approve      {"operator": "name"}: approve the planned path of a job awaiting approval
    POST /jobs/{id}/reject       {"operator": "name"}: refuse it (the job ends cancelled, nothing moves)
    POST /acknowledge            {"operator": "name"}: leave fault (latched device faults are cleared)
    POST /pause, /resume, /abort {"operator": "name"}: pause (motion stopped, arc off), resume where it stopped,
                                 or give the paused job up (the torch retracts, the job ends cancelled)
    GET  /status                 {"state", "fault_reason", "current_job", "queued", "recent_jobs", "interrupted"}
    GET  /                       a small HTML status page with the overlay of the last capture
    GET  /status.png             that overlay (PNG)
    GET  /metrics                Prometheus text format

Test only, with ``weldcell serve --sim-faults`` (``Daemon(sim_faults=True)``), which is refused unless every device
is a simulator this daemon started itself (:meth:`cell.factory.Cell.fault_injectors`)::

    GET  /sim/faults             the simulated devices, the faults each supports and the faults injected
    POST /sim/faults             {"device": "robot" | "track" | "camera", "fault": "...", "params": {...}}: switch a
                                 fault of that simulator on (``sim_fakes.faults``): a soak or a test plays the
                                 broken device, the cell reacts as it would to the real one
    POST /sim/faults/clear       {"device": ...} or {}: switch that simulator's (every simulator's) faults off; a
                                 latched stop or drive fault stays latched until POST /acknowledge clears it

Without the switch these paths answer 404 and no fault switch exists in the process.

Jobs wait in a FIFO queue; while the cell is in fault they wait for the acknowledgement. Everything goes to the
journal (cell.journal); a job found queued or running when the daemon starts (it was killed) is reported as
``interrupted`` and never resumed, and when one was running the cell starts in ``fault`` ("unclean stop"): no
motion before an operator's acknowledgement. :meth:`Daemon.shutdown` (SIGTERM, Ctrl-C) stops the motion and
switches the arc off through the state machine's ``fault_now`` before anything else, cancels the queued jobs,
then closes the devices and the journal; the arc output is then switched off once more and read back
(:attr:`Daemon.arc_on_at_exit`).
"""

from __future__ import annotations

import html
import json
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
from cell.http_api import HttpServer, build_app, listen
from cell.job import FileRules, Job, job_from_text, load_job
from cell.journal import JobRecord, Journal
from cell.machine import PAUSABLE, CellState
from cell.planning import WeldPath
from cell.runner import CYCLE_PHASES, CellBusy, JobReport, JobRunner

logger = logging.getLogger(__name__)

ACTIVE_STATES = frozenset(CellState) - {CellState.IDLE, CellState.DONE, CellState.FAULT}


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
            real = real_devices(config)
            if real:
                raise ConfigError(
                    f"{config.source or 'the config'}: --sim-faults is for simulated cells only, and "
                    f"{', '.join(real)} is real hardware"
                )
            if cell is None and not start_simulators:
                raise ConfigError(
                    "--sim-faults needs the simulators this daemon starts: it cannot be combined with --no-sims"
                )
        self.config = config
        dc = config.daemon
        self.journal = Journal(config.resolve(dc.journal))
        self.interrupted: tuple[JobRecord, ...] = self.journal.interrupted
        self.submitted_dir = (self.journal.path.parent / "jobs").resolve()  # copies of the jobs sent as text
        self.jobs_dir = config.resolve(dc.jobs_dir).resolve() if dc.jobs_dir is not None else self.submitted_dir
        self.captures_dir = (
            config.resolve(dc.captures_dir) if dc.captures_dir is not None else self.journal.path.parent / "captures"
        ).resolve()
        self.status_image = config.resolve(dc.status_image)
        self._own_cell = cell is None
        try:
            self.cell = cell if cell is not None else build_cell(config, start_simulators=start_simulators)
            if self._own_cell:
                self.cell.connect()
            self.runner = JobRunner(self.cell, journal=self.journal, status_image=self.status_image)
            self.runner.switch_arc_off()  # the previous process may have died with the arc on
            self._fault_injectors: dict[str, Any] | None = self.cell.fault_injectors() if sim_faults else None
        except BaseException:
            if self._own_cell and cell is None and hasattr(self, "cell"):
                self.cell.close()
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
        self._injected: dict[str, list[dict[str, Any]]] = {}
        self.arc_on_at_exit: bool | None = None
        """After :meth:`shutdown`: whether the arc output read on (None: it could not be read back)."""
        self._worker = threading.Thread(target=self._work, name="weldcell-jobs", daemon=True)
        try:
            sock = listen(dc.host, dc.port)
        except OSError:
            if self._own_cell:
                self.cell.close()
            self.journal.close()
            raise
        self._address = sock.getsockname()[:2]
        self.app = build_app(self, int(self._address[1]))
        self.http = HttpServer(self.app, sock, timeout_s=dc.request_timeout_s, max_connections=dc.max_connections)
        for record in self.interrupted:
            logger.warning(
                "job %d (%s) was interrupted by the previous daemon: not resumed", record.id, record.job_file
            )
        unclean = [r.id for r in self.interrupted if r.started_s is not None]
        if unclean:  # the torch may stand on the part: nothing moves before an operator has looked
            self.runner.machine.fault_now(
                f"unclean stop: job {', '.join(map(str, unclean))} was running when the previous daemon stopped; "
                "check the torch and the part, then acknowledge (POST /acknowledge)"
            )
        if self._fault_injectors is not None:
            logger.warning(
                "test-only fault injection is on (/sim/faults) for the simulated %s", ", ".join(self._fault_injectors)
            )

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._address
        return str(host), int(port)

    def start(self) -> Daemon:
        limit_malloc_arenas()  # before the worker and HTTP threads exist
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
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError as err:
            raise ConfigError("the request body is not UTF-8 text") from err
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

    def _count(self, report: JobReport) -> None:
        with self._lock:
            self._outcomes[report.outcome] = self._outcomes.get(report.outcome, 0) + 1
            self._totals["seams_welded"] += report.seams_welded
            self._totals["poses_sent"] += report.poses_sent
            self._totals["arc_time_s"] += report.arc_time_s
            self._last_cycle = dict(report.cycle_s)

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

    # ------------------------------------------------------------------------------------------ test faults
    @property
    def sim_faults(self) -> bool:
        """Whether the test-only ``/sim/faults`` endpoints are served."""
        return self._fault_injectors is not None

    def sim_fault_view(self) -> dict[str, Any]:
        """The simulated devices: the faults each supports and those injected since they were last cleared."""
        injectors = self._fault_injectors or {}
        with self._lock:
            injected = {role: list(faults) for role, faults in self._injected.items()}
        return {
            "devices": {
                role: {"supported": sorted(handle.supported_faults), "injected": injected.get(role, [])}
                for role, handle in injectors.items()
            },
            "arc_output_on": self._simulated_arc_on(injectors.get("robot")),
        }

    def _simulated_arc_on(self, robot: Any) -> bool | None:
        """The arc output as the simulated controller itself holds it (not as the driver reports it): what an
        independent reader of the controller's outputs sees. None: unknown."""
        index = self.runner.arc_output
        try:
            if hasattr(robot, "digital_output"):  # the fake FANUC: DO[index + 1]
                return bool(robot.digital_output(index + 1))
            if hasattr(robot, "snapshot"):  # the fake UR, through its process's control pipe
                return bool(robot.snapshot()["digital_outputs"][index])
        except (RuntimeError, TimeoutError, OSError, ValueError, IndexError, KeyError):
            return None
        return None

    def inject_sim_fault(self, device: str, fault: str, params: dict[str, Any]) -> None:
        """Switch ``fault`` of the simulated ``device`` on. ConfigError for an unknown device, fault or parameter."""
        handle = self._sim_device(device)
        try:
            handle.inject(fault, **params)
        except (ValueError, TypeError) as err:
            raise ConfigError(f"simulated {device}: {err}") from err
        except (RuntimeError, TimeoutError, OSError) as err:  # a fake (the UR's own process) that does not answer
            raise WeldcellError(f"the simulated {device} did not take the fault: {err}") from err
        with self._lock:
            self._injected.setdefault(device, []).append({"fault": fault, "params": params})
        self._journal_sim_fault(f"test fault injected into the simulated {device}: {fault} {json.dumps(params)}")

    def clear_sim_faults(self, device: str | None = None) -> list[str]:
        """Switch the faults of the simulated ``device`` (None: every one) off; returns the devices cleared."""
        roles = [device] if device is not None else sorted(self._fault_injectors or {})
        handles = [(role, self._sim_device(role)) for role in roles]
        for role, handle in handles:
            try:
                handle.clear_faults()
            except (RuntimeError, TimeoutError, OSError) as err:
                raise WeldcellError(f"the simulated {role} did not clear its faults: {err}") from err
            with self._lock:
                self._injected.pop(role, None)
        self._journal_sim_fault(f"test faults cleared in the simulated {', '.join(roles)}")
        return roles

    def _sim_device(self, device: str) -> Any:
        injectors = self._fault_injectors
        if injectors is None:  # the routes check first; this guards direct calls
            raise ConfigError("fault injection is off (weldcell serve --sim-faults, simulated cells only)")
        if device not in injectors:
            raise ConfigError(f"no simulated device {device!r}; choose one of {sorted(injectors)}")
        return injectors[device]

    def _journal_sim_fault(self, text: str) -> None:
        logger.warning("%s", text)
        state = self.runner.machine.state.value
        self.journal.record_state_change(self.runner.machine.job_id, state, state, text)

    # ------------------------------------------------------------------------------------------ views
    def status(self) -> dict[str, Any]:
        m = self.runner.machine
        with self._lock:
            current = self._current
            queued = sorted(self._queued)
            awaiting = self._approval.job_id if self._approval is not None else None
        current_view = None
        if current is not None:
            data = self.runner.current
            current_view = {
                "id": current.job_id,
                "workpiece": current.job.workpiece,
                "dry_run": current.dry_run,
                "awaiting_approval": awaiting == current.job_id,
                "seams_welded": data.seams_welded if data is not None and data.job_id == current.job_id else 0,
            }
        return {
            "state": m.state.value,
            "fault_reason": m.fault_reason if m.state is CellState.FAULT else None,
            "current_job": current_view,
            "queued": queued,
            "recent_jobs": [_job_view(r) for r in self.journal.recent_jobs(self.config.daemon.recent_jobs)],
            "interrupted": [_job_view(r) for r in self.interrupted],
            "sim_faults": self._fault_injectors is not None,
        }

    def jobs_view(self) -> dict[str, Any]:
        return {"jobs": [_job_view(r) for r in self.journal.recent_jobs(self.config.daemon.recent_jobs)]}

    def acknowledge(self, operator: str) -> tuple[int, dict[str, Any]]:
        """POST /acknowledge: (HTTP status, answer). Waits for the runner to finish a job that faulted."""
        machine = self.runner.machine
        if machine.state is not CellState.FAULT:
            return HTTPStatus.CONFLICT, {"error": f"the cell is {machine.state.value}, not in fault"}
        try:
            ok = self.runner.acknowledge(operator)
        except CellBusy as err:
            return HTTPStatus.CONFLICT, {"error": str(err)}
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

    def sim_fault_command(self, path: str, body: bytes) -> dict[str, Any]:
        """POST /sim/faults {"device", "fault", "params"} or /sim/faults/clear {"device"} (optional)."""
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError as err:
            raise ConfigError("the request body is not UTF-8 text") from err
        obj = parse_json_object(text)
        device = obj.get("device")
        if path.endswith("/clear"):
            if device is not None and not isinstance(device, str):
                raise ConfigError('"device" must be a device name (or left out: every simulator)')
            return {"cleared": self.clear_sim_faults(device)}
        fault, params = obj.get("fault"), obj.get("params", {})
        if not isinstance(device, str) or not isinstance(fault, str) or not isinstance(params, dict):
            raise ConfigError('send {"device": "robot" | "track" | "camera", "fault": "<name>", "params": {}}')
        self.inject_sim_fault(device, fault, params)
        return {"device": device, "fault": fault, "params": params}

    def job_view(self, job_id: int) -> dict[str, Any]:
        view = _job_view(self.journal.job(job_id))
        view["events"] = [
            {"time_s": e.time_s, "from": e.from_state, "to": e.to_state, "reason": e.reason}
            for e in self.journal.events(job_id)
        ]
        return view

    def metrics(self) -> str:
        """The Prometheus text exposition (format 0.0.4)."""
        m = self.runner.machine
        with self._lock:
            outcomes = dict(self._outcomes)
            totals = dict(self._totals)
            cycle = dict(self._last_cycle)
            queued = len(self._queued)
        lines = [
            "# HELP weldcell_cell_state 1 for the state the cell is in, 0 for the others.",
            "# TYPE weldcell_cell_state gauge",
        ]
        lines += [f'weldcell_cell_state{{state="{s.value}"}} {int(m.state is s)}' for s in CellState]
        lines += [
            "# HELP weldcell_jobs_finished_total Jobs finished since the daemon started, by outcome.",
            "# TYPE weldcell_jobs_finished_total counter",
        ]
        for outcome in ("welded", "dry_run", "rejected", "no_seam", "refused", "fault"):
            lines.append(f'weldcell_jobs_finished_total{{outcome="{outcome}"}} {outcomes.get(outcome, 0)}')
        lines += [
            "# HELP weldcell_jobs_queued Jobs waiting in the queue.",
            "# TYPE weldcell_jobs_queued gauge",
            f"weldcell_jobs_queued {queued}",
            "# HELP weldcell_seams_welded_total Seams welded since the daemon started.",
            "# TYPE weldcell_seams_welded_total counter",
            f"weldcell_seams_welded_total {totals['seams_welded']}",
            "# HELP weldcell_poses_sent_total Robot poses commanded since the daemon started.",
            "# TYPE weldcell_poses_sent_total counter",
            f"weldcell_poses_sent_total {totals['poses_sent']}",
            "# HELP weldcell_arc_seconds_total Time with the arc on since the daemon started.",
            "# TYPE weldcell_arc_seconds_total counter",
            f"weldcell_arc_seconds_total {totals['arc_time_s']:.3f}",
            "# HELP weldcell_last_job_cycle_seconds Cycle time of the last finished job, by phase.",
            "# TYPE weldcell_last_job_cycle_seconds gauge",
        ]
        for phase in (*CYCLE_PHASES, "total"):
            lines.append(f'weldcell_last_job_cycle_seconds{{phase="{phase}"}} {cycle.get(phase, 0.0):.3f}')
        return "\n".join(lines) + "\n"

    def page(self) -> str:
        st = self.status()
        rows = "".join(
            f"<tr><td>{j['id']}</td><td>{html.escape(str(j['job_file']))}</td><td>{j['state']}</td>"
            f"<td>{'' if j['report'] is None else j['report'].get('seams_welded', '')}</td>"
            f"<td>{html.escape(j['error'] or '')}</td></tr>"
            for j in st["recent_jobs"]
        )
        current = st["current_job"]
        fault = f"<p class=fault>fault: {html.escape(st['fault_reason'])}</p>" if st["fault_reason"] else ""
        image = '<img src="/status.png" alt="last capture overlay">' if self.status_image.is_file() else ""
        return (
            "<!doctype html><html><head><meta charset=utf-8><meta http-equiv=refresh content=2>"
            "<title>weldcell</title><style>body{font-family:sans-serif}td,th{padding:2px 8px}"
            ".fault{color:#b00}img{max-width:100%}</style></head><body>"
            f"<h1>weldcell: {st['state']}</h1>{fault}"
            f"<p>current job: {html.escape(json.dumps(current)) if current else 'none'}; queued: {st['queued']}</p>"
            f"{image}<h2>recent jobs</h2><table><tr><th>id</th><th>job</th><th>state</th><th>seams welded</th>"
            f"<th>error</th></tr>{rows}</table></body></html>"
        )

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
        self.http.stop()
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


def parse_flag(value: str, what: str) -> bool:
    """A query flag: ``1|true|yes`` or ``0|false|no`` (any case); ConfigError for anything else."""
    low = value.strip().lower()
    if low in ("1", "true", "yes"):
        return True
    if low in ("0", "false", "no"):
        return False
    raise ConfigError(f"{what} must be one of 1, true, yes, 0, false, no")


def parse_json_object(text: str) -> dict[str, Any]:
    """A JSON object from a request body; ConfigError for anything else (the position, never the text)."""
    try:
        obj = json.loads(text or "{}")
    except json.JSONDecodeError as err:
        raise ConfigError(f"the request body is not valid JSON (line {err.lineno}, column {err.colno})") from err
    except RecursionError as err:
        raise ConfigError("the request body is nested too deeply") from err
    if not isinstance(obj, dict):
        raise ConfigError("send a JSON object")
    return obj


def _job_view(record: JobRecord) -> dict[str, Any]:
    return {
        "id": record.id,
        "job_file": record.job_file,
        "state": record.state,
        "submitted_s": record.submitted_s,
        "started_s": record.started_s,
        "finished_s": record.finished_s,
        "report": record.report,
        "error": record.error,
    }


# ---------------------------------------------------------------------------------------------- memory
# A daemon that runs for days must not creep. Each job allocates and frees a few hundred MiB of arrays on
# the worker thread; glibc keeps freed memory in per-thread arenas, so the resident size grew ~0.4 MiB per
# job over a 100-job soak (scripts/soak.py) with no Python object leaked. Fewer arenas and handing freed
# memory back after each job keep it flat. Both are no-ops where glibc is absent.
_M_ARENA_MAX = -8  # mallopt parameter (glibc malloc.h)


def _libc() -> Any:
    import ctypes
    import ctypes.util
    import sys

    name = ctypes.util.find_library("c")
    if not name or not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(name)
    except OSError:
        return None


def limit_malloc_arenas(arenas: int = 2) -> bool:
    """Cap glibc's malloc arenas (as MALLOC_ARENA_MAX would); True when it took effect."""
    libc = _libc()
    return bool(libc is not None and hasattr(libc, "mallopt") and libc.mallopt(_M_ARENA_MAX, arenas) == 1)


def release_freed_memory() -> bool:
    """Return freed heap memory to the system (glibc malloc_trim); True when some was released."""
    libc = _libc()
    return bool(libc is not None and hasattr(libc, "malloc_trim") and libc.malloc_trim(0) == 1)

