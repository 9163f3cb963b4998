"""calibration.board: definition, printable PNG, detection and pose against exact ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.board import (
    METRES_PER_INCH,
    BoardObservation,
    CharucoBoardSpec,
    detect_board,
    read_png_scale_px_per_m,
    render_board_png,
    solve_board_pose,
)
from calibration.errors import CalibrationError
from perception.transforms import look_at_X, make_X, rotation_angle_rad
from sim_fakes.board_render import RenderParams, render_view


def pose_error(X_a: np.ndarray, X_b: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg)."""
    return float(np.linalg.norm(X_a[:3, 3] - X_b[:3, 3])), float(np.degrees(rotation_angle_rad(X_a, X_b)))


def test_spec_geometry(cell):
    board = cell.board
    assert board.size_m == pytest.approx((0.27, 0.18))
    assert board.n_corners == 8 * 5
    corners = board.corners_board
    assert corners.shape == (40, 3)
    # Inner corners start one square in from the outer top-left corner, row by row along x.
    np.testing.assert_allclose(corners[0], [0.03, 0.03, 0.0], atol=1e-7)
    np.testing.assert_allclose(corners[1], [0.06, 0.03, 0.0], atol=1e-7)
    np.testing.assert_allclose(corners[-1], [0.24, 0.15, 0.0], atol=1e-7)


@pytest.mark.parametrize(
    ("kwargs", "reason"),
    [
        ({"marker_length_m": 0.03}, "smaller than the square"),
        ({"dictionary": "DICT_NOPE"}, "unknown ArUco dictionary"),
        ({"squares_x": 1}, "at least 2x2"),
        ({"squares_x": 20, "squares_y": 12, "dictionary": "DICT_4X4_50"}, "holds only 50"),
    ],
)
def test_spec_refuses_bad_boards(kwargs, reason):
    with pytest.raises(CalibrationError, match=reason):
        CharucoBoardSpec(**kwargs)


def test_render_png_states_its_scale_and_detects_frontally(tmp_path, cell):
    board = cell.board
    # 150 dpi asks for 177.17 px per 30 mm square; every square gets 177 px, so the exact scale is
    # 177 / 0.03 = 5900 px/m = 149.86 dpi, and that is what the file states.
    path = render_board_png(tmp_path, board=board, dpi=150.0, margin_m=0.01)
    assert path.name == "charuco_9x6_sq30mm_mk22mm_DICT_5X5_100_149.9dpi.png"
    px_per_m = 5900.0
    assert read_png_scale_px_per_m(path) == px_per_m
    assert px_per_m * METRES_PER_INCH == pytest.approx(149.86, abs=0.01)
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    margin = 59
    assert image.shape == (6 * 177 + 2 * margin, 9 * 177 + 2 * margin)
    # Squares are whole pixels: the first row of squares alternates exactly every 177 px.
    row = image[margin + 88, margin : margin + 9 * 177]
    assert np.all(row[:177] == row[0]) and row[177] != row[0]

    # Read the print as a frontal pinhole image: f / Z = px_per_m, so the board pose is known exactly.
    f = 1000.0
    cx, cy = (image.shape[1] - 1) / 2.0, (image.shape[0] - 1) / 2.0
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    t_true = [(margin - 0.5 - cx) / px_per_m, (margin - 0.5 - cy) / px_per_m, f / px_per_m]
    obs = detect_board(image, board=board, K=K)
    assert obs.n_corners == board.n_corners
    dt, dr = pose_error(obs.X_camera_board, make_X(np.eye(3), t_true))
    assert dt < 2e-5  # 0.02 mm at 0.17 m
    assert dr < 0.01
    assert obs.rms_px < 0.05
    np.testing.assert_allclose(obs.corners_board, board.corners_board[obs.corner_ids], atol=1e-7)


def _tilted_view(cell, *, aim_offset=(0.0, 0.0), distance=0.42):
    """X_camera_board of a camera 25 deg off the board normal, rolled 20 deg, looking at the centre."""
    w, h = cell.board.size_m
    centre = np.array([w / 2, h / 2, 0.0])
    direction = np.array(
        [np.sin(np.radians(25)) * np.cos(0.7), np.sin(np.radians(25)) * np.sin(0.7), -np.cos(np.radians(25))]
    )
    aim = centre + np.array([*aim_offset, 0.0])
    X_board_camera = look_at_X(centre + distance * direction, aim, up=(0.0, -1.0, 0.0))
    X_board_camera = X_board_camera @ make_X(Rotation.from_euler("z", 20, degrees=True).as_matrix(), np.zeros(3))
    return np.linalg.inv(X_board_camera)


