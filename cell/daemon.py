"""``weldcell serve``: the cell as a small HTTP service (stdlib ``http.server``), running jobs one at a time.

Endpoints (JSON unless said otherwise; with ``[daemon] token`` every request needs ``Authorization: Bearer <token>``,
and the config refuses a non-loopback ``host`` without a token)::

    POST /jobs                   body: a job's TOML text, or JSON {"path": "job.toml"} or {"toml": "..."};
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
``interrupted`` and never resumed. :meth:`Daemon.shutdown` (SIGTERM, Ctrl-C) stops the motion and switches the arc
off through the state machine's ``fault_now`` before anything else, cancels the queued jobs, then closes the
devices and the journal; the arc output is then switched off once more and read back (:attr:`Daemon.arc_on_at_exit`).
"""

from __future__ import annotations

import hmac
import html
import json
import logging
import queue
import re
import threading
import time
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from cell.config import CellConfig
from cell.errors import ConfigError, WeldcellError
from cell.factory import Cell, build_cell, real_devices
from cell.job import Job, job_from_text, load_job
from cell.journal import JobRecord, Journal
from cell.machine import PAUSABLE, CellState
from cell.planning import WeldPath
from cell.runner import CYCLE_PHASES, JobReport, JobRunner

logger = logging.getLogger(__name__)

MAX_BODY_BYTES = 1 << 20
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
        self.jobs_dir = self.journal.path.parent / "jobs"
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
        self.server = ThreadingHTTPServer((dc.host, dc.port), _handler(self))
        self.server.daemon_threads = True
        self._server_thread = threading.Thread(target=self.server.serve_forever, name="weldcell-http", daemon=True)
        for record in self.interrupted:
            logger.warning(
                "job %d (%s) was interrupted by the previous daemon: not resumed", record.id, record.job_file
            )
        if self._fault_injectors is not None:
            logger.warning(
                "test-only fault injection is on (/sim/faults) for the simulated %s", ", ".join(self._fault_injectors)
            )

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.server.server_address[:2]
        return str(host), int(port)

    def start(self) -> Daemon:
        limit_malloc_arenas()  # before the worker and HTTP threads exist
        self._worker.start()
        self._server_thread.start()
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

    def job_from_request(self, body: bytes, content_type: str) -> tuple[Job, bool]:
        """A job from a POST /jobs body; ConfigError for a bad one. Returns (job, dry_run from the body)."""
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError as err:
            raise ConfigError("the request body is not UTF-8 text") from err
        dry_run = False
        if "json" in content_type:
            try:
                obj = json.loads(text)
            except json.JSONDecodeError as err:
                raise ConfigError(f"the request body is not valid JSON: {err}") from err
            if not isinstance(obj, dict) or not (("path" in obj) ^ ("toml" in obj)):
                raise ConfigError('send {"path": "job.toml"} or {"toml": "<job text>"} (one of them)')
            dry_run = bool(obj.get("dry_run", False))
            if "path" in obj:
                return load_job(str(obj["path"])), dry_run
            text = str(obj["toml"])
        job = job_from_text(text, source="<http job>", base_dir=Path.cwd())
        self.jobs_dir.mkdir(parents=True, exist_ok=True)
        name = re.sub(r"[^A-Za-z0-9_.-]+", "-", job.workpiece)[:40] or "job"
        path = self.jobs_dir / f"{time.strftime('%Y%m%d-%H%M%S')}-{time.monotonic_ns() % 10**9:09d}-{name}.toml"
        path.write_text(text, encoding="utf-8")
        return job_from_text(text, source=str(path), base_dir=Path.cwd()), dry_run

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
            }
        }

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
        self.server.shutdown()
        self.server.server_close()
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


