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

import json
import logging
import os
import re
import shutil
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board import BoardObservation, CharucoBoardSpec, detect_board
from calibration.errors import CalibrationError
from calibration.handeye import (
    DegeneracyLimits,
    HandEyeMode,
    HandEyeResult,
    check_motion,
    solve_hand_eye_from_observations,
)
from calibration.planner import PlanParams, Workspace, plan_eye_in_hand, plan_eye_to_hand
from drivers.errors import DriverError
from drivers.protocols import Camera, Robot, RobotState, Track, TrackStatus
from perception.capture import CameraIntrinsics
from perception.transforms import check_X, invert_X, rotation_angle_rad

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

RESULT_FORMAT = "weldcell-hand-eye/1"
PREVIOUS_SUFFIX = ".prev"


class WizardCancelled(CalibrationError):
    """The operator declined a confirmation; nothing was written (and nothing moved after the refusal)."""


# ================================================================================================ parameters
@dataclass(frozen=True)
class VerdictThresholds:
    """Limits of the verdict; each quantity is compared with its ``pass_*`` and ``fail_*`` limit.

    ``rms_px``: RMS reprojection error of all corners of all views with the robot poses as reported, pixels.
    ``worst_view_px``: the largest per-view RMS, pixels. ``rms_mm`` / ``rms_deg``: RMS over views of the
    distance / angle between the board pose the camera measured and the one the solution predicts.
    ``holdout_rms_px``: RMS distance between the corners seen at the held-out pose and where the solution
    predicts them, pixels. Verdict: ``fail`` when any quantity exceeds its ``fail_*`` limit, ``marginal`` when
    any exceeds its ``pass_*`` limit, else ``pass``. The pixel limits assume ~0.4-0.8 mm per pixel at the board
    (a 640-1280 px wide image 0.3-0.4 m away); see docs/calibration.md for the reasoning.
    """

    pass_rms_px: float = 1.0
    fail_rms_px: float = 2.0
    pass_worst_view_px: float = 2.0
    fail_worst_view_px: float = 4.0
    pass_rms_mm: float = 1.0
    fail_rms_mm: float = 3.0
    pass_rms_deg: float = 0.3
    fail_rms_deg: float = 1.0
    pass_holdout_rms_px: float = 1.5
    fail_holdout_rms_px: float = 3.0

    def __post_init__(self) -> None:
        for name in ("rms_px", "worst_view_px", "rms_mm", "rms_deg", "holdout_rms_px"):
            ok, bad = getattr(self, f"pass_{name}"), getattr(self, f"fail_{name}")
            if not 0.0 < ok <= bad:
                raise CalibrationError(f"verdict thresholds: need 0 < pass_{name} <= fail_{name}, got {ok}, {bad}")


