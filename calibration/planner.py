"""Robot poses for a hand-eye calibration run: well spread, reachable, deterministic for a seed.

The views are generated relative to the board, as camera poses ``X_board_camera`` on a spherical cap
on the board's front side (the side a camera reading the print is on, i.e. negative board z):

- stand-off distance ``standoff_m`` (± ``standoff_jitter_m``) from the board centre,
- tilt (angle between the optical axis and the board normal) between ``min_tilt_rad`` and
  ``max_tilt_rad``, stratified so small and large tilts both occur,
- azimuth around the board normal on a golden-angle sequence (evenly spread for any count),
- roll about the optical axis within ± ``max_roll_rad``, so the relative rotations turn about
  different axes (tilts alone give axes in the board plane; roll adds the normal),
- the optical axis aimed at the board centre ± ``aim_jitter_m``.

Eye-in-hand: ``X_base_tool = X_base_board @ X_board_camera @ inv(X_tool_camera)``.
Eye-to-hand: ``X_base_tool = X_base_camera @ inv(X_board_camera) @ inv(X_tool_board)``.

Candidates whose tool position leaves the reach sphere or the workspace box, whose board would not
fit in the image (when ``K`` and ``image_size`` are given), or that nearly repeat an accepted
orientation are skipped. The accepted poses are returned ordered by azimuth to keep robot travel short.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board import CharucoBoardSpec
from calibration.errors import CalibrationError
from perception.transforms import check_X, invert_X, look_at_X, make_X, rotation_angle_rad

FloatArray = NDArray[np.float64]

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


@dataclass(frozen=True)
class Workspace:
    """Where the tool frame origin may go, in the base frame, metres.

    Inside the sphere of ``reach_radius_m`` around ``reach_center_base`` (e.g. the shoulder joint),
    outside the sphere of ``min_radius_m`` around the same centre (the robot's own body), and inside
    the axis-aligned box ``box_min_base`` .. ``box_max_base`` when given.
    """

    reach_center_base: tuple[float, float, float]
    reach_radius_m: float
    min_radius_m: float = 0.0
    box_min_base: tuple[float, float, float] | None = None
    box_max_base: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_radius_m < self.reach_radius_m:
            raise CalibrationError(
                f"workspace: need 0 <= min_radius_m < reach_radius_m, got {self.min_radius_m} and {self.reach_radius_m}"
            )
        if (self.box_min_base is None) != (self.box_max_base is None):
            raise CalibrationError("workspace: give both box corners or neither")
        if (
            self.box_min_base is not None
            and self.box_max_base is not None
            and np.any(np.asarray(self.box_min_base) >= np.asarray(self.box_max_base))
        ):
            raise CalibrationError(f"workspace: box min {self.box_min_base} must be below max {self.box_max_base}")

    def contains(self, p_base: ArrayLike) -> NDArray[np.bool_]:
        """(N,) whether each of the (N, 3) points (base frame, metres) is reachable."""
        p = np.asarray(p_base, dtype=np.float64).reshape(-1, 3)
        r = np.linalg.norm(p - np.asarray(self.reach_center_base), axis=1)
        ok = (r <= self.reach_radius_m) & (r >= self.min_radius_m)
        if self.box_min_base is not None and self.box_max_base is not None:
            lo, hi = np.asarray(self.box_min_base), np.asarray(self.box_max_base)
            ok &= np.all(p >= lo, axis=1) & np.all(p <= hi, axis=1)
        return np.asarray(ok, dtype=np.bool_)


@dataclass(frozen=True)
class PlanParams:
    """How to spread the calibration views (see the module docstring). Metres and radians (the config's
    ``[hand_eye.calibration]`` keys are in degrees, converted once in :mod:`cell.config`);
    ``min_separation_rad`` is the least rotation between any two views."""

    n_poses: int = 15
    standoff_m: float = 0.40
    standoff_jitter_m: float = 0.05
    min_tilt_rad: float = math.radians(10.0)
    max_tilt_rad: float = math.radians(35.0)
    max_roll_rad: float = math.radians(40.0)
    aim_jitter_m: float = 0.02
    min_separation_rad: float = math.radians(5.0)
    image_margin_px: float = 20.0
    max_candidates: int = 5000

    def __post_init__(self) -> None:
        if self.n_poses < 3:
            raise CalibrationError(f"plan: need at least 3 poses (8+ recommended), got {self.n_poses}")
        if not 0.0 <= self.min_tilt_rad <= self.max_tilt_rad < math.radians(80.0):
            raise CalibrationError(
                f"plan: need 0 <= min_tilt <= max_tilt < 80 deg, got {math.degrees(self.min_tilt_rad):g} deg, "
                f"{math.degrees(self.max_tilt_rad):g} deg"
            )
        if self.standoff_m <= 0 or not 0.0 <= self.standoff_jitter_m < self.standoff_m:
            raise CalibrationError(
                f"plan: need standoff_m > standoff_jitter_m >= 0, got {self.standoff_m}, {self.standoff_jitter_m}"
            )
        if not 0.0 <= self.max_roll_rad <= math.pi:
            raise CalibrationError(
                f"plan: max_roll must be in [0, 180] deg, got {math.degrees(self.max_roll_rad):g} deg"
            )


def board_view_poses(board: CharucoBoardSpec, *, params: PlanParams, seed: int) -> Iterator[FloatArray]:
    """Up to ``params.max_candidates`` candidate ``X_board_camera`` poses, generated lazily.

    Deterministic for ``seed``. The camera looks at the board's printed face (from negative board z).
    """
    rng = np.random.default_rng(seed)
    width_m, height_m = board.size_m
    center_board = np.array([width_m / 2.0, height_m / 2.0, 0.0])
    cos_min = np.cos(params.min_tilt_rad)
    cos_max = np.cos(params.max_tilt_rad)
    azimuth0 = rng.uniform(0.0, 2.0 * np.pi)
    for k in range(params.max_candidates):
        azimuth = azimuth0 + k * _GOLDEN_ANGLE + rng.normal(0.0, 0.1)
        # Stratified in cos(tilt) (area-uniform on the cap), with the fraction on a low-discrepancy sequence.
        frac = ((k + 0.5) * 0.6180339887498949 + rng.uniform(-0.1, 0.1)) % 1.0
        tilt = np.arccos(cos_min + (cos_max - cos_min) * frac)
        standoff = params.standoff_m + rng.uniform(-1.0, 1.0) * params.standoff_jitter_m
        direction = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
        aim = center_board + np.array([*rng.uniform(-1.0, 1.0, 2) * params.aim_jitter_m, 0.0])
        eye = center_board + standoff * direction
        # "Up" in the image is the board's -y (the top of the print), then the roll.
        X_board_camera = look_at_X(eye, aim, up=(0.0, -1.0, 0.0))
        roll = rng.uniform(-params.max_roll_rad, params.max_roll_rad)
        c, s = np.cos(roll), np.sin(roll)
        yield X_board_camera @ make_X([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], np.zeros(3))


def plan_eye_in_hand(
    board: CharucoBoardSpec,
    *,
    X_base_board: ArrayLike,
    X_tool_camera: ArrayLike,
    workspace: Workspace,
    params: PlanParams | None = None,
    seed: int = 0,
    K: ArrayLike | None = None,
    image_size: tuple[int, int] | None = None,
) -> list[FloatArray]:
    """``params.n_poses`` (4, 4) ``X_base_tool`` for a camera on the tool looking at a fixed board.

    ``X_base_board``, ``X_tool_camera``: nominal (CAD) poses, metres; the plan tolerates errors of a
    few millimetres and degrees in them. ``K`` (3, 3) and ``image_size`` (width, height) in pixels,
    when given, keep the board's outline inside the image by ``params.image_margin_px`` (pinhole
    model; leave a margin for lens distortion). Raises CalibrationError when not enough
    candidates are reachable, naming how many were.
    """
    p = params or PlanParams()
    X_bb = check_X(X_base_board, name="X_base_board")
    X_tool_camera_inv = invert_X(check_X(X_tool_camera, name="X_tool_camera"))
    return _select(
        board,
        p,
        seed,
        workspace,
        lambda X_board_camera: X_bb @ X_board_camera @ X_tool_camera_inv,
        K,
        image_size,
    )


def plan_eye_to_hand(
    board: CharucoBoardSpec,
    *,
    X_base_camera: ArrayLike,
    X_tool_board: ArrayLike,
    workspace: Workspace,
    params: PlanParams | None = None,
    seed: int = 0,
    K: ArrayLike | None = None,
    image_size: tuple[int, int] | None = None,
) -> list[FloatArray]:
    """``params.n_poses`` (4, 4) ``X_base_tool`` presenting a tool-mounted board to a fixed camera.

    Same view geometry as :func:`plan_eye_in_hand`, seen from the camera: the board is held at the
    stand-off in front of the camera, tilted and rolled.
    """
    p = params or PlanParams()
    X_bc = check_X(X_base_camera, name="X_base_camera")
    X_tool_board_inv = invert_X(check_X(X_tool_board, name="X_tool_board"))
    return _select(
        board,
        p,
        seed,
        workspace,
        lambda X_board_camera: X_bc @ invert_X(X_board_camera) @ X_tool_board_inv,
        K,
        image_size,
    )


def _select(
    board: CharucoBoardSpec,
    params: PlanParams,
    seed: int,
    workspace: Workspace,
    to_base_tool: Callable[[FloatArray], FloatArray],
    K: ArrayLike | None,
    image_size: tuple[int, int] | None,
) -> list[FloatArray]:
    if (K is None) != (image_size is None):
        raise CalibrationError("plan: give K and image_size together (or neither)")
    outline_board = _board_outline(board)
    chosen: list[tuple[float, FloatArray, FloatArray]] = []  # (azimuth, X_board_camera, X_base_tool)
    reachable = 0
    for X_board_camera in board_view_poses(board, params=params, seed=seed):
        X_base_tool = to_base_tool(X_board_camera)
        if not workspace.contains(X_base_tool[:3, 3])[0]:
            continue
        reachable += 1
        if (
            K is not None
            and image_size is not None
            and not _outline_in_image(outline_board, X_board_camera, K, image_size, params.image_margin_px)
        ):
            continue
        min_sep = params.min_separation_rad
        if any(rotation_angle_rad(X_board_camera, other) < min_sep for _, other, _ in chosen):
            continue
        to_camera = X_board_camera[:3, 3] - np.array([*np.asarray(board.size_m) / 2.0, 0.0])
        chosen.append((float(np.arctan2(to_camera[1], to_camera[0])), X_board_camera, X_base_tool))
        if len(chosen) == params.n_poses:
            chosen.sort(key=lambda item: item[0])
            return [item[2] for item in chosen]
    raise CalibrationError(
        f"plan: found only {len(chosen)} of {params.n_poses} usable poses among {params.max_candidates} candidates "
        f"({reachable} reachable); widen the workspace, move the board closer to the robot, or relax the tilt limits"
    )


def _board_outline(board: CharucoBoardSpec) -> FloatArray:
    """(4, 3) outer corners of the board's chessboard, board frame, metres."""
    w, h = board.size_m
    return np.array([[0.0, 0.0, 0.0], [w, 0.0, 0.0], [w, h, 0.0], [0.0, h, 0.0]])


def _outline_in_image(
    outline_board: FloatArray,
    X_board_camera: FloatArray,
    K: ArrayLike,
    image_size: tuple[int, int],
    margin_px: float,
) -> bool:
    X_camera_board = invert_X(X_board_camera)
    p_camera = outline_board @ X_camera_board[:3, :3].T + X_camera_board[:3, 3]
    if np.any(p_camera[:, 2] <= 0.0):
        return False
    uv = (p_camera @ np.asarray(K, dtype=np.float64).T)[:, :2] / p_camera[:, 2:3]
    width, height = image_size
    return bool(
        np.all(uv[:, 0] >= margin_px)
        and np.all(uv[:, 0] <= width - 1 - margin_px)
        and np.all(uv[:, 1] >= margin_px)
        and np.all(uv[:, 1] <= height - 1 - margin_px)
    )
