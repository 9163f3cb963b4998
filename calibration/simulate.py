"""Synthetic hand-eye calibration data with known truth (for the benchmark and the tests).

Given the true hand-eye transform and board pose, a camera and a pose plan, each view gets:

- the pose the robot reports, ``X_base_tool`` (the plan), and the pose it really reached,
  ``X_base_tool_true`` = the plan perturbed by repeatability noise (``robot_sigma_m`` per axis,
  ``robot_sigma_rad`` per axis as a rotation vector);
- the true ``X_camera_board`` from the real pose;
- the ChArUco corners inside the image, projected with the camera model, plus Gaussian pixel noise
  (``corner_sigma_px`` per coordinate);
- optionally a rendered 8-bit image: the board picture warped into the camera (supersampled, so edges
  are area-averaged), lens blur, and sensor noise, for exercising :func:`calibration.board.detect_board`.

Everything random comes from ``seed``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from calibration.board import CharucoBoardSpec
from calibration.errors import CalibrationError
from calibration.handeye import HandEyeMode
from perception.transforms import check_X, invert_X, make_X

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class RenderParams:
    """Synthetic image settings. ``supersample``: render at this factor and area-average down.
    ``blur_sigma_px``: Gaussian lens blur, pixels. ``noise_sigma``: sensor noise, gray levels.
    ``background``: gray level around the board. ``board_px_per_m``: resolution of the board picture
    that is warped (keep it above the projected resolution times ``supersample``)."""

    supersample: int = 3
    blur_sigma_px: float = 0.6
    noise_sigma: float = 2.0
    background: int = 90
    board_px_per_m: float = 8000.0
    board_margin_m: float = 0.01


@dataclass(frozen=True)
class SimulatedView:
    """One synthetic view.

    ``X_base_tool``: (4, 4) pose the robot reports. ``X_base_tool_true``: (4, 4) pose it really had.
    ``X_camera_board_true``: (4, 4) true board pose in the camera. ``corner_ids``: (M,) visible
    ChArUco corner ids; ``corners_px``: (M, 2) their noisy pixels; ``corners_board``: (M, 3) their
    board-frame positions, metres. ``image``: (H, W) uint8 rendering, or None.
    """

    X_base_tool: FloatArray
    X_base_tool_true: FloatArray
    X_camera_board_true: FloatArray
    corner_ids: NDArray[np.int32]
    corners_px: FloatArray
    corners_board: FloatArray
    image: NDArray[np.uint8] | None = None


def perturb_pose(X: ArrayLike, *, sigma_m: float, sigma_rad: float, rng: np.random.Generator) -> FloatArray:
    """``X`` moved by N(0, sigma_m) per axis and rotated by a N(0, sigma_rad) per-axis rotation vector."""
    Xa = np.asarray(X, dtype=np.float64)
    dR = Rotation.from_rotvec(rng.normal(0.0, sigma_rad, 3)).as_matrix()
    return make_X(dR @ Xa[:3, :3], Xa[:3, 3] + rng.normal(0.0, sigma_m, 3))


def simulate_views(
    X_base_tool_plan: Sequence[ArrayLike],
    *,
    board: CharucoBoardSpec,
    K: ArrayLike,
    image_size: tuple[int, int],
    mode: HandEyeMode | str = HandEyeMode.EYE_IN_HAND,
    X_tool_camera: ArrayLike | None = None,
    X_base_board: ArrayLike | None = None,
    X_base_camera: ArrayLike | None = None,
    X_tool_board: ArrayLike | None = None,
    dist: ArrayLike | None = None,
    corner_sigma_px: float = 0.0,
    robot_sigma_m: float = 0.0,
    robot_sigma_rad: float = 0.0,
    seed: int = 0,
    render: RenderParams | None = None,
    min_corners: int = 6,
) -> list[SimulatedView]:
    """Synthesize one :class:`SimulatedView` per planned pose.

    Eye-in-hand needs the truths ``X_tool_camera`` and ``X_base_board``; eye-to-hand ``X_base_camera``
    and ``X_tool_board`` (all (4, 4), metres). ``K``: (3, 3); ``image_size``: (width, height) pixels;
    ``dist``: OpenCV distortion coefficients. ``render``: also draw an image of each view.
    Raises CalibrationError when a view sees fewer than ``min_corners`` corners (the plan does not
    fit the camera).
    """
    mode_ = HandEyeMode(mode)
    if mode_ is HandEyeMode.EYE_IN_HAND:
        if X_tool_camera is None or X_base_board is None:
            raise CalibrationError("eye-in-hand simulation needs X_tool_camera and X_base_board")
        X_camera_tool = invert_X(check_X(X_tool_camera, name="X_tool_camera"))
        X_bb = check_X(X_base_board, name="X_base_board")

        def camera_board(X_base_tool_true: FloatArray) -> FloatArray:
            return X_camera_tool @ invert_X(X_base_tool_true) @ X_bb

    else:
        if X_base_camera is None or X_tool_board is None:
            raise CalibrationError("eye-to-hand simulation needs X_base_camera and X_tool_board")
        X_camera_base = invert_X(check_X(X_base_camera, name="X_base_camera"))
        X_tb = check_X(X_tool_board, name="X_tool_board")

        def camera_board(X_base_tool_true: FloatArray) -> FloatArray:
            return X_camera_base @ X_base_tool_true @ X_tb

    rng = np.random.default_rng(seed)
    K_arr = np.asarray(K, dtype=np.float64)
    dist_arr = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
    corners_all = board.corners_board
    board_picture = None
    if render is not None:
        board_picture = board.image(
            px_per_m=render.board_px_per_m, margin_px=round(render.board_margin_m * render.board_px_per_m)
        )
    views: list[SimulatedView] = []
    for i, X_plan in enumerate(X_base_tool_plan):
        X_reported = check_X(X_plan, name=f"X_base_tool_plan[{i}]")
        X_true = perturb_pose(X_reported, sigma_m=robot_sigma_m, sigma_rad=robot_sigma_rad, rng=rng)
        X_cb = camera_board(X_true)
        ids, px = _visible_corners(corners_all, X_cb, K_arr, dist_arr, image_size)
        if len(ids) < min_corners:
            raise CalibrationError(f"simulated view {i} sees only {len(ids)} corners; the plan does not fit the camera")
        px_noisy = px + rng.normal(0.0, corner_sigma_px, px.shape)
        image = None
        if render is not None and board_picture is not None:
            image = render_view(
                board_picture, X_cb, K=K_arr, dist=dist_arr, image_size=image_size, params=render, rng=rng
            )
        views.append(
            SimulatedView(
                X_base_tool=X_reported,
                X_base_tool_true=X_true,
                X_camera_board_true=X_cb,
                corner_ids=ids,
                corners_px=px_noisy,
                corners_board=corners_all[ids],
                image=image,
            )
        )
    return views


def _visible_corners(
    corners_board: FloatArray, X_camera_board: FloatArray, K: FloatArray, dist: FloatArray, image_size: tuple[int, int]
) -> tuple[NDArray[np.int32], FloatArray]:
    """Ids and exact pixels of the corners in front of the camera, facing it, and inside the image."""
    p_camera = corners_board @ X_camera_board[:3, :3].T + X_camera_board[:3, 3]
    normal_camera = X_camera_board[:3, 2]  # board z, pointing away from a camera that sees the print
    facing = float(np.dot(normal_camera, X_camera_board[:3, 3])) > 0.0
    if not facing:
        return np.zeros(0, dtype=np.int32), np.zeros((0, 2))
    rvec, _ = cv2.Rodrigues(X_camera_board[:3, :3])
    px, _ = cv2.projectPoints(corners_board, rvec, X_camera_board[:3, 3], K, dist)
    px = px.reshape(-1, 2)
    width, height = image_size
    inside = (
        (p_camera[:, 2] > 0.0)
        & (px[:, 0] >= 0.0)
        & (px[:, 0] <= width - 1.0)
        & (px[:, 1] >= 0.0)
        & (px[:, 1] <= height - 1.0)
    )
    ids = np.flatnonzero(inside).astype(np.int32)
    return ids, np.asarray(px[ids], dtype=np.float64)


def render_view(
    board_picture: NDArray[np.uint8],
    X_camera_board: ArrayLike,
    *,
    K: ArrayLike,
    image_size: tuple[int, int],
    params: RenderParams,
    rng: np.random.Generator,
    dist: ArrayLike | None = None,
) -> NDArray[np.uint8]:
    """(H, W) uint8 camera image of a board picture made by ``CharucoBoardSpec.image`` with
    ``px_per_m = params.board_px_per_m`` and margin ``params.board_margin_m``.

    Board point (x, y) is at picture pixel ``margin - 0.5 + (x, y) * px_per_m`` (pixel-centre
    convention). Without distortion the picture is warped by the plane homography; with distortion
    each image pixel's ray is intersected with the board plane and the picture is remapped.
    """
    X = check_X(X_camera_board, name="X_camera_board")
    K_arr = np.asarray(K, dtype=np.float64)
    dist_arr = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
    width, height = image_size
    s = int(params.supersample)
    if s < 1:
        raise CalibrationError(f"supersample must be >= 1, got {s}")
    ppm = params.board_px_per_m
    offset = round(params.board_margin_m * ppm) - 0.5
    # Board metres -> picture pixels, and supersampled-image pixels -> image pixels (pixel centres).
    picture_from_board = np.array([[ppm, 0.0, offset], [0.0, ppm, offset], [0.0, 0.0, 1.0]])
    big_from_image = np.array([[s, 0.0, (s - 1) / 2.0], [0.0, s, (s - 1) / 2.0], [0.0, 0.0, 1.0]])
    big_size = (width * s, height * s)
    if not np.any(dist_arr):
        image_from_board = K_arr @ np.column_stack([X[:3, 0], X[:3, 1], X[:3, 3]])
        H = big_from_image @ image_from_board @ np.linalg.inv(picture_from_board)
        big = cv2.warpPerspective(
            board_picture,
            H,
            big_size,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=params.background,
        )
    else:
        # Cast the ray of every image pixel centre onto the board plane (undistorting it first), then
        # upsample that smooth map to the supersampled grid: cv2.resize's pixel-centre convention
        # puts big pixel x at image pixel (x + 0.5) / s - 0.5, exactly where it belongs.
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        image_uv = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
        rays = cv2.undistortPoints(image_uv, K_arr, dist_arr).reshape(-1, 2)
        d_camera = np.column_stack([rays, np.ones(len(rays))])
        # Ray λ d meets the board plane z_board = 0: R^T (λ d - t) has zero z.
        R, t = X[:3, :3], X[:3, 3]
        d_board = d_camera @ R
        t_board = R.T @ t
        with np.errstate(divide="ignore"):
            lam = t_board[2] / d_board[:, 2]
        p_board = lam[:, None] * d_board - t_board
        map_x = (p_board[:, 0] * ppm + offset).reshape(height, width).astype(np.float32)
        map_y = (p_board[:, 1] * ppm + offset).reshape(height, width).astype(np.float32)
        off_board = ~np.isfinite(lam) | (lam <= 0)
        map_x[off_board.reshape(height, width)] = -1e6
        big = cv2.remap(
            board_picture,
            cv2.resize(map_x, big_size, interpolation=cv2.INTER_LINEAR),
            cv2.resize(map_y, big_size, interpolation=cv2.INTER_LINEAR),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=params.background,
        )
    image = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA).astype(np.float64)
    if params.blur_sigma_px > 0:
        image = np.asarray(cv2.GaussianBlur(image, (0, 0), params.blur_sigma_px), dtype=np.float64)
    image += rng.normal(0.0, params.noise_sigma, image.shape)
    return np.asarray(np.clip(np.rint(image), 0, 255), dtype=np.uint8)
