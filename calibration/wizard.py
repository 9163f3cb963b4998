"""The hand-eye calibration wizard: the one part of ``calibration`` that talks to devices, through the
driver Protocols (:class:`drivers.protocols.Robot`, ``Camera``, ``Track``).

Stages (:meth:`HandEyeWizard.run`), each reported to a :class:`WizardUI`:

1. **devices**: connect the robot, the track (when there is one) and the camera; the robot must be healthy and
   still, the track not faulted, and the camera must deliver a frame (its intrinsics are used from then on).
2. **plan**: ``n_poses`` views plus one held-out view from :func:`calibration.planner.plan_eye_in_hand` (or
   ``plan_eye_to_hand``) around the nominal board pose, inside the workspace (or a given list of poses). Before
   anything moves, the plan is checked: every tool position inside the workspace, enough poses, and motion that
   can determine the hand-eye transform (:func:`calibration.handeye.check_motion` on the views the nominal
   transforms predict: no pure translations, no rotations all about one axis). The operator confirms it.
3. **views**: the robot moves to each pose in a straight line (or, in manual mode, the operator jogs it there
   and presses Enter), waits ``settle_s``, and the camera captures; the tool pose is read before and after the
   capture (a view whose pose changed meanwhile is skipped). The board is detected; a view with fewer than
   ``min_corners`` corners, a poor board fit, or (manual mode) the same pose as an earlier view is skipped,
   saying why. Fewer than ``min_views`` usable views stop the calibration with a :class:`CalibrationError`.
4. **solve**: :func:`calibration.handeye.solve_hand_eye_from_observations`; per-view residuals in px, mm, deg.
5. **verify**: at the held-out pose (not used by the solver) the board corners are predicted from the solved
   transforms and compared with the corners the camera sees, in pixels.
6. **verdict**: :class:`VerdictThresholds`; ``fail`` refuses to write the result.
7. **write** (:func:`write_result_file`): the JSON the cell's ``[hand_eye] path`` reads, atomically, the
   previous file kept as ``FILE.prev``. Nothing is written before this stage.

The robot is told to stop (:meth:`Robot.stop`) whenever the run ends early (Ctrl-C, a device error, a refused
calibration), at any stage; the exception then propagates unchanged.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board import detect_board
from calibration.errors import CalibrationError
from calibration.handeye import DegeneracyLimits, HandEyeResult, solve_hand_eye_from_observations
from calibration.result_file import PREVIOUS_SUFFIX, result_document, write_result_file
from calibration.verdict import Assessment, Verdict, VerdictThresholds, Verification, assess, verify
from calibration.views import (
    CalibrationPlan,
    ViewRecord,
    WizardParams,
    make_plan,
    visible_corner_count,
    wizard_limits,
)
from drivers.errors import DriverError
from drivers.protocols import Camera, Robot, RobotState, Track, TrackStatus
from perception.capture import CameraIntrinsics
from perception.transforms import rotation_angle_rad

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


class WizardCancelled(CalibrationError):
    """The operator declined a confirmation; nothing was written (and nothing moved after the refusal)."""


# ================================================================================================ value types
@dataclass(frozen=True)
class DeviceReport:
    """What the device check found: the robot's state (``X_base_tool`` where it started), the track's status
    (None without a track) and the camera's intrinsics (from its first frame)."""

    robot: RobotState
    track: TrackStatus | None
    intrinsics: CameraIntrinsics

    @property
    def X_base_tool_start(self) -> FloatArray:
        return self.robot.X_base_tool


@dataclass(frozen=True)
class WizardOutcome:
    """A finished run: the solution, every view, the verification, the verdict, and the file written (None when
    the verdict refused it) with the previous version kept beside it (None when there was none)."""

    result: HandEyeResult
    views: tuple[ViewRecord, ...]
    verification: Verification
    assessment: Assessment
    intrinsics: CameraIntrinsics
    written: Path | None
    previous: Path | None


