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
stand (with their measured pose), then the path is planned and validated and the job ends without welding.

The report (:class:`JobReport`) gives the final state, the seams found, planned and welded, the poses sent to the
robot, the arc-on time and the cycle time split into capture (moves to the capture poses and frames), detection,
planning (with validation) and motion (homing, welding, retracting).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cell.config import CellConfig
from cell.errors import ConfigError, SafetyViolation, WeldcellError
from cell.factory import Cell
from cell.job import PROMPTS_AUTOMATIC, Job, detect_params, weld_params
from cell.journal import Journal
from cell.machine import CellActions, CellMachine, CellState
from cell.planning import CellGeometry, Reach, SeamPass, TrackAxis, WeldParams, WeldPath, plan_weld_path
from cell.safety import SafetyLimits, validate
from cell.world_seams import WorldSeam, X_world_base, collect_seams
from drivers.errors import ConnectionLost, DeviceTimeout, DriverError, EmergencyStop, ProtectiveStop, TrackFault
from drivers.protocols import RobotMode
from perception.capture import Capture
from perception.errors import NoSeamFound
from perception.seams import DetectionResult

logger = logging.getLogger(__name__)

S = CellState

AUTO_APPROVER = "auto (job approval = false)"
FINAL_STATES = (S.DONE, S.FAULT, S.IDLE)
MOTION_STATES = (S.HOMING, S.MOVING_TO_CAPTURE, S.WELDING, S.RETRACTING)
"""States whose work moves the robot (or has the arc on): the watchdog's answer deadline applies in these."""
CYCLE_PHASES = ("capture", "detection", "planning", "motion")
MAX_DWELL_S = 10.0
"""The longest arc-on or arc-off dwell a job may ask for."""


class CellFaulted(WeldcellError):
    """A job cannot start: the cell is in ``fault`` and waits for an operator's acknowledgement."""


class CellBusy(WeldcellError):
    """The runner is still busy with a job (an acknowledgement waits for it to finish)."""


def safety_limits(config: CellConfig) -> SafetyLimits:
    """The :class:`SafetyLimits` of ``config``'s ``[safety]`` and ``[track]``; ConfigError without ``[safety]``."""
    sc = config.safety
    if sc is None:
        raise ConfigError(
            f"{config.where('safety')}: running jobs needs a [safety] table (workspace box, reach, limits); "
            "see examples/sim-cell.toml"
        )
    track = None
    if config.track.kind != "none":
        lo, hi = config.track.soft_limits_m
        track = TrackAxis(lo, hi, np.asarray(sc.track_axis_base, dtype=np.float64))
    reach = Reach(sc.reach_radius_m, sc.reach_preferred_m, np.asarray(sc.reach_centre_base, dtype=np.float64))
    return SafetyLimits(
        workspace_min_world=np.asarray(sc.workspace_min_world, dtype=np.float64),
        workspace_max_world=np.asarray(sc.workspace_max_world, dtype=np.float64),
        geometry=CellGeometry(reach, track),
        max_speed_m_s=sc.max_speed_m_s,
        max_accel_m_s2=sc.max_accel_m_s2,
        max_blend_m=sc.max_blend_m,
        max_step_m=sc.max_step_m,
        max_step_rad=math.radians(sc.max_step_deg),
        max_tilt_rad=math.radians(sc.max_tilt_deg),
    )


@dataclass
class JobReport:
    """What a job did. ``state``: the machine's final state (``done``, ``fault``, ``idle``); ``outcome``:
    ``welded``, ``dry_run``, ``rejected``, ``no_seam``, ``refused`` (a safety violation, nothing moved for
    welding) or ``fault``; ``reason``: why it did not weld (None when it did). Times in seconds."""

    job_id: int
    workpiece: str
    state: str
    outcome: str
    reason: str | None
    dry_run: bool
    seams_found: int
    seams_planned: int
    seams_welded: int
    poses_sent: int
    arc_time_s: float
    cycle_s: dict[str, float]
    path: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["arc_time_s"] = round(self.arc_time_s, 3)
        out["cycle_s"] = {k: round(v, 3) for k, v in self.cycle_s.items()}
        return out


