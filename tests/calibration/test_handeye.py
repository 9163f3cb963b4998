"""calibration.handeye: exact recovery, noise behaviour, degenerate input, eye-to-hand."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.axxb import LinearMethod
from calibration.board import solve_board_pose
from calibration.errors import CalibrationError
from calibration.handeye import (
    REFINED,
    DegeneracyLimits,
    HandEyeMode,
    HandEyeResult,
    RefineParams,
    check_motion,
    solve_hand_eye,
    solve_hand_eye_from_observations,
)
from calibration.planner import PlanParams, plan_eye_in_hand, plan_eye_to_hand
from calibration.simulate import simulate_views
from perception.transforms import invert_X, make_X

METHODS = [m.value for m in LinearMethod]


def errors(X: np.ndarray, X_true: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation rad); the angle via the rotation vector, exact near zero (arccos is not)."""
    angle = Rotation.from_matrix(X[:3, :3].T @ X_true[:3, :3]).magnitude()
    return float(np.linalg.norm(X[:3, 3] - X_true[:3, 3])), float(angle)


def eye_in_hand_views(cell, *, n=12, seed=0, corner_sigma_px=0.0, robot_sigma_m=0.0, robot_sigma_rad=0.0):
    plan = plan_eye_in_hand(
        cell.board,
        X_base_board=cell.X_base_board,
        X_tool_camera=cell.X_tool_camera,
        workspace=cell.workspace,
        params=PlanParams(n_poses=n),
        seed=seed,
        K=cell.K,
        image_size=cell.image_size,
    )
    return simulate_views(
        plan,
        board=cell.board,
        K=cell.K,
        image_size=cell.image_size,
        X_tool_camera=cell.X_tool_camera,
        X_base_board=cell.X_base_board,
        corner_sigma_px=corner_sigma_px,
        robot_sigma_m=robot_sigma_m,
        robot_sigma_rad=robot_sigma_rad,
        seed=1000 + seed,
    )


def solve_views(cell, views, *, mode="eye_in_hand", measured=True, refine=None):
    """Solve from simulated views; the board poses are measured by PnP from the (noisy) corners."""
    if measured:
        X_camera_board = [solve_board_pose(v.corners_board, v.corners_px, K=cell.K)[0] for v in views]
    else:
        X_camera_board = [v.X_camera_board_true for v in views]
    return solve_hand_eye(
        [v.X_base_tool for v in views],
        X_camera_board,
        mode=mode,
        corners_px=[v.corners_px for v in views],
        corners_board=[v.corners_board for v in views],
        K=cell.K,
        refine=refine,
    )


def test_noise_free_every_method_and_the_refinement_recover_the_truth(cell):
    views = eye_in_hand_views(cell)
    result = solve_views(cell, views, measured=False)
    assert result.method == REFINED and result.mode is HandEyeMode.EYE_IN_HAND
    assert sorted(r.method for r in result.linear) == sorted(METHODS)
    assert result.linear_failures == ()
    for res in (result, *result.linear):
        dt, dr = errors(res.X_tool_camera, cell.X_tool_camera)
        assert dt < 1e-8, res.method
        assert dr < 1e-8, res.method
        db, dbr = errors(res.X_base_board, cell.X_base_board)
        assert db < 1e-8 and dbr < 1e-8, res.method
    assert result.X_base_camera is None and result.X_tool_board is None
    assert result.n_views == 12
    assert result.rms_px < 1e-6 and result.rms_mm < 1e-5 and result.rms_deg < 1e-6
    assert result.view_residuals_px.shape == (12,)


