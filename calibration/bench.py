"""Hand-eye accuracy benchmark on synthetic data with known truth.

A trial: draw a true camera mount and board pose (a few mm and degrees away from the nominal CAD
values the planner is given), plan N eye-in-hand poses, simulate the views with realistic noise
(corner noise, robot repeatability), measure each board pose by PnP from the noisy corners (or, handed a
renderer, render the images and run the real detector), solve, and compare every
closed-form method and the refined result with the truth. The report holds medians over trials.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from calibration.axxb import LinearMethod
from calibration.board import CharucoBoardSpec, detect_board, solve_board_pose
from calibration.errors import CalibrationError
from calibration.handeye import REFINED, HandEyeResult, solve_hand_eye
from calibration.planner import PlanParams, Workspace, plan_eye_in_hand
from calibration.simulate import ViewRenderer, perturb_pose, simulate_views
from perception.transforms import make_X, rotation_angle_rad

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

METHODS: tuple[str, ...] = (REFINED, *(m.value for m in LinearMethod))

# Report: {"15": {"refined": {"translation_mm": 0.14, "rotation_deg": 0.028}, "tsai": {...}, ...}, ...}
Report = dict[str, dict[str, dict[str, float | None]]]


@dataclass(frozen=True)
class BenchScene:
    """The simulated cell: a 9x6 ChArUco board (30 mm squares) flat on the table 0.6 m in front of the
    robot, a 1280x800 camera (fx = fy = 1000 px) on the tool, a UR-sized reach sphere.

    ``X_tool_camera_nominal`` / ``X_base_board_nominal``: what the planner is told (CAD), metres.
    ``mount_sigma_m`` / ``mount_sigma_rad``: per-axis spread of the true poses around them.
    """

    board: CharucoBoardSpec = field(
        default_factory=lambda: CharucoBoardSpec(squares_x=9, squares_y=6, square_length_m=0.030, marker_length_m=0.022)
    )
    K: FloatArray = field(default_factory=lambda: np.array([[1000.0, 0.0, 639.5], [0.0, 1000.0, 399.5], [0, 0, 1]]))
    image_size: tuple[int, int] = (1280, 800)
    workspace: Workspace = field(
        default_factory=lambda: Workspace(
            reach_center_base=(0.0, 0.0, 0.163),
            reach_radius_m=0.85,
            min_radius_m=0.25,
            box_min_base=(0.1, -0.6, 0.05),
            box_max_base=(1.0, 0.6, 0.9),
        )
    )
    X_tool_camera_nominal: FloatArray = field(
        default_factory=lambda: make_X(Rotation.from_euler("z", 90, degrees=True).as_matrix(), [0.06, -0.03, 0.08])
    )
    # Board face up on the table (board z points down into it), centred at (0.6, 0, 0).
    X_base_board_nominal: FloatArray = field(
        default_factory=lambda: make_X(np.diag([1.0, -1.0, -1.0]), [0.6 - 0.135, 0.09, 0.0])
    )
    mount_sigma_m: float = 0.003
    mount_sigma_rad: float = float(np.radians(1.0))


@dataclass(frozen=True)
class BenchConfig:
    """Benchmark settings: pose counts, trials, seed, and the noise (SI units)."""

    pose_counts: tuple[int, ...] = (8, 15, 25)
    trials: int = 20
    seed: int = 0
    corner_sigma_px: float = 0.3
    robot_sigma_m: float = 0.05e-3
    robot_sigma_rad: float = 1e-4  # the 0.05 mm seen over a 0.5 m lever

    def __post_init__(self) -> None:
        if self.trials < 1:
            raise CalibrationError(f"bench: trials must be >= 1, got {self.trials}")
        if not self.pose_counts or min(self.pose_counts) < 3:
            raise CalibrationError(f"bench: pose counts must be >= 3, got {self.pose_counts}")


@dataclass(frozen=True)
class TrialErrors:
    """Errors of one trial against the truth, per method: (translation metres, rotation radians);
    NaN when that method failed."""

    n_poses: int
    errors: dict[str, tuple[float, float]]


def run_trial(
    n_poses: int,
    trial: int,
    *,
    config: BenchConfig,
    scene: BenchScene | None = None,
    render: ViewRenderer | None = None,
) -> TrialErrors:
    """One trial with ``n_poses`` planned poses; deterministic for (config.seed, n_poses, trial). With ``render``
    (``sim_fakes.board_render.BoardRenderer()``) every view's image is rendered and the board detector measures
    it (the corners then carry the image's noise, not ``config.corner_sigma_px``)."""
    sc = scene or BenchScene()
    rng = np.random.default_rng([config.seed, n_poses, trial])
    X_tool_camera = perturb_pose(
        sc.X_tool_camera_nominal, sigma_m=sc.mount_sigma_m, sigma_rad=sc.mount_sigma_rad, rng=rng
    )
    X_base_board = perturb_pose(
        sc.X_base_board_nominal, sigma_m=sc.mount_sigma_m, sigma_rad=sc.mount_sigma_rad, rng=rng
    )
    plan = plan_eye_in_hand(
        sc.board,
        X_base_board=sc.X_base_board_nominal,
        X_tool_camera=sc.X_tool_camera_nominal,
        workspace=sc.workspace,
        params=PlanParams(n_poses=n_poses),
        seed=int(rng.integers(2**31)),
        K=sc.K,
        image_size=sc.image_size,
    )
    views = simulate_views(
        plan,
        board=sc.board,
        K=sc.K,
        image_size=sc.image_size,
        X_tool_camera=X_tool_camera,
        X_base_board=X_base_board,
        corner_sigma_px=0.0 if render is not None else config.corner_sigma_px,
        robot_sigma_m=config.robot_sigma_m,
        robot_sigma_rad=config.robot_sigma_rad,
        seed=int(rng.integers(2**31)),
        render=render,
    )
    X_base_tool = [v.X_base_tool for v in views]
    if render is not None:
        observations = []
        for v in views:
            assert v.image is not None
            observations.append(detect_board(v.image, board=sc.board, K=sc.K))
        X_camera_board = [o.X_camera_board for o in observations]
        corners_px = [o.corners_px for o in observations]
        corners_board = [o.corners_board for o in observations]
    else:
        X_camera_board = [solve_board_pose(v.corners_board, v.corners_px, K=sc.K)[0] for v in views]
        corners_px = [v.corners_px for v in views]
        corners_board = [v.corners_board for v in views]
    result = solve_hand_eye(X_base_tool, X_camera_board, corners_px=corners_px, corners_board=corners_board, K=sc.K)
    errors = {REFINED: _errors(result, X_tool_camera)}
    for method in LinearMethod:
        try:
            errors[method.value] = _errors(result.linear_result(method), X_tool_camera)
        except CalibrationError:
            errors[method.value] = (float("nan"), float("nan"))
    return TrialErrors(n_poses=n_poses, errors=errors)


def _errors(result: HandEyeResult, X_tool_camera_true: FloatArray) -> tuple[float, float]:
    assert result.X_tool_camera is not None
    translation_m = float(np.linalg.norm(result.X_tool_camera[:3, 3] - X_tool_camera_true[:3, 3]))
    return translation_m, rotation_angle_rad(result.X_tool_camera, X_tool_camera_true)


def run_bench(
    config: BenchConfig,
    *,
    scene: BenchScene | None = None,
    on_trial: Callable[[TrialErrors], None] | None = None,
    render: ViewRenderer | None = None,
) -> Report:
    """Medians over ``config.trials`` trials for each pose count and method, in mm and degrees
    (the report is for people and JSON readers). ``on_trial`` is called after every trial; ``render``: as in
    :func:`run_trial`."""
    report: Report = {}
    for n in config.pose_counts:
        trials = []
        for t in range(config.trials):
            res = run_trial(n, t, config=config, scene=scene, render=render)
            trials.append(res)
            if on_trial is not None:
                on_trial(res)
        per_method: dict[str, dict[str, float | None]] = {}
        for method in METHODS:
            errs = np.array([tr.errors[method] for tr in trials])
            ok = np.all(np.isfinite(errs), axis=1)
            if not np.any(ok):
                per_method[method] = {"translation_mm": None, "rotation_deg": None}
                continue
            per_method[method] = {
                "translation_mm": round(float(np.median(errs[ok, 0])) * 1000.0, 4),
                "rotation_deg": round(float(np.degrees(np.median(errs[ok, 1]))), 5),
            }
            if not np.all(ok):
                logger.warning("bench: %s failed in %d of %d trials with %d poses", method, (~ok).sum(), len(ok), n)
        report[str(n)] = per_method
    return report


def target_failures(
    report: Report, *, n_poses: int = 15, max_translation_mm: float = 0.5, max_rotation_deg: float = 0.05
) -> list[str]:
    """Why the report misses the target (empty when it meets it): with ``n_poses`` poses the refined
    result lies within the limits and beats every closed-form method in translation and rotation."""
    key = str(n_poses)
    if key not in report:
        return [f"no result for {n_poses} poses"]
    refined = report[key][REFINED]
    t_mm, r_deg = refined["translation_mm"], refined["rotation_deg"]
    if t_mm is None or r_deg is None:
        return ["refined result missing"]
    problems = []
    if t_mm > max_translation_mm:
        problems.append(f"refined translation {t_mm:.3f} mm > {max_translation_mm} mm")
    if r_deg > max_rotation_deg:
        problems.append(f"refined rotation {r_deg:.4f} deg > {max_rotation_deg} deg")
    for method, errs in report[key].items():
        if method == REFINED or errs["translation_mm"] is None or errs["rotation_deg"] is None:
            continue
        if errs["translation_mm"] <= t_mm or errs["rotation_deg"] <= r_deg:
            problems.append(
                f"{method} ({errs['translation_mm']:.3f} mm, {errs['rotation_deg']:.4f} deg) is not worse than refined"
            )
    return problems
