"""Synthetic hand-eye calibration data with known truth (for the benchmark and the tests).

Given the true hand-eye transform and board pose, a camera and a pose plan, each view gets:

- the pose the robot reports, ``X_base_tool`` (the plan), and the pose it really reached,
  ``X_base_tool_true`` = the plan perturbed by repeatability noise (``robot_sigma_m`` per axis,
  ``robot_sigma_rad`` per axis as a rotation vector);
- the true ``X_camera_board`` from the real pose;
- the ChArUco corners inside the image, projected with the camera model, plus Gaussian pixel noise
  (``corner_sigma_px`` per coordinate);
- optionally a rendered 8-bit image, drawn by the :class:`ViewRenderer` the caller hands in (the simulator's
  ``sim_fakes.board_render.BoardRenderer``: the board picture warped into the camera, supersampled, lens blur
  and sensor noise), for exercising :func:`calibration.board.detect_board`.

Everything random comes from ``seed``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from calibration.board import CharucoBoardSpec
from calibration.errors import CalibrationError
from calibration.handeye import HandEyeMode
from perception.transforms import check_X, invert_X, make_X

FloatArray = NDArray[np.float64]


class ViewRenderer(Protocol):
    """Draws a simulated view's (H, W) uint8 image of ``board`` lying at ``X_camera_board`` (4, 4, metres), sensor
    noise drawn from ``rng``. The simulator's ``sim_fakes.board_render.BoardRenderer`` is one; the caller hands it
    in, so calibration imports nothing of sim_fakes."""

    def __call__(
        self,
        board: CharucoBoardSpec,
        X_camera_board: FloatArray,
        *,
        K: FloatArray,
        image_size: tuple[int, int],
        rng: np.random.Generator,
        dist: FloatArray | None = None,
    ) -> NDArray[np.uint8]: ...


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
    render: ViewRenderer | None = None,
    min_corners: int = 6,
) -> list[SimulatedView]:
    """Synthesize one :class:`SimulatedView` per planned pose.

    Eye-in-hand needs the truths ``X_tool_camera`` and ``X_base_board``; eye-to-hand ``X_base_camera``
    and ``X_tool_board`` (all (4, 4), metres). ``K``: (3, 3); ``image_size``: (width, height) pixels;
    ``dist``: OpenCV distortion coefficients. ``render``: also draw an image of each view with it.
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
        if render is not None:
            image = render(board, X_cb, K=K_arr, dist=dist_arr, image_size=image_size, rng=rng)
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