@dataclass(frozen=True)
class WizardParams:
    """What the wizard needs to know about the cell (metres, seconds, m/s).

    ``board``: the printed board. ``workspace``: where the tool origin may go. Nominal (CAD) transforms the plan
    aims with (a few mm and degrees off is fine): eye-in-hand ``X_base_board`` and ``X_tool_camera``;
    eye-to-hand ``X_base_camera`` and ``X_tool_board``; each (4, 4). ``plan``: view spread and count
    (``plan.n_poses`` views to solve from; one more is taken for the verification). ``speed_m_s`` /
    ``accel_m_s2`` / ``move_timeout_s``: each move between views. ``settle_s``: wait after a move before the
    capture. ``min_corners``: fewer corners skip a view. ``max_view_fit_px``: a view whose board pose leaves a
    larger RMS corner residual (a blurred or mis-detected board) is skipped. ``min_views``: fewer usable views
    stop the calibration. ``still_tol_m`` / ``still_tol_rad``: how much the tool may move during a capture.
    ``duplicate_tol_m`` / ``duplicate_tol_rad``: a manual view closer than this to an earlier one is skipped.
    """

    board: CharucoBoardSpec
    workspace: Workspace
    mode: HandEyeMode = HandEyeMode.EYE_IN_HAND
    X_base_board: FloatArray | None = None
    X_tool_camera: FloatArray | None = None
    X_base_camera: FloatArray | None = None
    X_tool_board: FloatArray | None = None
    plan: PlanParams = field(default_factory=lambda: PlanParams(n_poses=12))
    seed: int = 0
    speed_m_s: float = 0.1
    accel_m_s2: float = 0.5
    move_timeout_s: float = 60.0
    capture_timeout_s: float = 5.0
    settle_s: float = 0.2
    min_corners: int = 12
    max_view_fit_px: float = 1.0
    min_views: int = 6
    still_tol_m: float = 1e-4
    still_tol_rad: float = float(np.radians(0.02))
    duplicate_tol_m: float = 0.005
    duplicate_tol_rad: float = float(np.radians(2.0))
    thresholds: VerdictThresholds = field(default_factory=VerdictThresholds)

    def __post_init__(self) -> None:
        mode = HandEyeMode(self.mode)
        object.__setattr__(self, "mode", mode)
        needed = (
            ("X_base_board", "X_tool_camera") if mode is HandEyeMode.EYE_IN_HAND else ("X_base_camera", "X_tool_board")
        )
        for name in ("X_base_board", "X_tool_camera", "X_base_camera", "X_tool_board"):
            value = getattr(self, name)
            if name in needed and value is None:
                raise CalibrationError(f"{mode.value} calibration needs the nominal {name}")
            if value is not None:
                object.__setattr__(self, name, check_X(value, name=f"nominal {name}"))
        if not 3 <= self.min_views <= self.plan.n_poses:
            raise CalibrationError(
                f"need 3 <= min_views <= poses, got min_views {self.min_views} and {self.plan.n_poses} poses"
            )
        positive = ("speed_m_s", "accel_m_s2", "move_timeout_s", "capture_timeout_s", "max_view_fit_px")
        for name in positive:
            if not getattr(self, name) > 0:
                raise CalibrationError(f"{name} must be positive, got {getattr(self, name)}")
        if self.settle_s < 0:
            raise CalibrationError(f"settle_s must be >= 0, got {self.settle_s}")
        if self.min_corners < 4:
            raise CalibrationError(f"min_corners must be >= 4 (a board pose needs 4), got {self.min_corners}")

    @property
    def X_hand_eye_nominal(self) -> FloatArray:
        """The nominal transform being calibrated: ``X_tool_camera`` or ``X_base_camera``."""
        X = self.X_tool_camera if self.mode is HandEyeMode.EYE_IN_HAND else self.X_base_camera
        assert X is not None
        return X

    @property
    def X_board_nominal(self) -> FloatArray:
        """The nominal board pose: ``X_base_board`` or ``X_tool_board``."""
        X = self.X_base_board if self.mode is HandEyeMode.EYE_IN_HAND else self.X_tool_board
        assert X is not None
        return X


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
class CalibrationPlan:
    """Where the views are taken. ``X_base_tool``: N (4, 4) tool poses to solve from; ``X_base_tool_holdout``:
    (4, 4) the verification pose. ``X_camera_board_nominal``: (N + 1, 4, 4) the board pose each view should
    show, under the nominal transforms (the held-out one last). Metres."""

    X_base_tool: tuple[FloatArray, ...]
    X_base_tool_holdout: FloatArray
    X_camera_board_nominal: FloatArray

    @property
    def n_views(self) -> int:
        return len(self.X_base_tool)

    def view_geometry(self, i: int) -> tuple[float, float]:
        """(distance camera-board origin in metres, tilt of the optical axis from the board normal in degrees)
        of view ``i`` (``n_views`` = the held-out view), under the nominal transforms."""
        X = self.X_camera_board_nominal[i]
        normal_camera = X[:3, 2]
        tilt = float(np.degrees(np.arccos(np.clip(abs(normal_camera[2]), 0.0, 1.0))))
        return float(np.linalg.norm(X[:3, 3])), tilt


@dataclass(frozen=True)
class ViewRecord:
    """One captured view. ``index``: 0-based position in the run. ``X_base_tool``: (4, 4) tool pose the robot
    reported at the capture, metres. ``observation``: the detected board (None when none was found).
    ``skipped``: why the view is not used ("" when it is)."""

    index: int
    X_base_tool: FloatArray
    observation: BoardObservation | None
    skipped: str = ""

    @property
    def usable(self) -> bool:
        return self.observation is not None and not self.skipped


