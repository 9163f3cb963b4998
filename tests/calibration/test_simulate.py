"""calibration.simulate: the synthetic data carries exactly the truth and noise it claims."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.planner import PlanParams, plan_eye_in_hand
from calibration.simulate import perturb_pose, simulate_views
from perception.transforms import invert_X


@pytest.fixture(scope="module")
def plan15(cell):
    return plan_eye_in_hand(
        cell.board,
        X_base_board=cell.X_base_board,
        X_tool_camera=cell.X_tool_camera,
        workspace=cell.workspace,
        params=PlanParams(n_poses=15),
        seed=0,
        K=cell.K,
        image_size=cell.image_size,
    )


def simulate(cell, plan, **kwargs):
    return simulate_views(
        plan,
        board=cell.board,
        K=cell.K,
        image_size=cell.image_size,
        X_tool_camera=cell.X_tool_camera,
        X_base_board=cell.X_base_board,
        **kwargs,
    )


def test_noise_free_views_are_exact_projections(cell, plan15):
    views = simulate(cell, plan15)
    for X_plan, v in zip(plan15, views, strict=True):
        np.testing.assert_array_equal(v.X_base_tool, X_plan)
        np.testing.assert_allclose(v.X_base_tool_true, X_plan, atol=1e-15)
        expected = invert_X(cell.X_tool_camera) @ invert_X(X_plan) @ cell.X_base_board
        np.testing.assert_allclose(v.X_camera_board_true, expected, atol=1e-12)
        assert len(v.corner_ids) == 40  # the planner keeps the whole board in view
        rvec, _ = cv2.Rodrigues(expected[:3, :3])
        px, _ = cv2.projectPoints(cell.board.corners_board, rvec, expected[:3, 3], cell.K, np.zeros(5))
        np.testing.assert_allclose(v.corners_px, px.reshape(-1, 2), atol=1e-9)
        assert v.image is None


def test_noise_has_the_requested_spread(cell, plan15):
    views = simulate(cell, plan15, corner_sigma_px=0.3, robot_sigma_m=1e-3, robot_sigma_rad=2e-3, seed=7)
    exact = simulate(cell, plan15)
    # Robot: the true pose differs from the reported one by the requested noise.
    dt = np.concatenate([v.X_base_tool_true[:3, 3] - v.X_base_tool[:3, 3] for v in views])
    assert np.std(dt) == pytest.approx(1e-3, rel=0.3)
    # Corners: relative to the exact projection of the *true* pose.
    true_pose_views = simulate_views(
        [v.X_base_tool_true for v in views],
        board=cell.board,
        K=cell.K,
        image_size=cell.image_size,
        X_tool_camera=cell.X_tool_camera,
        X_base_board=cell.X_base_board,
    )
    d = np.concatenate([v.corners_px - t.corners_px for v, t in zip(views, true_pose_views, strict=True)])
    assert np.std(d) == pytest.approx(0.3, rel=0.1)
    assert abs(np.mean(d)) < 0.03
    # Same seed, same data; the exact views do not move.
    again = simulate(cell, plan15, corner_sigma_px=0.3, robot_sigma_m=1e-3, robot_sigma_rad=2e-3, seed=7)
    np.testing.assert_array_equal(views[3].corners_px, again[3].corners_px)
    assert np.abs(views[3].corners_px - exact[3].corners_px).max() > 0.1


def test_perturb_pose_is_a_rigid_transform():
    rng = np.random.default_rng(0)
    X = perturb_pose(np.eye(4), sigma_m=0.01, sigma_rad=0.1, rng=rng)
    np.testing.assert_allclose(X[:3, :3].T @ X[:3, :3], np.eye(3), atol=1e-12)
    assert np.linalg.det(X[:3, :3]) == pytest.approx(1.0)


def test_a_plan_that_misses_the_camera_is_refused(cell):
    away = [np.eye(4)]  # tool at the base origin: the board is behind the camera
    with pytest.raises(CalibrationError, match="sees only 0 corners"):
        simulate(cell, away)


def test_each_view_image_is_drawn_by_the_renderer_handed_in_with_that_view_s_true_pose(cell, plan15):
    calls = []

    def recording(board, X_camera_board, *, K, image_size, rng, dist=None):
        calls.append((board, X_camera_board, K, image_size, dist))
        return np.full((image_size[1], image_size[0]), len(calls), dtype=np.uint8)

    views = simulate(cell, plan15[:3], render=recording)
    assert len(calls) == 3
    for i, (v, (board, X_cb, K, size, dist)) in enumerate(zip(views, calls, strict=True)):
        assert board is cell.board and size == cell.image_size
        np.testing.assert_array_equal(X_cb, v.X_camera_board_true)
        np.testing.assert_array_equal(K, cell.K)
        np.testing.assert_array_equal(dist, np.zeros(5))
        assert v.image is not None and v.image.shape == (800, 1280) and np.all(v.image == i + 1)


def test_a_rendered_view_shows_the_board_where_its_corners_are(cell, plan15):
    from calibration.board import detect_board
    from sim_fakes.board_render import BoardRenderer, RenderParams

    (view,) = simulate(cell, plan15[:1], render=BoardRenderer(RenderParams()))
    assert view.image is not None
    obs = detect_board(view.image, board=cell.board, K=cell.K)
    assert obs.n_corners == 40
    order = np.argsort(view.corner_ids)
    np.testing.assert_array_equal(obs.corner_ids, view.corner_ids[order])
    # the detector finds the exact projections (corner noise 0), as on test_board's rendered views
    error_px = np.linalg.norm(obs.corners_px - view.corners_px[order], axis=1)
    assert error_px.mean() < 0.06 and error_px.max() < 0.2