def _handler(daemon: Daemon) -> type[BaseHTTPRequestHandler]:
    token = daemon.config.daemon.token

    class Handler(BaseHTTPRequestHandler):
        server_version = "weldcell"
        protocol_version = "HTTP/1.1"

        def log_message(self, format: str, *args: Any) -> None:
            logger.debug("http %s: " + format, self.client_address[0], *args)

        # -------------------------------------------------------------------------- plumbing
        def _send(self, status: HTTPStatus, body: bytes, content_type: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, status: HTTPStatus, obj: Any) -> None:
            self._send(status, json.dumps(obj).encode(), "application/json")

        def _error(self, status: HTTPStatus, message: str) -> None:
            self._json(status, {"error": message})

        def _authorized(self) -> bool:
            if token is None:
                return True
            given = self.headers.get("Authorization", "")
            if given.startswith("Bearer ") and hmac.compare_digest(given[7:].encode(), token.encode()):
                return True
            self.send_response(HTTPStatus.UNAUTHORIZED)
            body = b'{"error": "a bearer token is required: Authorization: Bearer <token>"}'
            self.send_header("WWW-Authenticate", 'Bearer realm="weldcell"')
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return False

        def _body(self) -> bytes | None:
            try:
                length = int(self.headers.get("Content-Length", "0"))
            except ValueError:
                length = -1
            if not 0 <= length <= MAX_BODY_BYTES:
                self._error(HTTPStatus.BAD_REQUEST, f"need a Content-Length of 0..{MAX_BODY_BYTES} bytes")
                return None
            return self.rfile.read(length)

        def _operator(self, body: bytes) -> str | None:
            try:
                obj = json.loads(body.decode("utf-8") or "{}")
            except (UnicodeDecodeError, json.JSONDecodeError):
                obj = None
            name = obj.get("operator") if isinstance(obj, dict) else None
            if not isinstance(name, str) or not name.strip():
                self._error(HTTPStatus.BAD_REQUEST, 'send {"operator": "<name>"}: an operator must be named')
                return None
            return name.strip()

        # -------------------------------------------------------------------------- routes
        def do_GET(self) -> None:
            if not self._authorized():
                return
            path = urlsplit(self.path).path
            try:
                if path == "/status":
                    self._json(HTTPStatus.OK, daemon.status())
                elif path == "/jobs":
                    jobs = daemon.journal.recent_jobs(daemon.config.daemon.recent_jobs)
                    self._json(HTTPStatus.OK, {"jobs": [_job_view(r) for r in jobs]})
                elif (found := re.fullmatch(r"/jobs/(\d+)", path)) is not None:
                    try:
                        self._json(HTTPStatus.OK, daemon.job_view(int(found.group(1))))
                    except KeyError:
                        self._error(HTTPStatus.NOT_FOUND, f"no job {found.group(1)}")
                elif path == "/sim/faults" and daemon.sim_faults:
                    self._json(HTTPStatus.OK, daemon.sim_fault_view())
                elif path == "/metrics":
                    self._send(HTTPStatus.OK, daemon.metrics().encode(), "text/plain; version=0.0.4; charset=utf-8")
                elif path == "/":
                    self._send(HTTPStatus.OK, daemon.page().encode(), "text/html; charset=utf-8")
                elif path == "/status.png":
                    try:
                        self._send(HTTPStatus.OK, daemon.status_image.read_bytes(), "image/png")
                    except OSError:
                        self._error(HTTPStatus.NOT_FOUND, "no capture yet")
                else:
                    self._error(HTTPStatus.NOT_FOUND, f"no such resource {path}")
            except WeldcellError as err:
                self._error(HTTPStatus.INTERNAL_SERVER_ERROR, str(err))

        def do_POST(self) -> None:
            if not self._authorized():
                return
            parts = urlsplit(self.path)
            path = parts.path
            body = self._body()
            if body is None:
                return
            try:
                if path == "/jobs":
                    job, dry_run = daemon.job_from_request(body, self.headers.get("Content-Type", ""))
                    query = parse_qs(parts.query)
                    dry_run = dry_run or query.get("dry_run", ["0"])[0].lower() in ("1", "true", "yes")
                    job_id = daemon.submit(job, dry_run=dry_run)
                    self._json(HTTPStatus.CREATED, {"id": job_id, "state": "queued", "dry_run": dry_run})
                elif (found := re.fullmatch(r"/jobs/(\d+)/(approve|reject)", path)) is not None:
                    operator = self._operator(body)
                    if operator is None:
                        return
                    job_id = int(found.group(1))
                    approve = found.group(2) == "approve"
                    if daemon.answer_approval(job_id, operator if approve else None):
                        self._json(HTTPStatus.OK, {"id": job_id, "approved": approve, "operator": operator})
                    else:
                        self._error(HTTPStatus.CONFLICT, f"job {job_id} is not waiting for approval")
                elif path in ("/pause", "/resume", "/abort"):
                    operator = self._operator(body)
                    if operator is None:
                        return
                    self._motion_command(path[1:], operator)
                elif path in ("/sim/faults", "/sim/faults/clear") and daemon.sim_faults:
                    self._sim_fault_command(path, body)
                elif path == "/acknowledge":
                    operator = self._operator(body)
                    if operator is None:
                        return
                    machine = daemon.runner.machine
                    if machine.state is not CellState.FAULT:
                        self._error(HTTPStatus.CONFLICT, f"the cell is {machine.state.value}, not in fault")
                        return
                    ok = daemon.runner.acknowledge(operator)
                    status = HTTPStatus.OK if ok else HTTPStatus.CONFLICT
                    self._json(status, {"state": machine.state.value, "fault_reason": machine.fault_reason})
                else:
                    self._error(HTTPStatus.NOT_FOUND, f"no such resource {path}")
            except ConfigError as err:
                self._error(HTTPStatus.BAD_REQUEST, str(err))
            except WeldcellError as err:
                self._error(HTTPStatus.SERVICE_UNAVAILABLE, str(err))

        def _sim_fault_command(self, path: str, body: bytes) -> None:
            """POST /sim/faults {"device", "fault", "params"} or /sim/faults/clear {"device"} (optional)."""
            try:
                obj = json.loads(body.decode("utf-8") or "{}")
            except (UnicodeDecodeError, json.JSONDecodeError) as err:
                raise ConfigError(f"the request body is not valid JSON: {err}") from err
            if not isinstance(obj, dict):
                raise ConfigError('send a JSON object: {"device": ..., "fault": ..., "params": {...}}')
            device = obj.get("device")
            if path.endswith("/clear"):
                if device is not None and not isinstance(device, str):
                    raise ConfigError('"device" must be a device name (or left out: every simulator)')
                self._json(HTTPStatus.OK, {"cleared": daemon.clear_sim_faults(device)})
                return
            fault, params = obj.get("fault"), obj.get("params", {})
            if not isinstance(device, str) or not isinstance(fault, str) or not isinstance(params, dict):
                raise ConfigError('send {"device": "robot" | "track" | "camera", "fault": "<name>", "params": {}}')
            daemon.inject_sim_fault(device, fault, params)
            self._json(HTTPStatus.OK, {"device": device, "fault": fault, "params": params})

        def _motion_command(self, command: str, operator: str) -> None:
            """pause (motion stopped and arc off now), resume (back to the paused state), abort (retract, the job
            ends cancelled): the state machine decides what is allowed."""
            machine = daemon.runner.machine
            state = machine.state
            if command == "pause":
                if state not in PAUSABLE:
                    self._error(HTTPStatus.CONFLICT, f"nothing to pause: the cell is {state.value}")
                    return
                machine.request_pause(f"paused by {operator} over HTTP")
                ok = machine.state is CellState.PAUSED
            elif state is not CellState.PAUSED:
                self._error(HTTPStatus.CONFLICT, f"the cell is {state.value}, not paused")
                return
            else:
                ok = machine.resume() if command == "resume" else machine.abort(operator)
            status = HTTPStatus.OK if ok else HTTPStatus.CONFLICT
            self._json(status, {"state": machine.state.value, "fault_reason": machine.fault_reason})

    return Handler


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