# ================================================================================================ the operator
class WizardUI(Protocol):
    """How the wizard talks to the operator (the CLI renders it with rich; tests script it)."""

    def stage(self, title: str) -> None:
        """A new stage begins."""

    def info(self, text: str) -> None:
        """A line for the operator."""

    def warn(self, text: str) -> None:
        """A warning: something is off but the run goes on."""

    def devices_ready(self, report: DeviceReport) -> None:
        """The devices passed their check."""

    def plan_ready(self, plan: CalibrationPlan, params: WizardParams) -> None:
        """The plan passed its checks and is about to be confirmed."""

    def confirm(self, question: str) -> bool:
        """Ask a yes/no question; False cancels the run."""

    def ask_operator(self, text: str, X_base_tool_suggested: FloatArray | None) -> str:
        """Manual mode: wait until the operator has jogged the robot (Enter: the line, "" when empty). "q" stops
        collecting views. ``X_base_tool_suggested``: the planned pose for this view, (4, 4), metres."""

    def view_started(self, index: int, total: int, what: str) -> None:
        """View ``index`` (0-based) of ``total`` begins; ``what``: "moving", "capturing"... The held-out view comes
        last, as ``index == total`` (the number of views taken before it)."""

    def view_done(self, record: ViewRecord, total: int) -> None:
        """A view was captured (and used or skipped)."""

    def solved(self, result: HandEyeResult, views: Sequence[ViewRecord]) -> None:
        """The solution, with the used views in the order of its residual arrays."""

    def verified(self, verification: Verification) -> None:
        """The held-out check is done."""

    def assessed(self, assessment: Assessment, thresholds: VerdictThresholds) -> None:
        """The verdict."""


class LoggingUI:
    """A :class:`WizardUI` for scripts: everything goes to the log, every confirmation is granted, and manual
    mode is not available (it needs an operator)."""

    def stage(self, title: str) -> None:
        logger.info("calibration: %s", title)

    def info(self, text: str) -> None:
        logger.info("calibration: %s", text)

    def warn(self, text: str) -> None:
        logger.warning("calibration: %s", text)

    def devices_ready(self, report: DeviceReport) -> None:
        logger.info("calibration: devices ready, camera %dx%d", report.intrinsics.width, report.intrinsics.height)

    def plan_ready(self, plan: CalibrationPlan, params: WizardParams) -> None:
        logger.info("calibration: plan of %d views and one held-out view", plan.n_views)

    def confirm(self, question: str) -> bool:
        logger.info("calibration: %s yes (LoggingUI confirms everything)", question)
        return True

    def ask_operator(self, text: str, X_base_tool_suggested: FloatArray | None) -> str:
        raise CalibrationError("manual mode needs an operator; LoggingUI cannot jog the robot")

    def view_started(self, index: int, total: int, what: str) -> None:
        logger.debug("calibration: view %d/%d: %s", index + 1, total, what)

    def view_done(self, record: ViewRecord, total: int) -> None:
        if record.usable:
            assert record.observation is not None
            logger.info("calibration: view %d/%d: %d corners", record.index + 1, total, record.observation.n_corners)
        else:
            logger.warning("calibration: view %d/%d skipped: %s", record.index + 1, total, record.skipped)

    def solved(self, result: HandEyeResult, views: Sequence[ViewRecord]) -> None:
        logger.info("calibration: solved from %d views, rms %s px", result.n_views, result.rms_px)

    def verified(self, verification: Verification) -> None:
        logger.info("calibration: held-out view rms %.3f px", verification.rms_px)

    def assessed(self, assessment: Assessment, thresholds: VerdictThresholds) -> None:
        logger.info("calibration: verdict %s %s", assessment.verdict.value, "; ".join(assessment.reasons))