@dataclass(frozen=True)
class Verification:
    """The solution checked at a pose it was not solved from.

    ``X_base_tool``: (4, 4) the held-out pose. ``n_corners``: corners seen there. ``rms_px`` / ``max_px``:
    RMS and largest distance between the seen corners and where the solved transforms put them, pixels.
    ``translation_mm`` / ``rotation_deg``: the board pose measured there (PnP) against the predicted one.
    """

    X_base_tool: FloatArray
    n_corners: int
    rms_px: float
    max_px: float
    translation_mm: float
    rotation_deg: float


class Verdict(StrEnum):
    PASS = "pass"
    MARGINAL = "marginal"
    FAIL = "fail"


@dataclass(frozen=True)
class Assessment:
    """The verdict and, for each quantity over its ``pass_*`` limit, one line saying which and by how much."""

    verdict: Verdict
    reasons: tuple[str, ...]


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


# ================================================================================================ pure steps
def predict_X_camera_board(
    X_base_tool: ArrayLike, *, mode: HandEyeMode, X_hand_eye: ArrayLike, X_board: ArrayLike
) -> FloatArray:
    """(4, 4) board pose in the camera at tool pose ``X_base_tool`` (4, 4).

    Eye-in-hand: ``X_hand_eye = X_tool_camera``, ``X_board = X_base_board``,
    ``X_camera_board = inv(X_tool_camera) @ inv(X_base_tool) @ X_base_board``.
    Eye-to-hand: ``X_hand_eye = X_base_camera``, ``X_board = X_tool_board``,
    ``X_camera_board = inv(X_base_camera) @ X_base_tool @ X_tool_board``.
    """
    T = np.asarray(X_base_tool, dtype=np.float64)
    if HandEyeMode(mode) is HandEyeMode.EYE_IN_HAND:
        return invert_X(X_hand_eye) @ invert_X(T) @ np.asarray(X_board, dtype=np.float64)
    return invert_X(X_hand_eye) @ T @ np.asarray(X_board, dtype=np.float64)