@dataclass
class JobData:
    """What the running (or last) job has gathered and done so far: its captures ((track position m, Capture)),
    detection results, world-frame seams, the validated path, where welding stands (``next_pass``, ``resume_from``:
    the travel pose a paused pass resumes from; ``pending_retract``: a retract pose not yet reached), counters
    and the seconds spent per cycle phase."""

    job: Job
    job_id: int
    dry_run: bool
    params: WeldParams
    captures: list[tuple[float, Capture]] = field(default_factory=list)
    results: list[DetectionResult | None] = field(default_factory=list)
    seams: list[WorldSeam] = field(default_factory=list)
    path: WeldPath | None = None
    next_pass: int = 0
    resume_from: int = 0
    pending_retract: np.ndarray | None = None
    seams_welded: int = 0
    poses_sent: int = 0
    arc_time_s: float = 0.0
    times: dict[str, float] = field(default_factory=lambda: dict.fromkeys(CYCLE_PHASES, 0.0))


Progress = Callable[[str, dict[str, Any]], None]
"""``on_progress(kind, data)``: ``kind`` is ``"state"`` (data: state, reason), ``"step"`` (data: text) or
``"weld"`` (data: pass, passes, seam_id, pose, poses): called in the runner's thread."""


class JobRunner:
    """Runs jobs on ``cell`` (its drivers connected by :meth:`connect` or already connected), journaling to
    ``journal``. ``on_progress``: see :data:`Progress`. ``status_image``: where the overlay of the last capture is
    written (PNG; None: not written). ``watchdog_period_s``: how often the watchdog polls the devices;
    ``answer_timeout_s``: while the robot moves (:data:`MOTION_STATES`), a device whose status has not come back
    within this long is a fault (the poll runs in a thread of its own, so a device that hangs cannot hold the
    watchdog up)."""

    def __init__(
        self,
        cell: Cell,
        *,
        journal: Journal,
        on_progress: Progress | None = None,
        status_image: str | Path | None = None,
        watchdog_period_s: float = 0.1,
        answer_timeout_s: float = 0.6,
    ) -> None:
        self.cell = cell
        self.config = cell.config
        self.journal = journal
        self.limits = safety_limits(cell.config)
        self.on_progress = on_progress
        self.status_image = Path(status_image) if status_image is not None else None
        self.watchdog_period_s = watchdog_period_s
        self.answer_timeout_s = answer_timeout_s
        self._job_lock = threading.Lock()  # held by run() for a whole job; acknowledge() waits for it
        self._data: JobData | None = None
        arc_output = cell.config.welding.arc_output
        self._arc_index = arc_output if arc_output is not None else WeldParams().arc_do_index
        self._arc_on_since: float | None = None
        self._arc_lock = threading.Lock()
        self._watchdog_stop = threading.Event()
        self._watchdog_thread: threading.Thread | None = None
        self._watchdog_fired = False
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
        self._start_watchdog()
        try:
            self._emit("state", state=self.machine.state.value, reason=f"job {job_id} ({job.workpiece}) starting")
            if self.machine.start_job(job_id, n_captures=len(job.captures), dry_run=dry_run):
                self._drive(data, approve)
        finally:
            self._stop_watchdog()
        report = self._report(data, time.monotonic() - t0)
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
            if state is S.AWAITING_APPROVAL:
                assert data.path is not None
                if data.dry_run:
                    m.end_dry_run()
                elif not data.job.spec.approval:
                    m.approve(AUTO_APPROVER)
                else:
                    who = approve(data.path) if approve is not None else None
                    if who and who.strip():
                        m.approve(who)
                    else:
                        m.reject("operator (approval refused or not given)")
            elif state is S.PAUSED:
                time.sleep(0.05)  # resume() or abort() comes from another thread (the daemon)
            else:
                before = state
                if m.advance():
                    self._emit("state", state=m.state.value, reason=f"{before.value} finished")

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
            return self.machine.acknowledge(operator)
        finally:
            self._job_lock.release()

    # ------------------------------------------------------------------------------------------ report
    def _report(self, data: JobData, total_s: float) -> JobReport:
        m = self.machine
        state = m.state
        reason: str | None = None
        err = m.last_error
        if state is S.DONE:
            outcome = "welded"
        elif state is S.FAULT:
            reason = m.fault_reason
            if isinstance(err, NoSeamFound):
                outcome = "no_seam"
            elif isinstance(err, SafetyViolation):
                outcome = "refused"
            else:
                outcome = "fault"
        elif data.dry_run and data.path is not None:
            outcome, reason = "dry_run", "dry run: planned and validated, nothing moved or welded"
        else:
            outcome, reason = "rejected", "the operator did not approve the path"
        cycle = dict(data.times)
        cycle["total"] = total_s
        path = data.path
        return JobReport(
            job_id=data.job_id,
            workpiece=data.job.workpiece,
            state=state.value,
            outcome=outcome,
            reason=reason,
            dry_run=data.dry_run,
            seams_found=len(data.seams),
            seams_planned=len(path.passes) if path is not None else 0,
            seams_welded=data.seams_welded,
            poses_sent=data.poses_sent,
            arc_time_s=data.arc_time_s,
            cycle_s=cycle,
            path=path.summary() if path is not None else None,
        )

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

    def _move(self, X_base_tool: np.ndarray, speed_m_s: float, accel_m_s2: float, what: str) -> None:
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
                self._note(f"dry run: capture {index + 1}/{len(data.job.captures)} from where the robot stands")
                return
            self._move_track(spec.track_position_m, f"capture {index + 1}")
            self._note(f"robot to capture pose {index + 1}/{len(data.job.captures)}")
            self._move(X_base_tool, self.config.robot.speed_m_s, self.config.robot.accel_m_s2, f"capture {index + 1}")

    def check_job(self, job: Job) -> None:
        """Refuse (ConfigError naming the job's key and the cell's limit) a job the cell must not even queue: speeds,
        acceleration and blend over the cell's ``[safety]`` limits, another arc output than the cell's (its
        controller-side watchdog covers that one), capture poses beyond the reach or track positions outside the
        track's soft limits, dwell times and distances out of any sensible range, seam ids that are not 31-bit
        integers. Numbers are finite already (the job's tables refuse inf and nan)."""
        lim = self.limits
        params = weld_params(self.config.welding, job.spec.welding, job.spec.seams.seam_filter())
        w = job.spec.welding
        for key, value, limit, name in (
            ("travel_speed_m_s", params.travel_speed_m_s, lim.max_speed_m_s, "max_speed_m_s"),
            ("approach_speed_m_s", params.approach_speed_m_s, lim.max_speed_m_s, "max_speed_m_s"),
            ("air_speed_m_s", params.air_speed_m_s, lim.max_speed_m_s, "max_speed_m_s"),
            ("accel_m_s2", params.accel_m_s2, lim.max_accel_m_s2, "max_accel_m_s2"),
            ("blend_m", params.blend_m, lim.max_blend_m, "max_blend_m"),
        ):
            if not value <= limit:
                raise ConfigError(
                    f"{job.where(f'welding.{key}')}: {value} exceeds the cell's limit [safety] {name} = {limit}"
                )
        reach = lim.geometry.reach
        for key in ("approach_m", "retract_m", "stickout_m"):
            value = getattr(params, key)
            if not value <= reach.radius_m:
                raise ConfigError(
                    f"{job.where(f'welding.{key}')}: {value} m exceeds the reach radius [safety] reach_radius_m = "
                    f"{reach.radius_m} m"
                )
        for key in ("arc_on_dwell_s", "arc_off_dwell_s"):
            value = getattr(params, key)
            if not value <= MAX_DWELL_S:
                raise ConfigError(f"{job.where(f'welding.{key}')}: {value} s exceeds the limit of {MAX_DWELL_S} s")
        cell_arc = self.config.welding.arc_output if self.config.welding.arc_output is not None else 0
        if w.arc_output is not None and w.arc_output != cell_arc:
            raise ConfigError(
                f"{job.where('welding.arc_output')}: {w.arc_output} is not the cell's arc output [welding] "
                f"arc_output = {cell_arc} (the one its controller-side watchdog switches off)"
            )
        for seam_id in job.spec.seams.ids or ():
            if not 0 <= seam_id < 2**31:
                raise ConfigError(f"{job.where('seams.ids')}: {seam_id} is not a seam id (0 <= id < 2^31)")
        track = lim.geometry.track
        for i, capture in enumerate(job.captures):
            t = capture.track_position_m
            if track is None and t != 0.0:
                raise ConfigError(
                    f"{job.where(f'capture[{i}].track_position_m')}: {t} m, but the cell has no track ([track])"
                )
            if track is not None and not track.min_m <= t <= track.max_m:
                raise ConfigError(
                    f"{job.where(f'capture[{i}].track_position_m')}: {t} m is outside the track's soft limits "
                    f"[track] soft_limit_min_m..soft_limit_max_m = {track.min_m}..{track.max_m} m"
                )
            X = self.capture_pose(job, i)
            d = float(np.linalg.norm(X[:3, 3] - reach.centre_base))
            if not d <= reach.radius_m:
                raise ConfigError(
                    f"{job.where(f'capture[{i}]')}: the capture pose is {d:.3f} m from the reach centre, beyond "
                    f"[safety] reach_radius_m = {reach.radius_m} m"
                )

    def capture_pose(self, job: Job, index: int) -> np.ndarray:
        """(4, 4) ``X_base_tool`` of capture ``index`` of ``job`` with the carriage at its track position."""
        spec = job.captures[index]
        X = spec.X_base_tool()
        if job.spec.frame == "base":
            return X
        fixture = self.config.fixture
        if fixture is None:
            raise ConfigError(
                f"{job.where('frame')}: the job's poses are fixture-relative but {self.config.where('fixture')} "
                "is missing: add [fixture] X_world_fixture to the cell config"
            )
        X_world_fixture = np.asarray(fixture.X_world_fixture, dtype=np.float64)
        X_base_world = X_world_base(-spec.track_position_m, self.limits.geometry.axis_base)
        return X_base_world @ X_world_fixture @ X

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
                    result = detect(capture, params)
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
        for (_t, capture), result in zip(reversed(data.captures), reversed(data.results), strict=True):
            if result is None:
                continue
            try:
                from perception.overlay import draw_overlay, write_png

                self.status_image.parent.mkdir(parents=True, exist_ok=True)
                tmp = self.status_image.with_name(self.status_image.name + ".tmp.png")
                write_png(str(tmp), draw_overlay(capture, result))
                tmp.replace(self.status_image)
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

    # ------------------------------------------------------------------------------------------ watchdog
    def _start_watchdog(self) -> None:
        self._watchdog_stop.clear()
        self._watchdog_fired = False
        self._watchdog_thread = threading.Thread(target=self._watch, name="cell-watchdog", daemon=True)
        self._watchdog_thread.start()

    def _stop_watchdog(self) -> None:
        self._watchdog_stop.set()
        thread, self._watchdog_thread = self._watchdog_thread, None
        if thread is not None:
            thread.join(timeout=10.0)

    def _watch(self) -> None:
        poller = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="cell-device-poll")
        try:
            while not self._watchdog_stop.wait(self.watchdog_period_s):
                if self.machine.state in (*FINAL_STATES, S.PAUSED) or self._watchdog_fired:
                    continue
                # the deadline applies while something moves or the arc may be on; while capturing, detecting or
                # planning this process's own computing can hold the GIL for longer than that (the drivers' own
                # timeouts still end a poll that gets no answer)
                limit = self.answer_timeout_s if self.machine.state in MOTION_STATES else None
                poll = poller.submit(self._device_problem)
                try:
                    problem = poll.result(timeout=limit)
                except concurrent.futures.TimeoutError:
                    problem = f"no status from the robot or the track within {self.answer_timeout_s:.1f} s"
                except Exception as err:  # a bug in a driver's status path must still stop the cell
                    problem = f"device status failed: {type(err).__name__}: {err}"
                if problem is not None and not self._watchdog_stop.is_set():
                    self._watchdog_fired = True
                    logger.error("watchdog: %s", problem)
                    self.machine.fault_now(f"watchdog: {problem}")
        finally:
            poller.shutdown(wait=False, cancel_futures=True)

    def _device_problem(self) -> str | None:
        """Why the cell must stop now, or None."""
        robot, track = self.cell.robot, self.cell.track
        try:
            st = robot.state()
        except DriverError as err:
            return f"{robot.name} unreachable: {type(err).__name__}: {err}"
        if st.emergency_stop:
            return f"{robot.name}: emergency stop ({st.message})"
        if st.protective_stop:
            return f"{robot.name}: protective stop ({st.message})"
        if st.mode is RobotMode.FAULT:
            return f"{robot.name}: fault ({st.message})"
        if track is not None:
            try:
                status = track.status()
            except DriverError as err:
                return f"{track.name} unreachable: {type(err).__name__}: {err}"
            if status.fault:
                return f"{track.name}: fault latched (code {status.fault_code}) at {status.position_m:.4f} m"
        return None
