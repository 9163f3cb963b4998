"""The job runner: :class:`cell.machine.CellMachine`'s actions done with the cell's real drivers.

One :class:`JobRunner` owns one :class:`cell.factory.Cell` (connected drivers), one state machine and a journal.
:meth:`JobRunner.run` takes a :class:`cell.job.Job` through the machine: homing (robot to ``[home]``, track to its
home position), for each capture pose a track move and a robot move, a camera frame with the robot's measured
``X_base_tool``, the carriage's measured position and the configured hand-eye ``X_tool_camera``, detection
(:func:`perception.detect.detect`), planning (:func:`cell.world_seams.collect_seams` merges the seams of all captures
in the world frame, :func:`cell.planning.plan_weld_path` orders them), safety validation
(:func:`cell.safety.validate`), approval, then for each pass: track move (when the pass needs another carriage
position), air move to the approach pose, approach to the arc-on pose, arc on (the digital output), the travel poses
streamed with the robot's ``stream_path``, arc off, retract. Finally the robot returns to its home pose.

Every state change is journaled by the machine; every step inside a state (a capture, a track move, arc on and
off of each pass) is journaled as an event whose from and to state are the current state.

A watchdog thread polls the robot and the track while a job runs and turns a protective stop, an emergency stop,
a track fault or an unreachable device into :meth:`CellMachine.fault_now` (which stops motion and turns the arc off
at once, from its thread). The drivers raise the same conditions during a motion; the watchdog also catches them
between motions (while capturing or detecting).

A dry run (``dry_run=True``) moves nothing and switches nothing: the captures are taken where the robot and track
stand (with their measured pose), then the path is planned and validated and the job ends without welding. After an
acknowledged fault, until a job has homed the robot again, a dry run captures only from home or from one of the
job's capture poses (:func:`cell.job_checks.station_of`): a fault can leave the torch anywhere (on the part, half way
to a capture pose), and frames from there find no seam or the wrong ones. Elsewhere it is refused before it
captures (a :class:`SafetyViolation` naming where the robot stands and what to do).

The report (:class:`JobReport`) gives the final state, the seams found, planned and welded, the poses sent to the
robot, the arc-on time and the cycle time split into capture (moves to the capture poses and frames), detection,
planning (with validation) and motion (homing, welding, retracting).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from cell.errors import ConfigError, SafetyViolation, WeldcellError
from cell.factory import Cell
from cell.job import PROMPTS_AUTOMATIC, Job, detect_params, weld_params
from cell.job_checks import capture_pose, check_job, safety_limits, station_of
from cell.job_report import JobData, JobReport, job_report
from cell.journal import Journal
from cell.machine import CellActions, CellMachine, CellState
from cell.planning import SeamPass, WeldParams, WeldPath, plan_weld_path
from cell.safety import validate
from cell.watchdog import FINAL_STATES, DeviceWatchdog
from cell.world_seams import X_world_base, collect_seams
from drivers.errors import (
    ConnectionLost,
    DeviceTimeout,
    DriverError,
    EmergencyStop,
    MotionAborted,
    ProtectiveStop,
    TrackFault,
)
from drivers.protocols import RobotMode
from perception.errors import NoSeamFound
from perception.helper_process import HelperProcess

logger = logging.getLogger(__name__)

S = CellState

AUTO_APPROVER = "auto (job approval = false)"


class CellFaulted(WeldcellError):
    """A job cannot start: the cell is in ``fault`` and waits for an operator's acknowledgement."""


class CellBusy(WeldcellError):
    """The runner is still busy with a job (an acknowledgement waits for it to finish)."""






Progress = Callable[[str, dict[str, Any]], None]
"""``on_progress(kind, data)``: ``kind`` is ``"state"`` (data: state, reason), ``"step"`` (data: text) or
``"weld"`` (data: pass, passes, seam_id, pose, poses): called in the runner's thread."""


