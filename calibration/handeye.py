"""Hand-eye calibration: the closed-form methods, then a joint reprojection refinement.

Two set-ups, one model. With ``H[i]`` the robot pose of view i and ``X_camera_board[i]`` the board pose
the camera measured:

- eye-in-hand (camera on the tool, board fixed): unknowns ``X_tool_camera`` and ``X_base_board``;
  ``X_camera_board[i] = inv(X_tool_camera) @ inv(X_base_tool[i]) @ X_base_board``.
- eye-to-hand (camera fixed, board on the tool): unknowns ``X_base_camera`` and ``X_tool_board``;
  ``X_camera_board[i] = inv(X_base_camera) @ X_base_tool[i] @ X_tool_board``.

Both are ``X_camera_board[i] = inv(X) @ inv(H[i]) @ Y`` with ``H[i] = X_base_tool[i]`` (eye-in-hand)
or ``inv(X_base_tool[i])`` (eye-to-hand), which is also how OpenCV's ``calibrateHandEye`` is fed for
the eye-to-hand case.

Steps: refuse degenerate motion; run the five closed-form methods (:mod:`calibration.axxb`); pick the
one whose (X, Y) reproject the board corners best; refine X and Y jointly with
``scipy.optimize.least_squares`` over all corner reprojections of all views. The reported robot
poses are not exact (repeatability), and the board's lateral position is measured more precisely
than that, so the refinement also estimates a small per-view robot pose correction held by a
Gaussian prior (:class:`RefineParams`); treating the robot as exact would tilt X to absorb the robot
noise. Without corner pixels the refinement minimises the 3D disagreement of board points instead,
robot poses taken as exact.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calibration.axxb import LinearMethod, calibrate_hand_eye_linear, relative_motions, require_opencv_hand_eye
from calibration.board import BoardObservation
from calibration.errors import CalibrationError
from perception.transforms import TransformError, check_X, invert_X, make_X

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

REFINED = "refined"
# Board points whose 3D disagreement is minimised when no corner pixels are given: the origin and
# 0.1 m along each board axis, so rotation and translation errors are weighed at a board's scale.
_POSE_ANCHORS_BOARD = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]])


class HandEyeMode(StrEnum):
    EYE_IN_HAND = "eye_in_hand"  # camera on the tool: solve X_tool_camera (and X_base_board)
    EYE_TO_HAND = "eye_to_hand"  # camera fixed: solve X_base_camera (and X_tool_board)


# The two unknowns of each mode, as HandEyeResult fields: (hand-eye transform, board pose).
_UNKNOWN_NAMES: dict[HandEyeMode, tuple[str, str]] = {
    HandEyeMode.EYE_IN_HAND: ("X_tool_camera", "X_base_board"),
    HandEyeMode.EYE_TO_HAND: ("X_base_camera", "X_tool_board"),
}


@dataclass(frozen=True)
class DegeneracyLimits:
    """When the robot motion cannot determine the hand-eye transform (or barely can).

    ``min_views``: hard minimum (3: two independent motions). ``recommended_views``: fewer only warns.
    ``pure_translation_rad``: below this largest relative rotation the poses are called pure
    translations. ``min_rotation_rad``: the largest relative rotation between any two views must
    reach this. ``min_axis_spread_rad``: the rotation axes of the relative motions must deviate from
    their common direction by at least this. ``max_angle_mismatch_rad``: the rotation angle of each
    robot motion must match the camera's (an invariant of AX = XB); a larger median mismatch means
    the views are mis-paired. Angles in radians (the messages say degrees).

    After solving, the solution must explain the views: the median corner reprojection error must
    stay below ``max_median_px`` (without corner pixels, the median board-position disagreement below
    ``max_median_mm``). A wrong mode, inverted robot poses, millimetres passed as metres or wrong
    intrinsics fail here. Medians, so that a few outlying corners do not.
    """

    min_views: int = 3
    recommended_views: int = 8
    pure_translation_rad: float = math.radians(0.5)
    min_rotation_rad: float = math.radians(5.0)
    min_axis_spread_rad: float = math.radians(5.0)
    max_angle_mismatch_rad: float = math.radians(2.0)
    max_median_px: float = 2.0
    max_median_mm: float = 5.0


@dataclass(frozen=True)
class HandEyeResult:
    """One hand-eye solution and how well it explains the views.

    Eye-in-hand sets ``X_tool_camera`` and ``X_base_board``; eye-to-hand sets ``X_base_camera`` and
    ``X_tool_board``; the other two are None. All (4, 4), metres.

    Per view i (arrays of shape (N,)): ``view_residuals_px`` RMS reprojection error of its corners in
    pixels (None without corner pixels); ``view_residuals_mm`` distance between the measured board
    origin and the one this solution predicts, in millimetres; ``view_residuals_deg`` angle between
    the measured and predicted board orientations, in degrees. ``rms_px`` is the RMS over all corners
    of all views (None without corner pixels); ``rms_mm`` / ``rms_deg`` pool the per-view values.

    ``method``: ``"refined"`` or a :class:`~calibration.axxb.LinearMethod` value. For the refined
    result, ``start_method`` names the closed-form solution it started from, ``linear`` holds every
    closed-form result (each a HandEyeResult, computed by ``cv2.calibrateHandEye``) and ``linear_failures``
    the methods that failed and why.
    """

    mode: HandEyeMode
    method: str
    view_residuals_mm: FloatArray
    view_residuals_deg: FloatArray
    view_residuals_px: FloatArray | None = None
    rms_px: float | None = None
    X_tool_camera: FloatArray | None = None
    X_base_board: FloatArray | None = None
    X_base_camera: FloatArray | None = None
    X_tool_board: FloatArray | None = None
    start_method: str | None = None
    linear: tuple[HandEyeResult, ...] = ()
    linear_failures: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        mode = HandEyeMode(self.mode)
        object.__setattr__(self, "mode", mode)
        wanted = _UNKNOWN_NAMES[mode]
        for name in ("X_tool_camera", "X_base_board", "X_base_camera", "X_tool_board"):
            value = getattr(self, name)
            if name in wanted:
                if value is None:
                    raise CalibrationError(f"HandEyeResult ({mode}): {name} is required")
                object.__setattr__(self, name, check_X(value, name=name))
            elif value is not None:
                raise CalibrationError(f"HandEyeResult ({mode}): {name} belongs to the other mode")
        mm = np.asarray(self.view_residuals_mm, dtype=np.float64).reshape(-1)
        deg = np.asarray(self.view_residuals_deg, dtype=np.float64).reshape(-1)
        if deg.shape != mm.shape:
            raise CalibrationError(f"HandEyeResult: {mm.shape[0]} mm residuals but {deg.shape[0]} deg residuals")
        object.__setattr__(self, "view_residuals_mm", mm)
        object.__setattr__(self, "view_residuals_deg", deg)
        if (self.view_residuals_px is None) != (self.rms_px is None):
            raise CalibrationError("HandEyeResult: view_residuals_px and rms_px come together")
        if self.view_residuals_px is not None and self.rms_px is not None:
            px = np.asarray(self.view_residuals_px, dtype=np.float64).reshape(-1)
            if px.shape != mm.shape:
                raise CalibrationError(f"HandEyeResult: {px.shape[0]} px residuals for {mm.shape[0]} views")
            object.__setattr__(self, "view_residuals_px", px)
            object.__setattr__(self, "rms_px", float(self.rms_px))

    @property
    def n_views(self) -> int:
        return int(self.view_residuals_mm.shape[0])

    @property
    def rms_mm(self) -> float:
        """RMS over views of the board-origin disagreement, millimetres."""
        return float(np.sqrt(np.mean(self.view_residuals_mm**2)))

    @property
    def rms_deg(self) -> float:
        """RMS over views of the board-orientation disagreement, degrees."""
        return float(np.sqrt(np.mean(self.view_residuals_deg**2)))

    def linear_result(self, method: LinearMethod | str) -> HandEyeResult:
        """The closed-form result of ``method`` (CalibrationError if it failed or was not run)."""
        name = LinearMethod(method).value
        for res in self.linear:
            if res.method == name:
                return res
        reasons = dict(self.linear_failures)
        raise CalibrationError(f"no {name} result: {reasons.get(name, 'not run')}")


@dataclass(frozen=True)
class RefineParams:
    """How the joint refinement weighs the data.

    The robot poses are not taken as exact: each view gets a pose correction (translation and
    rotation vector, applied in the base frame) with a zero-mean Gaussian prior of ``robot_sigma_m``
    metres and ``robot_sigma_rad`` radians per axis, weighed against corner noise of
    ``corner_sigma_px`` pixels per coordinate. ``corner_sigma_px=None`` estimates it from the
    per-view PnP residuals (which do not involve the robot). ``robot_sigma_m=None`` takes the robot
    poses as exact. Without corner pixels the robot poses are always taken as exact.

    ``loss``: a ``scipy.optimize.least_squares`` loss (``"linear"``, ``"huber"``, ``"soft_l1"``,
    ``"cauchy"``, ``"arctan"``) on the corner residuals, with inliers up to ``loss_scale_px``.
    """

    robot_sigma_m: float | None = 0.05e-3
    robot_sigma_rad: float = 1e-4
    corner_sigma_px: float | None = None
    loss: str = "linear"
    loss_scale_px: float = 1.0

    def __post_init__(self) -> None:
        if self.robot_sigma_m is not None and (self.robot_sigma_m <= 0 or self.robot_sigma_rad <= 0):
            raise CalibrationError(
                f"robot_sigma_m and robot_sigma_rad must be positive (or robot_sigma_m None for exact poses), "
                f"got {self.robot_sigma_m}, {self.robot_sigma_rad}"
            )
        if self.corner_sigma_px is not None and self.corner_sigma_px <= 0:
            raise CalibrationError(f"corner_sigma_px must be positive or None, got {self.corner_sigma_px}")
        if self.loss not in ("linear", "huber", "soft_l1", "cauchy", "arctan"):
            raise CalibrationError(f"unknown loss {self.loss!r}")
        if self.loss_scale_px <= 0:
            raise CalibrationError(f"loss_scale_px must be positive, got {self.loss_scale_px}")


@dataclass(frozen=True)
class _Problem:
    """Internal arrays of one solve (see the module docstring for H, X, Y)."""

    mode: HandEyeMode
    T: FloatArray  # (N, 4, 4) X_base_tool as reported
    H: FloatArray  # (N, 4, 4) X_base_tool (eye-in-hand) or its inverse (eye-to-hand)
    C: FloatArray  # (N, 4, 4) measured X_camera_board
    corners_px: tuple[FloatArray, ...] | None
    corners_board: tuple[FloatArray, ...] | None
    K: FloatArray | None
    dist: FloatArray


def solve_hand_eye(
    X_base_tool: Sequence[ArrayLike],
    X_camera_board: Sequence[ArrayLike],
    *,
    mode: HandEyeMode | str = HandEyeMode.EYE_IN_HAND,
    corners_px: Sequence[ArrayLike] | None = None,
    corners_board: Sequence[ArrayLike] | None = None,
    K: ArrayLike | None = None,
    dist: ArrayLike | None = None,
    refine: RefineParams | None = None,
    limits: DegeneracyLimits | None = None,
) -> HandEyeResult:
    """Solve the hand-eye transform from N paired views.

    ``X_base_tool``: N (4, 4) robot poses, metres. ``X_camera_board``: N (4, 4) board poses measured by
    the camera, metres. ``corners_px`` / ``corners_board``: optional, per view an (M_i, 2) array of
    observed corner pixels and the (M_i, 3) board-frame points (metres) they image; with them (and
    ``K``, (3, 3), and ``dist``, OpenCV distortion coefficients) the refinement minimises reprojection
    error in pixels, else the 3D disagreement of board points. ``refine``: weights and loss of the
    refinement (:class:`RefineParams`). The closed-form starts come from ``cv2.calibrateHandEye``
    (:func:`calibration.axxb.calibrate_hand_eye_linear`).

    Raises CalibrationError for bad shapes, too few views, or degenerate motion (see
    :class:`DegeneracyLimits`), naming the reason.
    """
    problem = _build_problem(X_base_tool, X_camera_board, mode, corners_px, corners_board, K, dist)
    limits = limits or DegeneracyLimits()
    check_motion(problem.H, problem.C, limits=limits, mode=problem.mode)
    require_opencv_hand_eye()
    params = refine or RefineParams()

    linear: list[HandEyeResult] = []
    failures: list[tuple[str, str]] = []
    start: tuple[float, str, FloatArray, FloatArray] | None = None
    for method in LinearMethod:
        try:
            X = calibrate_hand_eye_linear(problem.H, problem.C, method=method)
            X = check_X(X, name=f"{method.value} solution", tol=1e-6)
        except (CalibrationError, TransformError, cv2.error, np.linalg.LinAlgError) as err:
            failures.append((method.value, str(err).strip().splitlines()[-1]))
            logger.warning("hand-eye %s failed: %s", method.value, err)
            continue
        Y = _fit_Y(problem, X)
        linear.append(_evaluate(problem, X, Y, method=method.value))
        score = _score(problem, X, Y)
        if start is None or score < start[0]:
            start = (score, method.value, X, Y)
    if start is None:
        raise CalibrationError(
            "every closed-form hand-eye method failed: " + "; ".join(f"{m}: {r}" for m, r in failures)
        )
    _, start_method, X0, Y0 = start
    X, Y = _refine(problem, X0, Y0, params=params)
    result = _evaluate(
        problem,
        X,
        Y,
        method=REFINED,
        start_method=start_method,
        linear=tuple(linear),
        linear_failures=tuple(failures),
    )
    _check_solution(problem, X, Y, limits=limits)
    logger.info(
        "hand-eye %s from %d views: start %s, rms %s px, %.3f mm, %.4f deg",
        problem.mode.value,
        result.n_views,
        start_method,
        "n/a" if result.rms_px is None else f"{result.rms_px:.3f}",
        result.rms_mm,
        result.rms_deg,
    )
    return result


def solve_hand_eye_from_observations(
    X_base_tool: Sequence[ArrayLike],
    observations: Sequence[BoardObservation],
    *,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    mode: HandEyeMode | str = HandEyeMode.EYE_IN_HAND,
    refine: RefineParams | None = None,
    limits: DegeneracyLimits | None = None,
) -> HandEyeResult:
    """:func:`solve_hand_eye` fed from :func:`calibration.board.detect_board` results (one per view)."""
    return solve_hand_eye(
        X_base_tool,
        [obs.X_camera_board for obs in observations],
        mode=mode,
        corners_px=[obs.corners_px for obs in observations],
        corners_board=[obs.corners_board for obs in observations],
        K=K,
        dist=dist,
        refine=refine,
        limits=limits,
    )


def _build_problem(
    X_base_tool: Sequence[ArrayLike],
    X_camera_board: Sequence[ArrayLike],
    mode: HandEyeMode | str,
    corners_px: Sequence[ArrayLike] | None,
    corners_board: Sequence[ArrayLike] | None,
    K: ArrayLike | None,
    dist: ArrayLike | None,
) -> _Problem:
    try:
        mode_ = HandEyeMode(mode)
    except ValueError as err:
        raise CalibrationError(f"unknown hand-eye mode {mode!r}; use 'eye_in_hand' or 'eye_to_hand'") from err
    n = len(X_base_tool)
    if len(X_camera_board) != n:
        raise CalibrationError(f"{n} robot poses but {len(X_camera_board)} board poses; pair them one per view")
    try:
        T = np.array([check_X(x, name=f"X_base_tool[{i}]") for i, x in enumerate(X_base_tool)]).reshape(n, 4, 4)
        C = np.array([check_X(x, name=f"X_camera_board[{i}]") for i, x in enumerate(X_camera_board)]).reshape(n, 4, 4)
    except TransformError as err:
        raise CalibrationError(f"invalid pose: {err}") from err
    H = T if mode_ is HandEyeMode.EYE_IN_HAND else np.array([invert_X(x) for x in T]).reshape(n, 4, 4)

    px_views: tuple[FloatArray, ...] | None = None
    board_views: tuple[FloatArray, ...] | None = None
    K_arr: FloatArray | None = None
    if corners_px is not None or corners_board is not None:
        if corners_px is None or corners_board is None or K is None:
            raise CalibrationError("corner refinement needs corners_px, corners_board and K together")
        if len(corners_px) != n or len(corners_board) != n:
            raise CalibrationError(
                f"{n} views but {len(corners_px)} corner-pixel and {len(corners_board)} board-point lists"
            )
        px_list, board_list = [], []
        for i, (px, pb) in enumerate(zip(corners_px, corners_board, strict=True)):
            px_a = np.asarray(px, dtype=np.float64).reshape(-1, 2)
            pb_a = np.asarray(pb, dtype=np.float64).reshape(-1, 3)
            if px_a.shape[0] != pb_a.shape[0] or px_a.shape[0] < 4:
                raise CalibrationError(
                    f"view {i}: {px_a.shape[0]} corner pixels for {pb_a.shape[0]} board points (need equal, >= 4)"
                )
            px_list.append(px_a)
            board_list.append(pb_a)
        px_views, board_views = tuple(px_list), tuple(board_list)
        K_arr = np.asarray(K, dtype=np.float64)
        if K_arr.shape != (3, 3) or not np.all(np.isfinite(K_arr)):
            raise CalibrationError(f"K must be a finite (3, 3) camera matrix, got shape {K_arr.shape}")
    dist_arr = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
    return _Problem(mode_, T, H, C, px_views, board_views, K_arr, dist_arr)


def check_motion(
    H: ArrayLike,
    X_camera_board: ArrayLike,
    *,
    limits: DegeneracyLimits,
    mode: HandEyeMode = HandEyeMode.EYE_IN_HAND,
) -> None:
    """Raise CalibrationError when the views cannot determine the hand-eye transform.

    ``H``: (N, 4, 4) robot poses as the solver uses them (``X_base_tool``, or its inverse for
    eye-to-hand); ``X_camera_board``: (N, 4, 4). Checks, in order: view count, no motion, pure
    translations, too-small rotations, rotations about a single axis, robot/camera rotation-angle
    mismatch.
    """
    H_arr = np.asarray(H, dtype=np.float64)
    C_arr = np.asarray(X_camera_board, dtype=np.float64)
    n = H_arr.shape[0]
    if n < limits.min_views:
        raise CalibrationError(
            f"hand-eye ({mode}) needs at least {limits.min_views} views, got {n}; "
            f"{limits.recommended_views} or more are recommended"
        )
    if n < limits.recommended_views:
        logger.warning("hand-eye from only %d views; %d or more are recommended", n, limits.recommended_views)
    A, B = relative_motions(H_arr, C_arr)
    i_idx, j_idx = np.triu_indices(n, k=1)
    rotvec_A = Rotation.from_matrix(A[:, :3, :3]).as_rotvec()
    angle_A = np.linalg.norm(rotvec_A, axis=1)
    angle_B = Rotation.from_matrix(B[:, :3, :3]).magnitude()
    k_max = int(np.argmax(angle_A))
    max_rad = float(angle_A[k_max])
    max_deg = math.degrees(max_rad)
    min_rotation_deg = math.degrees(limits.min_rotation_rad)
    max_move_mm = float(np.max(np.linalg.norm(A[:, :3, 3], axis=1))) * 1000.0
    if max_rad < limits.pure_translation_rad:
        if max_move_mm < 1.0:
            raise CalibrationError(
                f"all {n} views were taken at the same robot pose (largest move {max_move_mm:.2f} mm, "
                f"{max_deg:.2f} deg); move and rotate the robot between views"
            )
        raise CalibrationError(
            f"pure translations: the robot only translated between views (largest relative rotation "
            f"{max_deg:.2f} deg, largest move {max_move_mm:.0f} mm), so the camera rotation is unobservable; "
            f"rotate the tool by >= {min_rotation_deg:g} deg about at least two different axes"
        )
    if max_rad < limits.min_rotation_rad:
        raise CalibrationError(
            f"relative rotations too small: the largest, between views {i_idx[k_max]} and {j_idx[k_max]}, "
            f"is {max_deg:.2f} deg (< {min_rotation_deg:g} deg); rotate the tool more between views"
        )
    informative = angle_A >= limits.min_rotation_rad
    axes = rotvec_A[informative] / angle_A[informative, None]
    # Principal direction of the axes (sign-free), then the largest deviation from it.
    _, eigvec = np.linalg.eigh(axes.T @ axes)
    principal = eigvec[:, -1]
    spread_rad = float(np.arccos(np.clip(np.min(np.abs(axes @ principal)), 0.0, 1.0)))
    if spread_rad < limits.min_axis_spread_rad:
        raise CalibrationError(
            f"rotations all about a single axis: every relative rotation >= {min_rotation_deg:g} deg "
            f"is within {math.degrees(spread_rad):.2f} deg of the axis {np.round(principal, 3).tolist()}, so the "
            f"translation along it is unobservable; also rotate about an axis at least "
            f"{math.degrees(limits.min_axis_spread_rad):g} deg away"
        )
    median_mismatch_rad = float(np.median(np.abs(angle_A[informative] - angle_B[informative])))
    if median_mismatch_rad > limits.max_angle_mismatch_rad:
        raise CalibrationError(
            f"robot and camera rotations disagree: the median difference of their relative rotation angles is "
            f"{math.degrees(median_mismatch_rad):.2f} deg (> {math.degrees(limits.max_angle_mismatch_rad):g}); "
            "are the robot poses and the board poses paired view by view?"
        )


def _check_solution(problem: _Problem, X: FloatArray, Y: FloatArray, *, limits: DegeneracyLimits) -> None:
    """Raise CalibrationError when the solution does not explain the views (see DegeneracyLimits)."""
    fun = _Residuals(problem, X, Y)
    r = fun(np.zeros(12))
    hint = (
        f"check the mode ({problem.mode.value}), that robot poses are X_base_tool (not inverted) in metres, "
        "and the camera intrinsics"
    )
    if fun.pixels:
        median_px = float(np.median(np.linalg.norm(r.reshape(-1, 2), axis=1)))
        if median_px > limits.max_median_px:
            raise CalibrationError(
                f"the hand-eye solution does not explain the views: median corner reprojection error "
                f"{median_px:.2f} px (> {limits.max_median_px:g} px); {hint}"
            )
    else:
        median_mm = float(np.median(np.linalg.norm(r.reshape(-1, 3), axis=1))) * 1000.0
        if median_mm > limits.max_median_mm:
            raise CalibrationError(
                f"the hand-eye solution does not explain the views: median board-point disagreement "
                f"{median_mm:.2f} mm (> {limits.max_median_mm:g} mm); {hint}"
            )


def _mean_rotation(Rs: FloatArray) -> FloatArray:
    """Chordal L2 mean of (N, 3, 3) rotations."""
    U, _, Vt = np.linalg.svd(Rs.sum(axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return np.asarray(U @ D @ Vt, dtype=np.float64)


def _fit_Y(problem: _Problem, X: FloatArray) -> FloatArray:
    """Second unknown given X: the mean of ``H[i] @ X @ C[i]`` over views."""
    Ys = problem.H @ X @ problem.C
    return make_X(_mean_rotation(Ys[:, :3, :3]), Ys[:, :3, 3].mean(axis=0))


def _predict_C(H_inv: FloatArray, X: FloatArray, Y: FloatArray) -> FloatArray:
    """(N, 4, 4) predicted X_camera_board = inv(X) @ inv(H[i]) @ Y."""
    return invert_X(X) @ H_inv @ Y


def _project(points_camera: FloatArray, K: FloatArray, dist: FloatArray) -> FloatArray:
    """(M, 2) pixels of (M, 3) camera-frame points (OpenCV model)."""
    px, _ = cv2.projectPoints(points_camera.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    return np.asarray(px, dtype=np.float64).reshape(-1, 2)


class _Residuals:
    """Stacked, weighted residuals of all views.

    Parameters: ``[δrot_X, δt_X, δrot_Y, δt_Y]`` about (X0, Y0), then, when ``robot_sigmas`` is given,
    per view ``[δrot_i, δt_i]`` correcting the reported ``X_base_tool[i]`` (base frame). Residuals:
    corner reprojection errors divided by ``sigma_px`` (or, without pixels, 3D board-point errors in
    metres), then the robot corrections divided by their sigmas.
    """

    def __init__(
        self,
        problem: _Problem,
        X0: FloatArray,
        Y0: FloatArray,
        *,
        sigma_px: float = 1.0,
        robot_sigmas: tuple[float, float] | None = None,
    ) -> None:
        self.problem = problem
        self.X0, self.Y0 = X0, Y0
        self.sigma_px = sigma_px
        self.robot_sigmas = robot_sigmas
        self.n_views = problem.T.shape[0]
        self.n_params = 12 + (6 * self.n_views if robot_sigmas is not None else 0)
        if problem.corners_board is not None and problem.corners_px is not None:
            self.view_of_point = np.concatenate([np.full(len(p), i) for i, p in enumerate(problem.corners_board)])
            self.points_board = np.concatenate(problem.corners_board)
            self.observed_px = np.concatenate(problem.corners_px)
            self.pixels = True
        else:
            n = self.n_views
            self.view_of_point = np.repeat(np.arange(n), len(_POSE_ANCHORS_BOARD))
            self.points_board = np.tile(_POSE_ANCHORS_BOARD, (n, 1))
            Cm = problem.C[self.view_of_point]
            self.observed_camera = np.einsum("nij,nj->ni", Cm[:, :3, :3], self.points_board) + Cm[:, :3, 3]
            self.pixels = False

    def unpack(self, p: FloatArray) -> tuple[FloatArray, FloatArray]:
        X = make_X(Rotation.from_rotvec(p[0:3]).as_matrix() @ self.X0[:3, :3], self.X0[:3, 3] + p[3:6])
        Y = make_X(Rotation.from_rotvec(p[6:9]).as_matrix() @ self.Y0[:3, :3], self.Y0[:3, 3] + p[9:12])
        return X, Y

    def _H_inv(self, p: FloatArray) -> FloatArray:
        """(N, 4, 4) inv(H[i]) with the robot corrections of ``p`` applied."""
        T = self.problem.T
        if self.robot_sigmas is not None:
            d = p[12:].reshape(-1, 6)
            T = T.copy()
            T[:, :3, :3] = Rotation.from_rotvec(d[:, :3]).as_matrix() @ T[:, :3, :3]
            T[:, :3, 3] += d[:, 3:]
        if self.problem.mode is HandEyeMode.EYE_TO_HAND:
            return T  # H = inv(X_base_tool)
        return _invert_many(T)

    def __call__(self, p: FloatArray) -> FloatArray:
        X, Y = self.unpack(p)
        Cp = (invert_X(X) @ self._H_inv(p) @ Y)[self.view_of_point]
        pts = np.einsum("nij,nj->ni", Cp[:, :3, :3], self.points_board) + Cp[:, :3, 3]
        if self.pixels:
            assert self.problem.K is not None
            r = ((_project(pts, self.problem.K, self.problem.dist) - self.observed_px) / self.sigma_px).reshape(-1)
        else:
            r = (pts - self.observed_camera).reshape(-1)
        if self.robot_sigmas is None:
            return r
        d = p[12:].reshape(-1, 6)
        prior = np.concatenate([d[:, :3] / self.robot_sigmas[1], d[:, 3:] / self.robot_sigmas[0]], axis=1)
        return np.concatenate([r, prior.reshape(-1)])

    def jacobian(self, p: FloatArray) -> FloatArray:
        """Dense forward-difference Jacobian. The per-view robot parameters of different views touch
        disjoint residuals, so each of their 6 components is perturbed in all views at once."""
        r0 = self(p)
        J = np.zeros((r0.size, p.size))
        step = 1e-7
        for c in range(12):
            q = p.copy()
            q[c] += step
            J[:, c] = (self(q) - r0) / step
        if self.robot_sigmas is not None:
            per_point = 2 if self.pixels else 3
            rows_view = np.repeat(self.view_of_point, per_point)
            prior_view = np.repeat(np.arange(self.n_views), 6)
            row_view = np.concatenate([rows_view, prior_view])
            for c in range(6):
                q = p.copy()
                cols = 12 + 6 * np.arange(self.n_views) + c
                q[cols] += step
                diff = (self(q) - r0) / step
                # Row k belongs to one view; it gets the derivative for that view's column c.
                J[np.arange(r0.size), 12 + 6 * row_view + c] = diff
        return J


def _invert_many(T: FloatArray) -> FloatArray:
    """(N, 4, 4) inverses of rigid transforms."""
    out = np.zeros_like(T)
    Rt = np.transpose(T[:, :3, :3], (0, 2, 1))
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def _corner_sigma_from_pnp(problem: _Problem) -> float:
    """Corner noise per coordinate, pixels, from the per-view fits of the measured board poses:
    sqrt(SSR / (2M - 6)) pooled over views. Floored at 0.01 px (noise-free data)."""
    assert problem.corners_px is not None and problem.corners_board is not None and problem.K is not None
    ssr, dof = 0.0, 0
    for C, px, pb in zip(problem.C, problem.corners_px, problem.corners_board, strict=True):
        pts = pb @ C[:3, :3].T + C[:3, 3]
        ssr += float(np.sum((_project(pts, problem.K, problem.dist) - px) ** 2))
        dof += 2 * len(px) - 6
    return max(float(np.sqrt(ssr / max(dof, 1))), 0.01)


def _refine(
    problem: _Problem, X0: FloatArray, Y0: FloatArray, *, params: RefineParams
) -> tuple[FloatArray, FloatArray]:
    if problem.corners_px is None:
        fun = _Residuals(problem, X0, Y0)
        loss, f_scale = "linear", 1.0
    else:
        sigma_px = params.corner_sigma_px if params.corner_sigma_px is not None else _corner_sigma_from_pnp(problem)
        robot = None if params.robot_sigma_m is None else (params.robot_sigma_m, params.robot_sigma_rad)
        fun = _Residuals(problem, X0, Y0, sigma_px=sigma_px, robot_sigmas=robot)
        # The corner residuals are in units of sigma_px; the robot priors are never large, so the
        # robust loss only matters for outlying corners.
        loss, f_scale = params.loss, params.loss_scale_px / sigma_px
    # Plain least squares goes to MINPACK's Levenberg-Marquardt (its QR needs no threaded BLAS, which
    # made trf's SVD 10x slower on a loaded 2-core box); robust losses need trf.
    method = "lm" if loss == "linear" else "trf"
    options = {} if method == "lm" else {"tr_solver": "exact", "loss": loss, "f_scale": f_scale}
    try:
        sol = least_squares(
            fun,
            np.zeros(fun.n_params),
            jac=lambda q: fun.jacobian(q),
            method=method,
            x_scale="jac",
            ftol=1e-10,
            xtol=1e-10,
            gtol=1e-10,
            max_nfev=100,
            **options,
        )
    except ValueError as err:
        raise CalibrationError(f"hand-eye refinement: {err}") from err
    if not np.all(np.isfinite(sol.x)):
        raise CalibrationError("hand-eye refinement diverged (non-finite parameters)")
    return fun.unpack(sol.x)


def _evaluate(
    problem: _Problem,
    X: FloatArray,
    Y: FloatArray,
    *,
    method: str,
    start_method: str | None = None,
    linear: tuple[HandEyeResult, ...] = (),
    linear_failures: tuple[tuple[str, str], ...] = (),
) -> HandEyeResult:
    H_inv = np.stack([invert_X(h) for h in problem.H])
    C_pred = _predict_C(H_inv, X, Y)
    mm = np.linalg.norm(C_pred[:, :3, 3] - problem.C[:, :3, 3], axis=1) * 1000.0
    rel = np.einsum("nji,njk->nik", C_pred[:, :3, :3], problem.C[:, :3, :3])
    deg = np.degrees(Rotation.from_matrix(rel).magnitude())
    px_view: FloatArray | None = None
    rms_px: float | None = None
    if problem.corners_px is not None and problem.corners_board is not None and problem.K is not None:
        per_view = []
        sq_sum, count = 0.0, 0
        for i, (px, pb) in enumerate(zip(problem.corners_px, problem.corners_board, strict=True)):
            pts = pb @ C_pred[i, :3, :3].T + C_pred[i, :3, 3]
            err2 = np.sum((_project(pts, problem.K, problem.dist) - px) ** 2, axis=1)
            per_view.append(np.sqrt(np.mean(err2)))
            sq_sum += float(err2.sum())
            count += len(px)
        px_view = np.asarray(per_view)
        rms_px = float(np.sqrt(sq_sum / count))
    keys = _UNKNOWN_NAMES[problem.mode]
    transforms = {keys[0]: X, keys[1]: Y}
    return HandEyeResult(
        mode=problem.mode,
        method=method,
        view_residuals_mm=mm,
        view_residuals_deg=deg,
        view_residuals_px=px_view,
        rms_px=rms_px,
        start_method=start_method,
        linear=linear,
        linear_failures=linear_failures,
        **transforms,
    )


def _score(problem: _Problem, X: FloatArray, Y: FloatArray) -> float:
    """RMS per coordinate of the reprojection residuals at (X, Y) with the robot poses as reported
    (pixels), or of the 3D board-point residuals without corner pixels (metres)."""
    r = _Residuals(problem, X, Y)(np.zeros(12))
    return float(np.sqrt(np.mean(r**2)))