# ================================================================================================ the wizard
class HandEyeWizard:
    """One calibration run on real (or simulated) devices; see the module docstring for the stages.

    ``robot``, ``camera``: the drivers (connected by the wizard). ``track``: connected and checked when given
    (a fake camera reads the track position). ``ui``: the operator (:class:`LoggingUI` for scripts).
    ``manual``: the operator jogs the robot to every view instead of the wizard moving it.
    ``out``: the result file; None solves and verifies without writing. ``plan_poses``: explicit (4, 4)
    ``X_base_tool`` poses instead of the planner's (the last one is the held-out pose). ``source``: recorded in
    the result file (e.g. the config file's path).
    """

    def __init__(
        self,
        robot: Robot,
        camera: Camera,
        params: WizardParams,
        *,
        track: Track | None = None,
        ui: WizardUI | None = None,
        manual: bool = False,
        out: str | os.PathLike[str] | None = None,
        plan_poses: Sequence[ArrayLike] | None = None,
        source: str = "",
    ) -> None:
        self.robot = robot
        self.camera = camera
        self.track = track
        self.params = params
        self.ui: WizardUI = ui if ui is not None else LoggingUI()
        self.manual = manual
        self.out = Path(out) if out is not None else None
        self.plan_poses = None if plan_poses is None else [np.asarray(X, dtype=np.float64) for X in plan_poses]
        self.source = source
        self._robot_connected = False

    # ------------------------------------------------------------------ the whole run
    def run(self) -> WizardOutcome:
        """All stages; on any exception (Ctrl-C included) the robot is told to stop and the exception
        propagates. The result file is written last, atomically, only for a verdict other than ``fail``."""
        try:
            return self._run()
        except BaseException as err:
            self._stop_robot(err)
            raise

    def _run(self) -> WizardOutcome:
        p = self.params
        self.ui.stage("Checking the devices")
        report = self.check_devices()
        self.ui.devices_ready(report)

        self.ui.stage("Planning the views")
        plan = self.plan_and_confirm(report.intrinsics)

        self.ui.stage("Collecting the views")
        views = self.collect_views(plan, report.intrinsics)
        used = self._usable(views)

        self.ui.stage(f"Solving ({p.mode.value}) from {len(used)} views")
        result = solve_hand_eye_from_observations(
            [v.X_base_tool for v in used],
            [v.observation for v in used if v.observation is not None],
            K=report.intrinsics.K,
            mode=p.mode,
            limits=wizard_limits(p),
        )
        self.ui.solved(result, used)

        self.ui.stage("Verifying at the held-out pose")
        verification = self.verify_holdout(plan, result, report.intrinsics, views)
        self.ui.verified(verification)
        if not self.manual:
            self._move(report.X_base_tool_start, what="back to the start pose")

        assessment = assess(result, verification, p.thresholds)
        self.ui.assessed(assessment, p.thresholds)
        if assessment.verdict is Verdict.FAIL:
            raise CalibrationError(
                f"verdict fail ({'; '.join(r for r in assessment.reasons if r.endswith('(fail)'))}); "
                f"nothing written{f', {self.out} unchanged' if self.out else ''}"
            )

        written, previous = self._write(result, views, verification, assessment, report.intrinsics)
        return WizardOutcome(
            result=result,
            views=tuple(views),
            verification=verification,
            assessment=assessment,
            intrinsics=report.intrinsics,
            written=written,
            previous=previous,
        )

    # ------------------------------------------------------------------ stages
    def plan_and_confirm(self, intrinsics: CameraIntrinsics) -> CalibrationPlan:
        """The checked plan (:func:`calibration.views.make_plan`), with warnings about views likely to be skipped,
        once the operator has agreed to the motion it needs; :class:`WizardCancelled` otherwise."""
        p = self.params
        plan = make_plan(p, intrinsics, X_base_tool=self.plan_poses)
        self._warn_about_visibility(plan, intrinsics)
        recommended = DegeneracyLimits().recommended_views
        if plan.n_views < recommended:
            self.ui.warn(f"{plan.n_views} views to solve from; {recommended} or more give a more reliable result")
        self.ui.plan_ready(plan, p)
        if self.manual:
            question = f"Jog the robot to {plan.n_views} views and one held-out view, capturing at each?"
        else:
            question = (
                f"Move the robot in straight lines through {plan.n_views} views and one held-out view at "
                f"{p.speed_m_s:g} m/s (start above the board, clear of fixtures)?"
            )
        if not self.ui.confirm(question):
            raise WizardCancelled("calibration cancelled by the operator before any motion; nothing written")
        return plan

    def _usable(self, views: Sequence[ViewRecord]) -> list[ViewRecord]:
        """The usable views; CalibrationError listing why the others were skipped when fewer than ``min_views``."""
        p = self.params
        used = [v for v in views if v.usable]
        if len(used) < p.min_views:
            by_reason: dict[str, list[int]] = {}
            for v in views:
                if not v.usable:
                    by_reason.setdefault(v.skipped, []).append(v.index + 1)
            skipped = "; ".join(
                f"view{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))}: {reason}"
                for reason, ids in by_reason.items()
            )
            raise CalibrationError(
                f"only {len(used)} of {len(views)} views are usable, at least {p.min_views} are needed "
                f"({skipped}); check that the board lies where the nominal pose says, fully in view and lit"
            )
        return used

    def _write(
        self,
        result: HandEyeResult,
        views: Sequence[ViewRecord],
        verification: Verification,
        assessment: Assessment,
        intrinsics: CameraIntrinsics,
    ) -> tuple[Path | None, Path | None]:
        """(file written, previous file kept) once the operator agrees; (None, None) without ``out``."""
        if self.out is None:
            return None, None
        self.ui.stage("Writing the result")
        keep = f" (the current one is kept as {self.out}{PREVIOUS_SUFFIX})" if self.out.exists() else ""
        if not self.ui.confirm(f"Write the result to {self.out}{keep}?"):
            raise WizardCancelled(f"calibration result not written (declined by the operator); {self.out} unchanged")
        document = result_document(
            result,
            views=views,
            verification=verification,
            assessment=assessment,
            intrinsics=intrinsics,
            board=self.params.board,
            source=self.source,
        )
        previous = write_result_file(self.out, document)
        logger.info("calibration: wrote %s (previous kept: %s)", self.out, previous)
        return self.out, previous

    def check_devices(self) -> DeviceReport:
        """Connect robot, track and camera (in that order: a fake camera reads the other two) and check them."""
        self.robot.connect()
        self._robot_connected = True
        if self.track is not None:
            self.track.connect()
        self.camera.connect()
        state = self.robot.state()
        if not state.healthy:
            raise DriverError(
                f"{self.robot.name}: not ready to calibrate: mode {state.mode.value}"
                f"{f' ({state.message})' if state.message else ''}; clear it and start again"
            )
        if state.is_moving:
            raise DriverError(f"{self.robot.name}: the robot is moving; wait until it stands still and start again")
        track_status = None
        if self.track is not None:
            track_status = self.track.status()
            if track_status.fault or track_status.moving:
                what = f"faulted (code {track_status.fault_code})" if track_status.fault else "moving"
                raise DriverError(
                    f"{self.track.name}: {what} at {track_status.position_m:.4f} m; the track must stand still "
                    "and healthy while calibrating"
                )
        capture = self.camera.capture(timeout_s=self.params.capture_timeout_s)
        return DeviceReport(robot=state, track=track_status, intrinsics=capture.intrinsics)

    def collect_views(self, plan: CalibrationPlan, intrinsics: CameraIntrinsics) -> list[ViewRecord]:
        """Move (or have the operator jog) to every planned pose and capture; the held-out pose is not visited."""
        views: list[ViewRecord] = []
        total = plan.n_views
        for i, X_target in enumerate(plan.X_base_tool):
            if self.manual:
                answer = self.ui.ask_operator(
                    f"Jog the robot to view {i + 1}/{total} (a new position and orientation, board in view), "
                    "then press Enter; q + Enter stops collecting",
                    X_target,
                )
                if answer.strip().lower() in ("q", "quit", "done"):
                    self.ui.info(f"stopped collecting after {len(views)} views at the operator's request")
                    break
            else:
                self.ui.view_started(i, total, "moving")
                self._move(X_target, what=f"to view {i + 1}")
            self.ui.view_started(i, total, "capturing")
            record = self.capture_view(i, intrinsics, earlier=views)
            views.append(record)
            self.ui.view_done(record, total)
        return views

    def capture_view(
        self, index: int, intrinsics: CameraIntrinsics, *, earlier: Sequence[ViewRecord] = ()
    ) -> ViewRecord:
        """Settle, read the tool pose, capture, read the pose again, and detect the board."""
        p = self.params
        if p.settle_s > 0:
            time.sleep(p.settle_s)
        state = self.robot.state()
        X_before = state.X_base_tool
        if not state.healthy:
            raise DriverError(f"{self.robot.name}: mode {state.mode.value} at view {index + 1}: {state.message}")
        capture = self.camera.capture(timeout_s=p.capture_timeout_s)
        X_after = self.robot.get_X_base_tool()
        if capture.intrinsics != intrinsics:
            raise CalibrationError(
                f"view {index + 1}: the camera's intrinsics changed during the calibration "
                f"({capture.intrinsics} instead of {intrinsics}); keep its resolution fixed"
            )
        moved_m = float(np.linalg.norm(X_after[:3, 3] - X_before[:3, 3]))
        turned_rad = rotation_angle_rad(X_after, X_before)
        if moved_m > p.still_tol_m or turned_rad > p.still_tol_rad:
            reason = (
                f"the tool moved {moved_m * 1000:.2f} mm / {np.degrees(turned_rad):.3f} deg during the capture; "
                "let it stand still"
            )
            return ViewRecord(index, X_before, None, reason)
        for other in earlier:
            if (
                float(np.linalg.norm(other.X_base_tool[:3, 3] - X_before[:3, 3])) < p.duplicate_tol_m
                and rotation_angle_rad(other.X_base_tool, X_before) < p.duplicate_tol_rad
            ):
                return ViewRecord(
                    index, X_before, None, f"same pose as view {other.index + 1}; move and rotate the tool"
                )
        gray = cv2.cvtColor(np.asarray(capture.color_rgb), cv2.COLOR_RGB2GRAY)
        try:
            observation = detect_board(gray, board=p.board, K=intrinsics.K, min_corners=p.min_corners)
        except CalibrationError as err:
            return ViewRecord(index, X_before, None, str(err))
        if observation.rms_px > p.max_view_fit_px:
            reason = (
                f"the board pose fits its {observation.n_corners} corners to {observation.rms_px:.2f} px RMS "
                f"(> {p.max_view_fit_px:g} px): blurred, moving or mis-detected"
            )
            return ViewRecord(index, X_before, observation, reason)
        return ViewRecord(index, X_before, observation)

    def verify_holdout(
        self, plan: CalibrationPlan, result: HandEyeResult, intrinsics: CameraIntrinsics, views: Sequence[ViewRecord]
    ) -> Verification:
        """Go to the held-out pose (manual: have the operator jog to a new one, unlike the earlier ``views``),
        capture, and compare."""
        index = len(views)
        if self.manual:
            answer = self.ui.ask_operator(
                "Jog the robot to one more pose, unlike the earlier ones, board in view, and press Enter "
                "(this view checks the result)",
                plan.X_base_tool_holdout,
            )
            if answer.strip().lower() in ("q", "quit", "done"):
                raise WizardCancelled("calibration stopped before the verification view; nothing written")
        else:
            self.ui.view_started(index, index, "moving to the held-out pose")
            self._move(plan.X_base_tool_holdout, what="to the held-out pose")
        self.ui.view_started(index, index, "capturing the held-out view")
        record = self.capture_view(index, intrinsics, earlier=views if self.manual else ())
        if not record.usable or record.observation is None:
            raise CalibrationError(f"verification impossible: the held-out view is unusable: {record.skipped}")
        return verify(record.observation, record.X_base_tool, result, intrinsics)

    # ------------------------------------------------------------------ helpers
    def _move(self, X_base_tool: FloatArray, *, what: str) -> None:
        p = self.params
        logger.debug(
            "calibration: move %s at %s m, %.3f m/s, %.3f m/s^2",
            what,
            np.round(X_base_tool[:3, 3], 4),
            p.speed_m_s,
            p.accel_m_s2,
        )
        self.robot.move_linear(X_base_tool, speed_m_s=p.speed_m_s, accel_m_s2=p.accel_m_s2, timeout_s=p.move_timeout_s)

    def _warn_about_visibility(self, plan: CalibrationPlan, intrinsics: CameraIntrinsics) -> None:
        for i in range(plan.n_views + 1):
            n = visible_corner_count(plan.X_camera_board_nominal[i], self.params.board, intrinsics)
            if n < self.params.min_corners:
                label = f"view {i + 1}" if i < plan.n_views else "the held-out view"
                self.ui.warn(
                    f"{label}: under the nominal poses only {n} board corners fall in the image "
                    f"(at least {self.params.min_corners} are needed); it will probably be skipped"
                )

    def _stop_robot(self, err: BaseException) -> None:
        if not self._robot_connected:
            return
        why = "interrupted" if isinstance(err, KeyboardInterrupt) else type(err).__name__
        logger.info("calibration: %s; stopping the robot", why)
        try:
            self.robot.stop()
        except Exception as stop_err:  # the original error matters more; a robot we cannot reach cannot move
            logger.warning("calibration: robot.stop() after %s failed: %s", why, stop_err)