def test_with_noise_the_refinement_beats_every_linear_method(cell):
    # 0.3 px corner noise and 0.05 mm / 0.1 mrad robot noise, 15 planned poses, six seeds.
    errs: dict[str, list[tuple[float, float]]] = {}
    for seed in range(6):
        views = eye_in_hand_views(
            cell, n=15, seed=seed, corner_sigma_px=0.3, robot_sigma_m=0.05e-3, robot_sigma_rad=1e-4
        )
        result = solve_views(cell, views)
        for res in (result, *result.linear):
            errs.setdefault(res.method, []).append(errors(res.X_tool_camera, cell.X_tool_camera))
        # Residuals are consistent with the noise that went in.
        assert 0.3 < result.rms_px < 0.6
    median = {m: np.median(np.array(e), axis=0) for m, e in errs.items()}
    t_ref, r_ref = median[REFINED]
    assert t_ref < 0.5e-3
    assert np.degrees(r_ref) < 0.05
    for m in METHODS:
        assert t_ref < median[m][0], m
        assert r_ref < median[m][1], m


def test_robot_noise_model_matters(cell):
    # With only robot noise, taking the robot as exact lets the refinement tilt the camera to absorb
    # it; the per-view robot corrections keep the rotation within a few thousandths of a degree.
    views = eye_in_hand_views(cell, n=15, seed=3, robot_sigma_m=0.05e-3)
    modelled = solve_views(cell, views, measured=False)
    exact = solve_views(cell, views, measured=False, refine=RefineParams(robot_sigma_m=None))
    r_modelled = errors(modelled.X_tool_camera, cell.X_tool_camera)[1]
    r_exact = errors(exact.X_tool_camera, cell.X_tool_camera)[1]
    assert np.degrees(r_modelled) < 0.01
    assert r_modelled < r_exact


def test_robust_loss_resists_outlier_corners(cell):
    views = eye_in_hand_views(cell, n=12, seed=5, corner_sigma_px=0.2)
    rng = np.random.default_rng(0)
    X_camera_board = [solve_board_pose(v.corners_board, v.corners_px, K=cell.K)[0] for v in views]
    corners_px = []
    for v in views:
        px = v.corners_px.copy()
        bad = rng.choice(len(px), size=3, replace=False)
        px[bad] += rng.normal(0.0, 15.0, (3, 2))  # 3 mis-detected corners per view
        corners_px.append(px)
    kwargs = dict(corners_px=corners_px, corners_board=[v.corners_board for v in views], K=cell.K)
    X_base_tool = [v.X_base_tool for v in views]
    plain = solve_hand_eye(X_base_tool, X_camera_board, **kwargs)
    robust = solve_hand_eye(X_base_tool, X_camera_board, **kwargs, refine=RefineParams(loss="soft_l1"))
    t_plain = errors(plain.X_tool_camera, cell.X_tool_camera)[0]
    t_robust = errors(robust.X_tool_camera, cell.X_tool_camera)[0]
    assert t_robust < 0.5e-3
    assert t_robust < 0.5 * t_plain


def test_without_corner_pixels_the_pose_refinement_recovers_the_truth(cell):
    views = eye_in_hand_views(cell, n=8)
    result = solve_hand_eye([v.X_base_tool for v in views], [v.X_camera_board_true for v in views])
    assert result.rms_px is None and result.view_residuals_px is None
    dt, dr = errors(result.X_tool_camera, cell.X_tool_camera)
    assert dt < 1e-8 and dr < 1e-8


def test_from_observations_matches_the_arrays_api(cell):
    from calibration.board import BoardObservation

    views = eye_in_hand_views(cell, n=10, seed=2, corner_sigma_px=0.2)
    observations = []
    for v in views:
        X, rms = solve_board_pose(v.corners_board, v.corners_px, K=cell.K)
        observations.append(BoardObservation(v.corner_ids, v.corners_px, v.corners_board, X, rms))
    a = solve_hand_eye_from_observations([v.X_base_tool for v in views], observations, K=cell.K)
    b = solve_views(cell, views)
    np.testing.assert_allclose(a.X_tool_camera, b.X_tool_camera, atol=1e-12)


