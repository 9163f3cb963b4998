"""The views of a calibration run: the wizard's parameters, the plan (where the views are taken, checked before
anything moves) and the record of each captured view."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board import BoardObservation, CharucoBoardSpec
from calibration.errors import CalibrationError
from calibration.handeye import DegeneracyLimits, HandEyeMode, check_motion
from calibration.planner import PlanParams, Workspace, plan_eye_in_hand, plan_eye_to_hand
from calibration.verdict import VerdictThresholds, predict_X_camera_board
from perception.capture import CameraIntrinsics
from perception.transforms import check_X, invert_X

FloatArray = NDArray[np.float64]


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
    limits = wizard_limits(params)
    try:
        check_motion(H, plan.X_camera_board_nominal[: plan.n_views], limits=limits, mode=params.mode)
    except CalibrationError as err:
        raise CalibrationError(f"plan refused before any motion: {err}") from err


def wizard_limits(params: WizardParams) -> DegeneracyLimits:
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