def make_plan(
    params: WizardParams,
    intrinsics: CameraIntrinsics,
    *,
    X_base_tool: Sequence[ArrayLike] | None = None,
) -> CalibrationPlan:
    """The views of a run: ``params.plan.n_poses`` planned around the nominal board plus a held-out one (the
    middle of the azimuth-ordered plan, so it lies among the others), or the given ``X_base_tool`` poses ((4, 4)
    each, metres; the last is the held-out one). Checked with :func:`check_plan` before it is returned."""
    if X_base_tool is None:
        n_total = params.plan.n_poses + 1
        plan_params = replace(params.plan, n_poses=n_total)
        common: dict[str, Any] = {
            "workspace": params.workspace,
            "params": plan_params,
            "seed": params.seed,
            "K": intrinsics.K,
            "image_size": (intrinsics.width, intrinsics.height),
        }
        if params.mode is HandEyeMode.EYE_IN_HAND:
            poses = plan_eye_in_hand(
                params.board, X_base_board=params.X_board_nominal, X_tool_camera=params.X_hand_eye_nominal, **common
            )
        else:
            poses = plan_eye_to_hand(
                params.board, X_base_camera=params.X_hand_eye_nominal, X_tool_board=params.X_board_nominal, **common
            )
        holdout = poses.pop(n_total // 2)
    else:
        given = [check_X(X, name=f"plan pose {i + 1}") for i, X in enumerate(X_base_tool)]
        if len(given) < 2:
            raise CalibrationError(f"a plan needs at least {params.min_views + 1} poses, got {len(given)}")
        poses, holdout = given[:-1], given[-1]
    predicted = np.stack(
        [
            predict_X_camera_board(
                X, mode=params.mode, X_hand_eye=params.X_hand_eye_nominal, X_board=params.X_board_nominal
            )
            for X in [*poses, holdout]
        ]
    )
    plan = CalibrationPlan(X_base_tool=tuple(poses), X_base_tool_holdout=holdout, X_camera_board_nominal=predicted)
    check_plan(plan, params)
    return plan


def check_plan(plan: CalibrationPlan, params: WizardParams) -> None:
    """Raise CalibrationError, before anything moves, when the plan cannot calibrate: fewer than
    ``min_views`` poses, a tool position outside the workspace, or degenerate motion (pure translations,
    rotations all about one axis, too small rotations; :func:`calibration.handeye.check_motion` on the board
    poses the nominal transforms predict)."""
    if plan.n_views < params.min_views:
        raise CalibrationError(
            f"the plan has {plan.n_views} poses to solve from (plus the held-out one); at least {params.min_views} "
            "are needed"
        )
    all_poses = [*plan.X_base_tool, plan.X_base_tool_holdout]
    inside = params.workspace.contains(np.stack([X[:3, 3] for X in all_poses]))
    if not np.all(inside):
        i = int(np.flatnonzero(~inside)[0])
        label = f"pose {i + 1}" if i < plan.n_views else "the held-out pose"
        where = np.round(all_poses[i][:3, 3], 3).tolist()
        raise CalibrationError(
            f"plan {label} puts the tool at {where} m, outside the calibration workspace; nothing was moved"
        )
    T = np.stack(plan.X_base_tool)
    H = T if params.mode is HandEyeMode.EYE_IN_HAND else np.stack([invert_X(X) for X in T])
    limits = _limits(params)
    try:
        check_motion(H, plan.X_camera_board_nominal[: plan.n_views], limits=limits, mode=params.mode)
    except CalibrationError as err:
        raise CalibrationError(f"plan refused before any motion: {err}") from err


def _limits(params: WizardParams) -> DegeneracyLimits:
    # The wizard tells the operator about a small view count itself (the solver would log it on every call).
    return DegeneracyLimits(min_views=params.min_views, recommended_views=params.min_views)


def visible_corner_count(X_camera_board: ArrayLike, board: CharucoBoardSpec, intrinsics: CameraIntrinsics) -> int:
    """How many of ``board``'s corners fall inside the image at board pose ``X_camera_board`` (4, 4) (in front
    of the camera, printed face towards it)."""
    X = np.asarray(X_camera_board, dtype=np.float64)
    if float(np.dot(X[:3, 2], X[:3, 3])) <= 0.0:  # the camera looks at the back of the board
        return 0
    p_camera = board.corners_board @ X[:3, :3].T + X[:3, 3]
    front = p_camera[:, 2] > 1e-3
    uv = intrinsics.project(p_camera[front])
    inside = (
        (uv[:, 0] >= 0) & (uv[:, 0] <= intrinsics.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= intrinsics.height - 1)
    )
    return int(np.count_nonzero(inside))


def verify(
    observation: BoardObservation,
    X_base_tool: ArrayLike,
    result: HandEyeResult,
    intrinsics: CameraIntrinsics,
) -> Verification:
    """Compare the corners of ``observation`` (seen at tool pose ``X_base_tool``, (4, 4)) with where ``result``
    puts them: the board pose its transforms predict, projected with ``intrinsics``."""
    X_hand_eye, X_board = solved_transforms(result)
    X_cb = predict_X_camera_board(X_base_tool, mode=result.mode, X_hand_eye=X_hand_eye, X_board=X_board)
    p_camera = observation.corners_board @ X_cb[:3, :3].T + X_cb[:3, 3]
    if np.any(p_camera[:, 2] <= 0):
        raise CalibrationError("verification: the solution puts the board behind the camera at the held-out pose")
    err = np.linalg.norm(intrinsics.project(p_camera) - observation.corners_px, axis=1)
    seen = observation.X_camera_board
    return Verification(
        X_base_tool=np.asarray(X_base_tool, dtype=np.float64),
        n_corners=observation.n_corners,
        rms_px=float(np.sqrt(np.mean(err**2))),
        max_px=float(np.max(err)),
        translation_mm=float(np.linalg.norm(seen[:3, 3] - X_cb[:3, 3])) * 1000.0,
        rotation_deg=float(np.degrees(rotation_angle_rad(seen, X_cb))),
    )


def solved_transforms(result: HandEyeResult) -> tuple[FloatArray, FloatArray]:
    """(hand-eye transform, board pose) of ``result``: (X_tool_camera, X_base_board) for eye-in-hand,
    (X_base_camera, X_tool_board) for eye-to-hand."""
    if result.mode is HandEyeMode.EYE_IN_HAND:
        X, Y = result.X_tool_camera, result.X_base_board
    else:
        X, Y = result.X_base_camera, result.X_tool_board
    assert X is not None and Y is not None
    return X, Y


def assess(result: HandEyeResult, verification: Verification, thresholds: VerdictThresholds) -> Assessment:
    """The verdict of a solution and its verification (see :class:`VerdictThresholds`)."""
    assert result.view_residuals_px is not None and result.rms_px is not None
    quantities = (
        ("RMS reprojection", result.rms_px, "px", "rms_px"),
        ("worst view", float(np.max(result.view_residuals_px)), "px", "worst_view_px"),
        ("RMS board position", result.rms_mm, "mm", "rms_mm"),
        ("RMS board orientation", result.rms_deg, "deg", "rms_deg"),
        ("held-out view", verification.rms_px, "px", "holdout_rms_px"),
    )
    verdict = Verdict.PASS
    reasons = []
    for label, value, unit, key in quantities:
        ok, bad = getattr(thresholds, f"pass_{key}"), getattr(thresholds, f"fail_{key}")
        if value > bad:
            verdict = Verdict.FAIL
            reasons.append(f"{label} {value:.3g} {unit} > {bad:g} {unit} (fail)")
        elif value > ok:
            verdict = Verdict.MARGINAL if verdict is Verdict.PASS else verdict
            reasons.append(f"{label} {value:.3g} {unit} > {ok:g} {unit} (pass limit)")
    return Assessment(verdict=verdict, reasons=tuple(reasons))


def result_document(
    result: HandEyeResult,
    *,
    views: Sequence[ViewRecord],
    verification: Verification,
    assessment: Assessment,
    intrinsics: CameraIntrinsics,
    board: CharucoBoardSpec,
    date: datetime | None = None,
    source: str = "",
) -> dict[str, Any]:
    """The JSON object of a result file (see docs/calibration.md): the solved transforms (metres), the method,
    the date, the residuals (px, mm, deg), the verification, the verdict, the board, the intrinsics and every
    view (its robot pose, its measured board pose, or why it was skipped)."""
    X_hand_eye, X_board = solved_transforms(result)
    names = (
        ("X_tool_camera", "X_base_board")
        if result.mode is HandEyeMode.EYE_IN_HAND
        else ("X_base_camera", "X_tool_board")
    )
    used = [v for v in views if v.usable]
    assert result.view_residuals_px is not None and result.rms_px is not None
    per_view = [
        {"view": v.index + 1, "px": round(float(px), 4), "mm": round(float(mm), 4), "deg": round(float(deg), 5)}
        for v, px, mm, deg in zip(
            used, result.view_residuals_px, result.view_residuals_mm, result.view_residuals_deg, strict=True
        )
    ]
    view_list: list[dict[str, Any]] = []
    for v in views:
        entry: dict[str, Any] = {"view": v.index + 1, "X_base_tool": _matrix(v.X_base_tool)}
        if v.observation is not None:
            entry["X_camera_board"] = _matrix(v.observation.X_camera_board)
            entry["corners"] = v.observation.n_corners
            entry["fit_rms_px"] = round(v.observation.rms_px, 4)
        if v.skipped:
            entry["skipped"] = v.skipped
        view_list.append(entry)
    when = date or datetime.now(UTC)
    return {
        "format": RESULT_FORMAT,
        names[0]: _matrix(X_hand_eye),
        names[1]: _matrix(X_board),
        "mode": result.mode.value,
        "method": result.method,
        "start_method": result.start_method,
        "date": when.isoformat(timespec="seconds"),
        "n_views": result.n_views,
        "n_views_skipped": len(views) - len(used),
        "verdict": assessment.verdict.value,
        "verdict_reasons": list(assessment.reasons),
        "residuals": {
            "rms_px": round(result.rms_px, 4),
            "rms_mm": round(result.rms_mm, 4),
            "rms_deg": round(result.rms_deg, 5),
            "per_view": per_view,
        },
        "verification": {
            "X_base_tool": _matrix(verification.X_base_tool),
            "corners": verification.n_corners,
            "rms_px": round(verification.rms_px, 4),
            "max_px": round(verification.max_px, 4),
            "translation_mm": round(verification.translation_mm, 4),
            "rotation_deg": round(verification.rotation_deg, 5),
        },
        "board": {
            "squares_x": board.squares_x,
            "squares_y": board.squares_y,
            "square_length_m": board.square_length_m,
            "marker_length_m": board.marker_length_m,
            "dictionary": board.dictionary,
            "legacy_pattern": board.legacy_pattern,
        },
        "intrinsics": intrinsics.to_json(),
        "source": source,
        "views": view_list,
    }


def _matrix(X: ArrayLike) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(X, dtype=np.float64)]