def test_eye_to_hand_recovers_camera_and_board_mount(cell):
    plan = plan_eye_to_hand(
        cell.board,
        X_base_camera=cell.X_base_camera,
        X_tool_board=cell.X_tool_board,
        workspace=cell.workspace,
        params=PlanParams(n_poses=12),
        seed=4,
        K=cell.K,
        image_size=cell.image_size,
    )
    sim = dict(
        board=cell.board,
        K=cell.K,
        image_size=cell.image_size,
        mode="eye_to_hand",
        X_base_camera=cell.X_base_camera,
        X_tool_board=cell.X_tool_board,
    )
    exact = solve_views(cell, simulate_views(plan, **sim), mode="eye_to_hand", measured=False)
    assert exact.mode is HandEyeMode.EYE_TO_HAND
    assert exact.X_tool_camera is None and exact.X_base_board is None
    for res in (exact, *exact.linear):
        dt, dr = errors(res.X_base_camera, cell.X_base_camera)
        assert dt < 1e-8 and dr < 1e-8, res.method
        dt, dr = errors(res.X_tool_board, cell.X_tool_board)
        assert dt < 1e-8 and dr < 1e-8, res.method

    noisy_views = simulate_views(plan, **sim, corner_sigma_px=0.3, robot_sigma_m=0.05e-3, seed=9)
    noisy = solve_views(cell, noisy_views, mode="eye_to_hand")
    dt, dr = errors(noisy.X_base_camera, cell.X_base_camera)
    # The camera is 0.4 m from the board, as in the eye-in-hand case, but 1 m from the base origin.
    assert dt < 1e-3 and np.degrees(dr) < 0.1
    # The same data solved as eye-in-hand cannot be explained, and says so.
    with pytest.raises(CalibrationError, match=r"does not explain the views: median corner reprojection error"):
        solve_views(cell, noisy_views, mode="eye_in_hand")


# ---- degenerate input ------------------------------------------------------------------------------


def _views_from_tool_poses(cell, X_base_tool):
    X_camera_tool = invert_X(cell.X_tool_camera)
    return X_base_tool, [X_camera_tool @ invert_X(T) @ cell.X_base_board for T in X_base_tool]


def _tool_pose(rotvec_deg, t):
    # Tool pointing down at the board, then the given extra rotation about the tool axes.
    R = Rotation.from_euler("x", 180, degrees=True) * Rotation.from_rotvec(np.radians(rotvec_deg))
    return make_X(R.as_matrix(), t)