class JobRunner:
    """Runs jobs on ``cell`` (its drivers connected by :meth:`connect` or already connected), journaling to
    ``journal``. ``on_progress``: see :data:`Progress`. ``status_image``: where the overlay of the last capture is
    written (PNG; None: not written). ``watchdog_period_s``, ``answer_timeout_s``: the device watchdog's poll
    period and, while the robot moves, its answer deadline (:class:`cell.watchdog.DeviceWatchdog`): a robot that
    stops answering is a fault within one period plus the deadline, 0.5 s, which leaves room under the 1 s the cell
    promises for a host whose other work delays the poll (a soak beside two benchmark processes took 1.02 s with a
    0.6 s deadline). ``helper``: a second process for the detections' fine stage (the caller owns it)."""

    def __init__(
        self,
        cell: Cell,
        *,
        journal: Journal,
        on_progress: Progress | None = None,
        status_image: str | Path | None = None,
        watchdog_period_s: float = 0.1,
        answer_timeout_s: float = 0.4,
        helper: HelperProcess | None = None,
    ) -> None:
        self.cell = cell
        self.helper = helper
        self.config = cell.config
        self.journal = journal
        self.limits = safety_limits(cell.config)
        self.on_progress = on_progress
        self.status_image = Path(status_image) if status_image is not None else None
        self._job_lock = threading.Lock()  # held by run() for a whole job; acknowledge() waits for it
        self._data: JobData | None = None
        self._moved_by_fault = False  # a fault was acknowledged and no job has homed the robot since
        arc_output = cell.config.welding.arc_output
        self._arc_index = arc_output if arc_output is not None else WeldParams().arc_do_index
        self._arc_on_since: float | None = None
        self._arc_lock = threading.Lock()
        self.machine = CellMachine(
            CellActions(
                stop_motion=self._stop_motion,
                arc_off=self._arc_off,
                home=self._home,
                move_to_capture=self._move_to_capture,
                capture=self._capture,
                detect=self._detect,
                plan=self._plan,
                weld=self._weld,
                retract=self._retract,
                calibrate=self._calibrate,
                reset_faults=self._reset_faults,
            ),
            journal=journal,
            name=cell.config.robot.name,
        )
        self.watchdog = DeviceWatchdog(
            cell,
            state=lambda: self.machine.state,
            fault_now=self.machine.fault_now,
            period_s=watchdog_period_s,
            answer_timeout_s=answer_timeout_s,
        )

    # ------------------------------------------------------------------------------------------ lifecycle
    def connect(self) -> None:
        """Connect every device (robot first: the fake camera reads its pose)."""
        self.cell.connect()

    @property
    def current(self) -> JobData | None:
        return self._data

    def run(
        self,
        job: Job,
        *,
        job_id: int | None = None,
        dry_run: bool = False,
        approve: Callable[[WeldPath], str | None] | None = None,
    ) -> JobReport:
        """Run ``job`` to its end and return its report (also stored in the journal).

        ``job_id``: a job already submitted to the journal (None: submitted here). ``approve(path)``: for a job
        with ``approval = true``, returns the approving operator's name, or None to reject (None: rejected).
        Raises :class:`CellFaulted` when the cell is in ``fault`` (acknowledge first); a failure during the job does
        not raise: it ends the job in ``fault`` and the report says why.
        """
        with self._job_lock:
            return self._run(job, job_id=job_id, dry_run=dry_run, approve=approve)

    def _run(
        self,
        job: Job,
        *,
        job_id: int | None,
        dry_run: bool,
        approve: Callable[[WeldPath], str | None] | None,
    ) -> JobReport:
        if self.machine.state is S.FAULT:
            raise CellFaulted(
                f"the cell is in fault ({self.machine.fault_reason}); an operator must acknowledge it first"
            )
        if job_id is None:
            job_id = self.journal.submit(job.source)
        params = weld_params(self.config.welding, job.spec.welding, job.spec.seams.seam_filter())
        data = JobData(job=job, job_id=job_id, dry_run=dry_run, params=params)
        self._data = data
        self._arc_index = params.arc_do_index
        t0 = time.monotonic()
        self.watchdog.start()
        try:
            self._emit("state", state=self.machine.state.value, reason=f"job {job_id} ({job.workpiece}) starting")
            if self.machine.start_job(job_id, n_captures=len(job.captures), dry_run=dry_run):
                self._drive(data, approve)
        finally:
            self.watchdog.stop()
        report = job_report(self.machine, data, time.monotonic() - t0)
        try:
            self.journal.set_report(job_id, report.to_dict())
        except WeldcellError:
            logger.exception("job %d: cannot store the report", job_id)
        self._emit("state", state=report.state, reason=report.reason or report.outcome)
        return report

    def _drive(self, data: JobData, approve: Callable[[WeldPath], str | None] | None) -> None:
        m = self.machine
        while True:
            state = m.state
            if state in FINAL_STATES:
                return
            # each trigger names the state it was chosen for: a watchdog's fault (or a pause) that changes the state
            # in between wins, the trigger is not fired and the loop sees the new state (seen=, CellMachine._fire)
            if state is S.AWAITING_APPROVAL:
                assert data.path is not None
                if data.dry_run:
                    m.end_dry_run(seen=state)
                elif not data.job.spec.approval:
                    m.approve(AUTO_APPROVER, seen=state)
                else:
                    who = approve(data.path) if approve is not None else None
                    if who and who.strip():
                        m.approve(who, seen=state)
                    else:
                        m.reject("operator (approval refused or not given)", seen=state)
            elif state is S.PAUSED:
                time.sleep(0.05)  # resume() or abort() comes from another thread (the daemon)
            elif m.advance(seen=state):
                self._emit("state", state=m.state.value, reason=f"{state.value} finished")

    def switch_arc_off(self) -> None:
        """Switch the arc output off now (a service starting after a crash must not leave it on)."""
        self._arc_off()
        logger.info("arc output %d switched off", self._arc_index)

    @property
    def arc_output(self) -> int:
        """The digital output that switches the arc (the job's ``arc_output``, else the cell's)."""
        return self._arc_index

    def arc_reads_on(self) -> bool:
        """Whether the robot reports the arc output on right now (read back through the driver)."""
        outputs = self.cell.robot.state().digital_outputs
        return self._arc_index < len(outputs) and bool(outputs[self._arc_index])

    def acknowledge(self, operator: str, *, wait_s: float = 30.0) -> bool:
        """Leave ``fault`` (clearing latched device faults): an operator has seen the fault and fixed its cause.

        Waits (at most ``wait_s``) until a job that faulted has finished in the runner (its report stored), so that
        the report and the journal say the same; raises :class:`CellBusy` when it has not by then."""
        if not self._job_lock.acquire(timeout=wait_s):
            raise CellBusy(f"the job runner is still finishing its job after {wait_s:.0f} s; acknowledge again")
        try:
            left = self.machine.acknowledge(operator)
            if left:
                self._moved_by_fault = True  # the fault may have stopped the robot anywhere
            return left
        finally:
            self._job_lock.release()

    # ------------------------------------------------------------------------------------------ report

    # ------------------------------------------------------------------------------------------ helpers
    def _emit(self, kind: str, **data: Any) -> None:
        if self.on_progress is not None:
            try:
                self.on_progress(kind, data)
            except Exception:  # a display must never stop the cell
                logger.exception("progress callback failed")

    def _note(self, text: str) -> None:
        """Journal a step inside the current state (an event from and to that state) and log it."""
        data = self._data
        job_id = data.job_id if data is not None else None
        state = self.machine.state.value
        logger.info("job %s: %s: %s", job_id if job_id is not None else "-", state, text)
        self.journal.record_state_change(job_id, state, state, text)
        self._emit("step", text=text)

    @contextlib.contextmanager
    def _timed(self, phase: str) -> Iterator[None]:
        t0 = time.monotonic()
        try:
            yield
        finally:
            if self._data is not None:
                self._data.times[phase] += time.monotonic() - t0

    def _job(self) -> JobData:
        if self._data is None:
            raise RuntimeError("no job is running")
        return self._data

    def _track_position(self) -> float:
        return self.cell.track.position_m() if self.cell.track is not None else 0.0

    def _at_motion_boundary(self, what: str) -> None:
        """Before a motion (or the arc going on): a pause or fault requested meanwhile stops the activity here.

        Its stop found nothing moving between two motions; without this check the activity would go on to the
        end of the weld before the pause took effect."""
        pending = self.machine.pending_interruption()
        if pending is not None:
            raise MotionAborted(f"{pending}: stopped before {what}")

    def _move(self, X_base_tool: np.ndarray, speed_m_s: float, accel_m_s2: float, what: str) -> None:
        self._at_motion_boundary(what)
        data = self._job()
        data.poses_sent += 1
        logger.debug("move_linear (%s) to %s m at %.3f m/s", what, np.round(X_base_tool[:3, 3], 4), speed_m_s)
        self.cell.robot.move_linear(X_base_tool, speed_m_s=speed_m_s, accel_m_s2=accel_m_s2)

    def _move_track(self, position_m: float, what: str) -> None:
        track = self.cell.track
        if track is None:
            if abs(position_m) > 1e-9:
                raise ConfigError(f"{what}: track position {position_m} m, but the cell has no track")
            return
        here = track.position_m()
        if abs(here - position_m) <= max(self.config.track.in_position_window_m, 1e-6):
            return
        self._at_motion_boundary(f"the track move ({what})")
        self._note(f"track {here:.4f} m -> {position_m:.4f} m ({what})")
        track.move_to(position_m, speed_m_s=self.config.track.speed_m_s)

    # ------------------------------------------------------------------------------------------ actions
    def _stop_motion(self) -> None:
        errors: list[BaseException] = []
        for device in (self.cell.robot, self.cell.track):
            if device is None:
                continue
            try:
                device.stop()
            except Exception as err:  # try the other device whatever this one did
                errors.append(err)
        if errors:
            raise errors[0]

    def _arc_off(self) -> None:
        """Switch the arc output off; the arc time is added."""
        with self._arc_lock:
            if self._arc_on_since is not None:
                if self._data is not None:
                    self._data.arc_time_s += time.monotonic() - self._arc_on_since
                self._arc_on_since = None
        # no reconnect here: a fault must not wait on a connect timeout. The controller's watchdog switches the arc
        # off when the host is gone (docs/controller-watchdogs.md); acknowledge() reconnects before anything moves.
        self.cell.robot.set_digital_output(self._arc_index, False)

    def _arc_on(self) -> None:
        self._at_motion_boundary("arc on")
        self.cell.robot.set_digital_output(self._arc_index, True)
        with self._arc_lock:
            self._arc_on_since = time.monotonic()

    def _check_robot_ready(self) -> None:
        st = self.cell.robot.state()
        if st.emergency_stop:
            raise EmergencyStop(f"{self.cell.robot.name}: emergency stop is active ({st.message})")
        if st.protective_stop:
            raise ProtectiveStop(f"{self.cell.robot.name}: protective stop is active ({st.message})")
        if not st.healthy:
            raise DriverError(f"{self.cell.robot.name}: not ready: mode {st.mode.value} ({st.message})")

    def _home(self) -> None:
        data = self._job()
        with self._timed("motion"):
            self._check_robot_ready()
            if data.dry_run:
                self._note("dry run: homing skipped, nothing moves")
                return
            self._arc_off()
            track = self.cell.track
            if track is not None:
                status = track.status()
                if status.fault:
                    raise TrackFault(f"{track.name}: a fault is latched", code=status.fault_code)
                if not status.enabled:
                    track.enable(True)
            home = self.config.home
            if home.pose is not None:
                self._note("robot to its home pose")
                self._move(home.pose.X_base_tool(), self.config.robot.speed_m_s, self.config.robot.accel_m_s2, "home")
            self._move_track(home.track_position_m, "home")
            self._moved_by_fault = False

    def _move_to_capture(self, index: int) -> None:
        data = self._job()
        spec = data.job.captures[index]
        X_base_tool = self.capture_pose(data.job, index)
        reach = self.limits.geometry.reach
        d = float(np.linalg.norm(X_base_tool[:3, 3] - reach.centre_base))
        if d > reach.radius_m:
            raise SafetyViolation(
                f"{data.job.where(f'capture[{index}]')}: the capture pose is {d:.3f} m from the reach centre, "
                f"beyond the reach radius {reach.radius_m:.3f} m"
            )
        with self._timed("capture"):
            if data.dry_run:
                where = self._dry_run_station(data.job) if index == 0 and self._moved_by_fault else None
                self._note(
                    f"dry run: capture {index + 1}/{len(data.job.captures)} from where the robot stands"
                    + (f" ({where})" if where else "")
                )
                return
            self._move_track(spec.track_position_m, f"capture {index + 1}")
            self._note(f"robot to capture pose {index + 1}/{len(data.job.captures)}")
            self._move(X_base_tool, self.config.robot.speed_m_s, self.config.robot.accel_m_s2, f"capture {index + 1}")

    def _dry_run_station(self, job: Job) -> str:
        """After an acknowledged fault: home or the capture pose the robot stands at; SafetyViolation elsewhere."""
        X_base_tool = self.cell.robot.get_X_base_tool()
        track_m = self._track_position()
        where = station_of(self.config, self.limits, job, X_base_tool, track_m)
        if where is None:
            p = X_base_tool[:3, 3]
            raise SafetyViolation(
                f"dry run after a fault: the tool stands at [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}] m (track "
                f"{track_m:.4f} m), neither at home nor at one of the job's {len(job.captures)} capture pose(s), "
                "and a dry run captures only from those (it moves nothing); run the job (it homes first) or bring "
                "the robot home, then dry-run again"
            )
        return where

    def check_job(self, job: Job) -> None:
        """Refuse a job the cell must not even queue (:func:`cell.job_checks.check_job`)."""
        check_job(self.config, self.limits, job)

    def capture_pose(self, job: Job, index: int) -> np.ndarray:
        """(4, 4) ``X_base_tool`` of capture ``index`` of ``job`` with the carriage at its track position."""
        return capture_pose(self.config, self.limits, job, index)

    def _capture(self, index: int) -> None:
        data = self._job()
        X_tool_camera = self.cell.X_tool_camera
        if X_tool_camera is None:
            raise ConfigError(
                f"{self.config.where('hand_eye')}: planning needs the camera's pose on the tool; add [hand_eye]"
            )
        with self._timed("capture"):
            camera = self.cell.camera
            try:
                frame = camera.capture(timeout_s=self.config.camera.timeout_s)
            except ConnectionLost as err:
                self._note(f"camera connection lost ({err}): reconnecting once")
                camera.connect()
                frame = camera.capture(timeout_s=self.config.camera.timeout_s)
            X_base_tool = self.cell.robot.get_X_base_tool()
            t = self._track_position()
            prompts = data.job.prompts_px(index)
            spec = data.job.captures[index]
            changes: dict[str, Any] = {"X_base_tool": X_base_tool, "X_tool_camera": X_tool_camera}
            if prompts is not None:
                changes["prompts_px"] = prompts
            elif spec.prompts == PROMPTS_AUTOMATIC:
                changes["prompts_px"] = None
            capture = dataclasses.replace(frame, **changes)
            data.captures.append((t, capture))
        p = X_base_tool[:3, 3]
        self._note(
            f"capture {index + 1}: {capture.shape[1]}x{capture.shape[0]} frame, tool at "
            f"[{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}] m, track at {t:.4f} m"
        )

    def _detect(self) -> None:
        from perception.detect import detect

        data = self._job()
        params = detect_params(self.config.detection)
        failures: list[str] = []
        with self._timed("detection"):
            data.results = []
            for k, (_t, capture) in enumerate(data.captures):
                try:
                    result = detect(capture, params, helper=self.helper)
                except NoSeamFound as err:
                    failures.append(f"capture {k + 1}: {err}")
                    data.results.append(None)
                    continue
                data.results.append(result)
                self._note(f"capture {k + 1}: {len(result.seams)} seam(s) found")
            found = [(t, r.seams) for (t, _c), r in zip(data.captures, data.results, strict=True) if r is not None]
            if not found:
                raise NoSeamFound("no seam in any capture: " + "; ".join(failures))
            dc = self.config.detection
            data.seams = collect_seams(
                found,
                axis_base=self.limits.geometry.axis_base,
                tol_m=dc.merge_tol_m,
                min_overlap_m=dc.merge_min_overlap_m,
            )
        self._write_status_image(data)
        self._note(f"{len(data.seams)} distinct seam(s) from {len(found)} capture(s)")

    def _write_status_image(self, data: JobData) -> None:
        if self.status_image is None:
            return
        pairs = zip(reversed(data.captures), reversed(data.results), strict=True)
        for k, ((_t, capture), result) in enumerate(pairs):
            if result is None:
                continue
            try:
                from perception.overlay import draw_overlay, write_png

                self.status_image.parent.mkdir(parents=True, exist_ok=True)
                tmp = self.status_image.with_name(self.status_image.name + ".tmp.png")
                write_png(str(tmp), draw_overlay(capture, result))
                tmp.replace(self.status_image)
                data.status_capture = len(data.captures) - 1 - k
            except Exception:  # the status page is a convenience: never fail a job for it
                logger.exception("cannot write the status image %s", self.status_image)
            return

    def _plan(self) -> None:
        data = self._job()
        with self._timed("planning"):
            t = self._track_position()
            X_base_tool = self.cell.robot.get_X_base_tool()
            p_world = (X_world_base(t, self.limits.geometry.axis_base) @ X_base_tool)[:3, 3]
            path = plan_weld_path(
                data.seams, data.params, geometry=self.limits.geometry, track_position_m=t, p_world_start=p_world
            )
            if not path.passes:
                reasons = "; ".join(f"seam {i}: {r}" for i, r in path.skipped)
                raise NoSeamFound(f"no seam left to weld after the job's [seams] filter ({reasons})")
            validate(path, self.limits)
            data.path = path
            data.planned_from = (t, p_world)
            data.next_pass = 0
            data.resume_from = 0
        self._note(
            f"path of {len(path.passes)} pass(es), {sum(p.length_m for p in path.passes):.3f} m of weld, "
            f"track at {', '.join(f'{x:.3f}' for x in path.track_positions_m)} m: validated"
        )

    def _weld(self) -> None:
        data = self._job()
        path = data.path
        assert path is not None, "weld before plan"
        with self._timed("motion"):
            if data.pending_retract is not None:  # paused while retracting: finish that first
                self._move(data.pending_retract, path.params.approach_speed_m_s, path.params.accel_m_s2, "retract")
                data.pending_retract = None
            while data.next_pass < len(path.passes):
                self._weld_pass(data, path, data.next_pass)

    def _weld_pass(self, data: JobData, path: WeldPath, i: int) -> None:
        p: SeamPass = path.passes[i]
        params = path.params
        n = len(path.passes)
        self._move_track(p.track_position_m, f"pass {i + 1}")
        travel = p.travel  # arc_on ... arc_off
        start = data.resume_from
        if start:
            self._note(f"pass {i + 1}/{n} (seam {p.seam_id}): resuming at travel pose {start}")
            X_start = travel[start].X_base_tcp
            X_above = X_start.copy()
            X_above[:3, 3] -= params.approach_m * X_start[:3, 2]
            self._move(X_above, params.air_speed_m_s, params.accel_m_s2, "resume approach")
            self._move(X_start, params.approach_speed_m_s, params.accel_m_s2, "resume arc on")
        else:
            self._move(p.approach.X_base_tcp, p.approach.speed_m_s, params.accel_m_s2, f"pass {i + 1} approach")
            self._move(p.arc_on.X_base_tcp, p.arc_on.speed_m_s, params.accel_m_s2, f"pass {i + 1} arc on")
        self._arc_on()
        self._note(f"pass {i + 1}/{n} (seam {p.seam_id}): arc on")
        if params.arc_on_dwell_s > 0:
            time.sleep(params.arc_on_dwell_s)
        rest = travel[start + 1 :]
        if rest:
            blends = [w.blend_m for w in rest[:-1]]
            blend = min(blends) if blends else 0.0

            def progress(k: int) -> None:
                data.resume_from = start + 1 + k
                self._emit(
                    "weld", **{"pass": i + 1, "passes": n, "seam_id": p.seam_id, "pose": k + 1, "poses": len(rest)}
                )

            self._at_motion_boundary(f"pass {i + 1} travel")
            data.poses_sent += len(rest)
            self.cell.robot.stream_path(
                [w.X_base_tcp for w in rest],
                speed_m_s=params.travel_speed_m_s,
                blend_m=blend,
                accel_m_s2=params.accel_m_s2,
                timeout_s=60.0 + 3.0 * p.length_m / params.travel_speed_m_s,
                on_progress=progress,
            )
        if params.arc_off_dwell_s > 0:
            time.sleep(params.arc_off_dwell_s)
        self._arc_off()
        self._note(f"pass {i + 1}/{n} (seam {p.seam_id}): arc off, {p.length_m * 1e3:.1f} mm welded")
        data.seams_welded += 1
        data.next_pass, data.resume_from = i + 1, 0
        data.pending_retract = p.retract.X_base_tcp
        self._move(p.retract.X_base_tcp, p.retract.speed_m_s, params.accel_m_s2, f"pass {i + 1} retract")
        data.pending_retract = None

    def _retract(self) -> None:
        data = self._job()
        with self._timed("motion"):
            if data.dry_run:
                return
            self._arc_off()
            path = data.path
            params = path.params if path is not None else data.params
            if data.pending_retract is not None:
                self._note("aborted: finishing the pass's retract")
                self._move(data.pending_retract, params.approach_speed_m_s, params.accel_m_s2, "retract")
                data.pending_retract = None
            elif path is not None and data.next_pass < len(path.passes):
                # aborted mid-job: back the torch off the work along its own axis first
                X = self.cell.robot.get_X_base_tool()
                X_up = X.copy()
                X_up[:3, 3] -= params.retract_m * X[:3, 2]
                self._note("aborted: torch backed off the work")
                self._move(X_up, params.approach_speed_m_s, params.accel_m_s2, "abort retract")
            home = self.config.home
            if home.pose is not None:
                self._note("robot back to its home pose")
                self._move(home.pose.X_base_tool(), self.config.robot.speed_m_s, self.config.robot.accel_m_s2, "home")

    def _calibrate(self) -> None:
        raise WeldcellError("hand-eye calibration runs through 'weldcell calibrate hand-eye', not the job runner")

    def _reset_faults(self) -> None:
        """On acknowledgement: reconnect what dropped, clear latched robot and track faults, arc off (checked)."""
        robot = self.cell.robot
        try:
            st = robot.state()
        except (ConnectionLost, DeviceTimeout):
            robot.connect()
            st = robot.state()
        reset = getattr(robot, "reset_faults", None)
        if reset is not None:  # always: a controller-side watchdog's alarm (FANUC UALM) is not in the robot state
            reset()
        elif st.protective_stop or st.emergency_stop or st.mode is RobotMode.FAULT:
            unlock = getattr(robot, "unlock_protective_stop", None)
            if unlock is None:
                raise DriverError(f"{robot.name}: cannot clear '{st.message}' from here; clear it on the controller")
            unlock()
        track = self.cell.track
        if track is not None:
            try:
                status = track.status()
            except (ConnectionLost, DeviceTimeout):
                track.connect()
                status = track.status()
            if status.fault:
                track.reset_fault()
            track.enable(True)
        self._arc_off()
        if self.arc_reads_on():
            raise DriverError(f"{robot.name}: the arc output {self._arc_index} still reads on after switching it off")