def _render(cell, X_camera_board, *, dist=None, seed=0, params=None):
    params = params or RenderParams()
    picture = cell.board.image(
        px_per_m=params.board_px_per_m, margin_px=round(params.board_margin_m * params.board_px_per_m)
    )
    return render_view(
        picture,
        X_camera_board,
        K=cell.K,
        dist=dist,
        image_size=cell.image_size,
        params=params,
        rng=np.random.default_rng(seed),
    )


def test_render_detect_round_trip_tilted(cell):
    X_camera_board = _tilted_view(cell)
    image = _render(cell, X_camera_board)
    obs = detect_board(image, board=cell.board, K=cell.K)
    assert obs.n_corners == 40
    rvec, _ = cv2.Rodrigues(X_camera_board[:3, :3])
    exact, _ = cv2.projectPoints(obs.corners_board, rvec, X_camera_board[:3, 3], cell.K, np.zeros(5))
    corner_err = np.linalg.norm(obs.corners_px - exact.reshape(-1, 2), axis=1)
    assert corner_err.mean() < 0.06
    assert corner_err.max() < 0.2
    dt, dr = pose_error(obs.X_camera_board, X_camera_board)
    assert dt < 1e-4  # 0.1 mm
    assert dr < 0.02


def test_render_detect_round_trip_with_distortion(cell):
    dist = np.array([-0.12, 0.05, 0.0005, -0.0003, 0.0])
    X_camera_board = _tilted_view(cell)
    image = _render(cell, X_camera_board, dist=dist)
    obs = detect_board(image, board=cell.board, K=cell.K, dist=dist)
    assert obs.n_corners == 40
    dt, dr = pose_error(obs.X_camera_board, X_camera_board)
    assert dt < 1e-4
    assert dr < 0.02
    # Ignoring the distortion must cost accuracy, or the test would not exercise it.
    naive = detect_board(image, board=cell.board, K=cell.K)
    assert pose_error(naive.X_camera_board, X_camera_board)[0] > 5 * dt


def test_too_few_corners_is_refused_with_the_count(cell):
    image = _render(cell, _tilted_view(cell))
    with pytest.raises(CalibrationError, match="40 ChArUco corners found, at least 41 needed"):
        detect_board(image, board=cell.board, K=cell.K, min_corners=41)
    blank = np.full((800, 1280), 128, dtype=np.uint8)
    with pytest.raises(CalibrationError, match="0 ChArUco corners found"):
        detect_board(blank, board=cell.board, K=cell.K)


def test_partly_visible_board_reports_the_corners_it_sees(cell):
    # Aimed off the board: about half of the corners are in the image, fewer have both neighbouring
    # markers whole (a ChArUco corner needs them).
    X_camera_board = _tilted_view(cell, aim_offset=(0.12, 0.08), distance=0.3)
    image = _render(cell, X_camera_board)
    rvec, _ = cv2.Rodrigues(X_camera_board[:3, :3])
    exact, _ = cv2.projectPoints(cell.board.corners_board, rvec, X_camera_board[:3, 3], cell.K, np.zeros(5))
    exact = exact.reshape(-1, 2)
    in_image = np.flatnonzero(np.all((exact >= 0) & (exact <= np.array(cell.image_size) - 1), axis=1))
    assert 10 < len(in_image) < 30
    obs = detect_board(image, board=cell.board, K=cell.K)
    assert set(obs.corner_ids.tolist()) <= set(in_image.tolist())
    assert 6 <= obs.n_corners < len(in_image)
    np.testing.assert_allclose(obs.corners_px, exact[obs.corner_ids], atol=0.25)
    dt, dr = pose_error(obs.X_camera_board, X_camera_board)
    assert dt < 5e-4 and dr < 0.1
    with pytest.raises(CalibrationError, match=f"{obs.n_corners} ChArUco corners found, at least 35"):
        detect_board(image, board=cell.board, K=cell.K, min_corners=35)


def test_solve_board_pose_is_exact_without_noise(cell):
    X_camera_board = _tilted_view(cell)
    rvec, _ = cv2.Rodrigues(X_camera_board[:3, :3])
    px, _ = cv2.projectPoints(cell.board.corners_board, rvec, X_camera_board[:3, 3], cell.K, np.zeros(5))
    X, rms = solve_board_pose(cell.board.corners_board, px.reshape(-1, 2), K=cell.K)
    dt, dr = pose_error(X, X_camera_board)
    assert dt < 1e-9 and dr < 1e-6 and rms < 1e-6


def test_observation_checks_shapes():
    with pytest.raises(CalibrationError, match="corners_px"):
        BoardObservation(
            corner_ids=np.arange(4),
            corners_px=np.zeros((3, 2)),
            corners_board=np.zeros((4, 3)),
            X_camera_board=np.eye(4),
            rms_px=0.0,
        )
