"""calibration.planner: spread, reach, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.errors import CalibrationError
from calibration.handeye import DegeneracyLimits, check_motion
from calibration.planner import PlanParams, Workspace, plan_eye_in_hand, plan_eye_to_hand
from perception.transforms import invert_X


def plan(cell, **kwargs):
    params = kwargs.pop("params", PlanParams(n_poses=15))
    return plan_eye_in_hand(
        cell.board,
        X_base_board=cell.X_base_board,
        X_tool_camera=cell.X_tool_camera,
        workspace=cell.workspace,
        params=params,
        K=cell.K,
        image_size=cell.image_size,
        **kwargs,
    )


def relative_rotvecs(poses):
    Rs = Rotation.from_matrix(np.array([p[:3, :3] for p in poses]))
    i, j = np.triu_indices(len(poses), k=1)
    return (Rs[j].inv() * Rs[i]).as_rotvec()


def test_poses_are_deterministic_for_a_seed(cell):
    a, b, c = plan(cell, seed=3), plan(cell, seed=3), plan(cell, seed=4)
    assert len(a) == 15
    np.testing.assert_array_equal(np.array(a), np.array(b))
    assert np.abs(np.array(a) - np.array(c)).max() > 0.01


def test_poses_are_within_reach(cell):
    poses = plan(cell, seed=1)
    p = np.array([X[:3, 3] for X in poses])
    ws = cell.workspace
    r = np.linalg.norm(p - np.array(ws.reach_center_base), axis=1)
    assert np.all(r <= ws.reach_radius_m) and np.all(r >= ws.min_radius_m)
    assert np.all(p >= np.array(ws.box_min_base)) and np.all(p <= np.array(ws.box_max_base))
    # A tighter box moves the poses but keeps them inside.
    tight = Workspace(ws.reach_center_base, ws.reach_radius_m, ws.min_radius_m, (0.3, -0.3, 0.3), (0.9, 0.3, 0.6))
    poses = plan_eye_in_hand(
        cell.board,
        X_base_board=cell.X_base_board,
        X_tool_camera=cell.X_tool_camera,
        workspace=tight,
        params=PlanParams(n_poses=10),
        seed=1,
    )
    p = np.array([X[:3, 3] for X in poses])
    assert np.all(p >= [0.3, -0.3, 0.3]) and np.all(p <= [0.9, 0.3, 0.6])


def test_views_follow_the_stand_off_and_tilt_limits_and_see_the_board(cell):
    params = PlanParams(
        n_poses=15, standoff_m=0.4, standoff_jitter_m=0.05, min_tilt_rad=math.radians(10), max_tilt_rad=math.radians(35)
    )
    poses = plan(cell, seed=2, params=params)
    w, h = cell.board.size_m
    centre_board = np.array([w / 2, h / 2, 0.0])
    for X_base_tool in poses:
        X_board_camera = invert_X(cell.X_base_board) @ X_base_tool @ cell.X_tool_camera
        offset = X_board_camera[:3, 3] - centre_board
        distance = np.linalg.norm(offset)
        assert 0.35 - 1e-9 <= distance <= 0.45 + 1e-9
        tilt = np.degrees(np.arccos(-offset[2] / distance))  # from the board's front normal (-z)
        assert 10 - 1e-6 <= tilt <= 35 + 1e-6
        # The whole board is in the image.
        X_camera_board = invert_X(X_board_camera)
        outline = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]])
        pc = outline @ X_camera_board[:3, :3].T + X_camera_board[:3, 3]
        uv = (pc @ cell.K.T)[:, :2] / pc[:, 2:]
        assert np.all(pc[:, 2] > 0)
        assert np.all(uv >= 0) and np.all(uv[:, 0] < 1280) and np.all(uv[:, 1] < 800)


def test_rotations_are_spread_over_different_axes(cell):
    poses = plan(cell, seed=5)
    rv = relative_rotvecs(poses)
    angles = np.linalg.norm(rv, axis=1)
    assert np.degrees(angles.min()) >= 5.0 - 1e-9  # no near-duplicates
    assert np.degrees(angles.max()) > 30.0
    axes = rv[angles > np.radians(5)] / angles[angles > np.radians(5), None]
    # Not all parallel: some pair of axes is at least 60 degrees apart, and the axes span 3D.
    cos = np.abs(axes @ axes.T)
    assert np.degrees(np.arccos(cos.min())) > 60.0
    singular = np.linalg.svd(axes, compute_uv=False)
    assert singular[2] / singular[0] > 0.2
    # And the solver's own degeneracy check accepts them.
    X_camera_board = [invert_X(cell.X_tool_camera) @ invert_X(X) @ cell.X_base_board for X in poses]
    check_motion(np.array(poses), np.array(X_camera_board), limits=DegeneracyLimits())


def test_eye_to_hand_plan_presents_the_board_to_the_camera(cell):
    poses = plan_eye_to_hand(
        cell.board,
        X_base_camera=cell.X_base_camera,
        X_tool_board=cell.X_tool_board,
        workspace=cell.workspace,
        params=PlanParams(n_poses=10),
        seed=0,
        K=cell.K,
        image_size=cell.image_size,
    )
    assert len(poses) == 10
    for X_base_tool in poses:
        X_camera_board = invert_X(cell.X_base_camera) @ X_base_tool @ cell.X_tool_board
        # The board's printed face is towards the camera: its z axis points away from the camera.
        assert X_camera_board[:3, 2] @ X_camera_board[:3, 3] > 0
        # The board centre is at the stand-off (0.40 ± 0.05 m) in front of the camera.
        centre_camera = X_camera_board[:3, :3] @ [0.135, 0.09, 0.0] + X_camera_board[:3, 3]
        assert 0.35 - 1e-9 <= np.linalg.norm(centre_camera) <= 0.45 + 1e-9
        assert centre_camera[2] > 0.3
    rv = relative_rotvecs(poses)
    assert np.degrees(np.linalg.norm(rv, axis=1).max()) > 30.0


def test_unreachable_board_is_refused(cell):
    far = Workspace(reach_center_base=(0.0, 0.0, 0.163), reach_radius_m=0.4)
    with pytest.raises(CalibrationError, match="found only 0 of 15 usable poses"):
        plan_eye_in_hand(
            cell.board,
            X_base_board=cell.X_base_board,
            X_tool_camera=cell.X_tool_camera,
            workspace=far,
            params=PlanParams(n_poses=15, max_candidates=300),
        )


@pytest.mark.parametrize(
    ("kwargs", "reason"),
    [
        ({"n_poses": 2}, "at least 3 poses"),
        (
            {"min_tilt_rad": math.radians(40), "max_tilt_rad": math.radians(30)},
            "need 0 <= min_tilt <= max_tilt < 80 deg, got 40 deg, 30 deg",
        ),
        ({"standoff_jitter_m": 0.5}, "standoff_m > standoff_jitter_m"),
    ],
)
def test_bad_plan_params_are_refused(kwargs, reason):
    with pytest.raises(CalibrationError, match=reason):
        PlanParams(**kwargs)