def write_result_file(path: str | os.PathLike[str], document: dict[str, Any]) -> Path | None:
    """Write ``document`` as JSON to ``path`` atomically, keeping an existing file as ``path + ".prev"``.

    The new content goes to a temporary file in the same folder (flushed to disk) first; then the current file
    is copied to a temporary file and renamed onto ``.prev``; then the new file is renamed onto ``path``. Each
    rename is atomic, so ``path`` always holds a complete file, old or new, whatever interrupts this. Returns the
    ``.prev`` path when there was a previous file, else None.
    """
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = _json_text(document)
    new_tmp = _temp_beside(out)
    previous: Path | None = None
    try:
        with open(new_tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        if out.exists():
            previous = out.with_name(out.name + PREVIOUS_SUFFIX)
            prev_tmp = _temp_beside(previous)
            try:
                shutil.copy2(out, prev_tmp)
                os.replace(prev_tmp, previous)
            except BaseException:
                prev_tmp.unlink(missing_ok=True)
                raise
        os.replace(new_tmp, out)
    except BaseException:
        new_tmp.unlink(missing_ok=True)
        raise
    return previous


def _json_text(document: dict[str, Any]) -> str:
    """Indented JSON with every innermost list of numbers on one line (a 4x4 matrix reads as 4 rows)."""
    text = json.dumps(document, indent=1, allow_nan=False)
    text = _INNER_LIST.sub(lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",")) + "]", text)
    return text + "\n"


