"""calibration.views: the wizard's parameters, the plan's predicted views and its checks, on exact geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.board import CharucoBoardSpec
from calibration.errors import CalibrationError
from calibration.handeye import HandEyeMode
from calibration.planner import PlanParams, Workspace
from calibration.views import CalibrationPlan, WizardParams, make_plan, visible_corner_count
from perception.capture import CameraIntrinsics
from perception.transforms import invert_X, make_X

BOARD = CharucoBoardSpec()  # 7 x 5 squares of 30 mm: 24 inner corners, 0.21 x 0.15 m
K = CameraIntrinsics(width=1280, height=720, fx=900.0, fy=900.0, cx=640.0, cy=360.0)
X_TOOL_CAMERA = make_X(np.eye(3), [0.0, 0.0, 0.1])
DOWN = Rotation.from_euler("x", 180, degrees=True).as_matrix()  # z pointing down
X_BASE_BOARD = make_X(DOWN, [0.5, 0.0, 0.0])  # on the table, printed face (board -z) up; it spans y in [-0.15, 0]


def params(**kwargs) -> WizardParams:
    base = {
        "board": BOARD,
        "workspace": Workspace(reach_center_base=(0.0, 0.0, 0.0), reach_radius_m=1.0),
        "X_base_board": X_BASE_BOARD,
        "X_tool_camera": X_TOOL_CAMERA,
        "plan": PlanParams(n_poses=6),
        "min_views": 3,
    }
    return WizardParams(**{**base, **kwargs})


def tool_above_board(dx: float, dy: float, height_m: float, tilt_rad: float = 0.0, about: str = "x") -> np.ndarray:
    """A tool pose whose camera looks down at the board centre from ``height_m`` above it, shifted (dx, dy)."""
    w, h = BOARD.size_m
    R = Rotation.from_euler(about, tilt_rad).as_matrix() @ DOWN
    X_base_camera = make_X(R, [0.5 + w / 2 + dx, -h / 2 + dy, height_m])
    return X_base_camera @ invert_X(X_TOOL_CAMERA)


def test_the_plan_predicts_each_view_through_the_nominal_transforms() -> None:
    poses = [tool_above_board(0.01 * k, 0.0, 0.4, math.radians(5 * k), "xy"[k % 2]) for k in range(4)]
    plan = make_plan(params(), K, X_base_tool=poses)
    assert plan.n_views == 3 and np.array_equal(plan.X_base_tool_holdout, poses[-1])
    for X, X_cb in zip(poses, plan.X_camera_board_nominal, strict=True):
        np.testing.assert_allclose(X @ X_TOOL_CAMERA @ X_cb, X_BASE_BOARD, atol=1e-14)
    # the first view: straight down from 0.4 m above the board centre
    distance, tilt_deg = plan.view_geometry(0)
    w, h = BOARD.size_m
    assert distance == pytest.approx(math.sqrt(0.4**2 + (w / 2) ** 2 + (h / 2) ** 2), abs=1e-12)
    assert tilt_deg == pytest.approx(0.0, abs=1e-9)
    assert plan.view_geometry(2)[1] == pytest.approx(10.0, abs=1e-9)


def test_visible_corners_count_what_falls_in_the_image_and_faces_the_camera() -> None:
    X_cb = invert_X(tool_above_board(0.0, 0.0, 0.4) @ X_TOOL_CAMERA) @ X_BASE_BOARD
    assert visible_corner_count(X_cb, BOARD, K) == BOARD.n_corners == 24
    flipped = X_cb @ make_X(Rotation.from_euler("x", 180, degrees=True).as_matrix(), np.zeros(3))
    assert visible_corner_count(flipped, BOARD, K) == 0  # the camera sees the back of the board
    aside = X_cb.copy()
    aside[0, 3] += 1.0  # 1 m to the side at 0.4 m: out of the image
    assert visible_corner_count(aside, BOARD, K) == 0


def test_a_plan_is_refused_before_anything_moves() -> None:
    with pytest.raises(CalibrationError, match=r"plan pose 3 puts the tool at \[2\.0, 0\.0, 0\.5\] m, outside"):
        poses = [tool_above_board(0.0, 0.0, 0.4, math.radians(20 * k), "xy"[k % 2]) for k in range(4)]
        poses[2] = make_X(DOWN, [2.0, 0.0, 0.5])
        make_plan(params(), K, X_base_tool=poses)
    with pytest.raises(
        CalibrationError, match=r"the plan has 2 poses to solve from \(plus the held-out one\); at least 3"
    ):
        make_plan(params(), K, X_base_tool=[tool_above_board(0.0, 0.01 * k, 0.4) for k in range(3)])
    pure_translations = [tool_above_board(0.05 * k, 0.0, 0.4) for k in range(5)]
    with pytest.raises(CalibrationError, match="plan refused before any motion: pure translations"):
        make_plan(params(), K, X_base_tool=pure_translations)


def test_wizard_params_need_the_nominal_transforms_of_their_mode() -> None:
    with pytest.raises(CalibrationError, match="eye_to_hand calibration needs the nominal X_base_camera"):
        params(mode=HandEyeMode.EYE_TO_HAND)
    with pytest.raises(CalibrationError, match=r"need 3 <= min_views <= poses, got min_views 7 and 6 poses"):
        params(min_views=7)
    with pytest.raises(CalibrationError, match="min_corners must be >= 4"):
        params(min_corners=3)
    p = params()
    np.testing.assert_array_equal(p.X_hand_eye_nominal, X_TOOL_CAMERA)
    np.testing.assert_array_equal(p.X_board_nominal, X_BASE_BOARD)
    assert isinstance(make_plan(p, K, X_base_tool=_spread()), CalibrationPlan)


def _spread() -> list[np.ndarray]:
    return [tool_above_board(0.01 * k, -0.01 * k, 0.4, math.radians(12 * (k + 1)), "xy"[k % 2]) for k in range(5)]