@pytest.mark.parametrize(
    ("tool_poses", "reason"),
    [
        ([_tool_pose([0, 0, 0], [0.5, 0, 0.5]), _tool_pose([20, 0, 0], [0.55, 0, 0.5])], "at least 3 views, got 2"),
        ([_tool_pose([0, 0, 0], [0.5, 0, 0.5])] * 4, "same robot pose"),
        (
            [_tool_pose([0, 0, 0], [0.5 + 0.05 * i, 0.03 * i, 0.5 - 0.02 * i]) for i in range(6)],
            "pure translations",
        ),
        (
            [_tool_pose([3 * (i % 2), 3 * (i // 2 % 2), 0], [0.5 + 0.05 * i, 0.02 * i, 0.5]) for i in range(6)],
            "relative rotations too small",
        ),
        (
            [_tool_pose([0, 0, 25 * i], [0.5 + 0.04 * i, 0.02 * i, 0.5]) for i in range(6)],
            "rotations all about a single axis",
        ),
    ],
    ids=["two-views", "no-motion", "pure-translation", "small-rotation", "single-axis"],
)
def test_degenerate_motion_is_refused_with_its_reason(cell, tool_poses, reason):
    X_base_tool, X_camera_board = _views_from_tool_poses(cell, tool_poses)
    with pytest.raises(CalibrationError, match=reason):
        solve_hand_eye(X_base_tool, X_camera_board)


def test_the_motion_limits_are_radians_and_the_messages_say_degrees(cell):
    # rotations of 3 deg about x and about y: the largest relative rotation is 3 * sqrt(2) = 4.24 deg
    poses = [_tool_pose([3 * (i % 2), 3 * (i // 2 % 2), 0], [0.5 + 0.05 * i, 0.02 * i, 0.5]) for i in range(6)]
    H, X_camera_board = _views_from_tool_poses(cell, poses)
    assert DegeneracyLimits().min_rotation_rad == pytest.approx(np.radians(5.0))
    with pytest.raises(CalibrationError, match=r"is 4\.24 deg \(< 5 deg\)"):
        check_motion(np.array(H), np.array(X_camera_board), limits=DegeneracyLimits())
    check_motion(np.array(H), np.array(X_camera_board), limits=DegeneracyLimits(min_rotation_rad=np.radians(4.2)))
    with pytest.raises(CalibrationError, match=r"\(< 4\.3 deg\)"):
        check_motion(np.array(H), np.array(X_camera_board), limits=DegeneracyLimits(min_rotation_rad=np.radians(4.3)))


def test_single_axis_is_refused_even_about_a_tilted_axis(cell):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    poses = [_tool_pose(axis * 20 * i, [0.5 + 0.03 * i, 0.01 * i, 0.5]) for i in range(7)]
    X_base_tool, X_camera_board = _views_from_tool_poses(cell, poses)
    with pytest.raises(CalibrationError, match="rotations all about a single axis") as info:
        solve_hand_eye(X_base_tool, X_camera_board)
    # The message names the axis (in the tool frame, sign-free).
    named = np.array(json.loads(re.search(r"of the axis (\[[^\]]*\])", str(info.value)).group(1)))
    assert abs(named @ axis) > 0.999


def test_inverted_robot_poses_are_refused(cell):
    # A classic slip: passing X_tool_base. The relative rotation angles are the same, so only the
    # solution's residuals can tell.
    views = eye_in_hand_views(cell, n=10, corner_sigma_px=0.2)
    with pytest.raises(CalibrationError, match="not inverted"):
        solve_hand_eye(
            [invert_X(v.X_base_tool) for v in views],
            [v.X_camera_board_true for v in views],
            corners_px=[v.corners_px for v in views],
            corners_board=[v.corners_board for v in views],
            K=cell.K,
        )
    with pytest.raises(CalibrationError, match=r"median board-point disagreement .* mm"):
        solve_hand_eye([invert_X(v.X_base_tool) for v in views], [v.X_camera_board_true for v in views])


def test_mis_paired_views_are_refused(cell):
    views = eye_in_hand_views(cell, n=10)
    X_camera_board = [v.X_camera_board_true for v in views]
    shuffled = X_camera_board[3:] + X_camera_board[:3]
    with pytest.raises(CalibrationError, match="robot and camera rotations disagree"):
        solve_hand_eye([v.X_base_tool for v in views], shuffled)


def test_bad_shapes_and_pairings_are_refused(cell):
    views = eye_in_hand_views(cell, n=8)
    X_base_tool = [v.X_base_tool for v in views]
    X_camera_board = [v.X_camera_board_true for v in views]
    with pytest.raises(CalibrationError, match="8 robot poses but 7 board poses"):
        solve_hand_eye(X_base_tool, X_camera_board[:7])
    with pytest.raises(CalibrationError, match="invalid pose"):
        solve_hand_eye([*X_base_tool[:-1], np.full((4, 4), np.nan)], X_camera_board)
    with pytest.raises(CalibrationError, match="together"):
        solve_hand_eye(X_base_tool, X_camera_board, corners_px=[v.corners_px for v in views])
    with pytest.raises(CalibrationError, match="unknown hand-eye mode"):
        solve_hand_eye(X_base_tool, X_camera_board, mode="eye_on_table")


def test_result_refuses_fields_of_the_other_mode():
    with pytest.raises(CalibrationError, match="X_base_board is required"):
        HandEyeResult(
            mode=HandEyeMode.EYE_IN_HAND,
            method=REFINED,
            view_residuals_mm=np.zeros(3),
            view_residuals_deg=np.zeros(3),
            X_tool_camera=np.eye(4),
        )
    with pytest.raises(CalibrationError, match="belongs to the other mode"):
        HandEyeResult(
            mode=HandEyeMode.EYE_IN_HAND,
            method=REFINED,
            view_residuals_mm=np.zeros(3),
            view_residuals_deg=np.zeros(3),
            X_tool_camera=np.eye(4),
            X_base_board=np.eye(4),
            X_tool_board=np.eye(4),
        )