# An innermost list as json.dumps(indent=...) lays it out: "[", newline, numbers, newline, "]". A JSON string
# never holds a raw newline, so text inside strings is never touched.
_INNER_LIST = re.compile(r"\[\n\s*([-+0-9.eE,\s]+?)\n\s*\]")


def _temp_beside(path: Path) -> Path:
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    os.chmod(name, 0o666 & ~_umask())  # mkstemp makes 0600; the result is read by other users of the cell
    return Path(name)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
        plan = make_plan(p, report.intrinsics, X_base_tool=self.plan_poses)
        self._warn_about_visibility(plan, report.intrinsics)
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

        self.ui.stage("Collecting the views")
        views = self.collect_views(plan, report.intrinsics)
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

        self.ui.stage(f"Solving ({p.mode.value}) from {len(used)} views")
        result = solve_hand_eye_from_observations(
            [v.X_base_tool for v in used],
            [v.observation for v in used if v.observation is not None],
            K=report.intrinsics.K,
            mode=p.mode,
            limits=_limits(p),
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

        written: Path | None = None
        previous: Path | None = None
        if self.out is not None:
            self.ui.stage("Writing the result")
            keep = f" (the current one is kept as {self.out}{PREVIOUS_SUFFIX})" if self.out.exists() else ""
            if not self.ui.confirm(f"Write the result to {self.out}{keep}?"):
                raise WizardCancelled(
                    f"calibration result not written (declined by the operator); {self.out} unchanged"
                )
            document = result_document(
                result,
                views=views,
                verification=verification,
                assessment=assessment,
                intrinsics=report.intrinsics,
                board=p.board,
                source=self.source,
            )
            previous = write_result_file(self.out, document)
            written = self.out
            logger.info("calibration: wrote %s (previous kept: %s)", self.out, previous)
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
