"""cell.config_hand_eye: [hand_eye] and [hand_eye.calibration]; the file's degrees become the planner's radians."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from cell.config_hand_eye import BoardConfig, CalibrationConfig, HandEyeConfig, WorkspaceConfig

BOARD_POSE = [[1.0, 0.0, 0.0, 0.5], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


def calibration(**kwargs) -> CalibrationConfig:
    base = {
        "board": BoardConfig(squares_x=7, squares_y=5, square_length_m=0.03, marker_length_m=0.022),
        "workspace": WorkspaceConfig(reach_center_base=[0.0, 0.0, 0.0], reach_radius_m=1.0),
        "X_base_board": BOARD_POSE,
    }
    return CalibrationConfig(**{**base, **kwargs})


def test_plan_params_convert_the_degrees_of_the_file_once() -> None:
    cal = calibration(min_tilt_deg=12.0, max_tilt_deg=30.0, max_roll_deg=45.0, standoff_m=0.35)
    plan = cal.plan_params(9)
    assert plan.n_poses == 9 and plan.standoff_m == 0.35
    assert plan.min_tilt_rad == math.radians(12.0) and plan.max_tilt_rad == math.radians(30.0)
    assert plan.max_roll_rad == math.radians(45.0)
    defaults = calibration().plan_params(12)
    assert (defaults.min_tilt_rad, defaults.max_tilt_rad, defaults.max_roll_rad) == (
        math.radians(10.0), math.radians(35.0), math.radians(40.0),
    )  # fmt: skip


def test_a_plan_the_planner_would_refuse_is_a_config_error() -> None:
    with pytest.raises(ValidationError, match="need 0 <= min_tilt <= max_tilt < 80 deg, got 40 deg, 30 deg"):
        calibration(min_tilt_deg=40.0, max_tilt_deg=30.0)


def test_hand_eye_takes_a_path_or_an_inline_mount_not_both() -> None:
    assert HandEyeConfig(path="hand_eye.json").X_tool_camera is None
    inline = HandEyeConfig(X_tool_camera=np.eye(4).tolist())
    assert inline.X_tool_camera == np.eye(4).tolist()
    with pytest.raises(ValidationError, match="give exactly one of 'path' and 'X_tool_camera'"):
        HandEyeConfig()
    with pytest.raises(ValidationError, match="X_tool_camera: rotation part is a reflection"):
        HandEyeConfig(X_tool_camera=np.diag([1.0, 1.0, -1.0, 1.0]).tolist())
