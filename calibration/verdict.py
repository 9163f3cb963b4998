"""Checking a hand-eye solution: where it puts the board, how it fares at a pose it was not solved from, and the
verdict (``pass`` / ``marginal`` / ``fail``) its residuals earn. Pure functions on arrays and value types."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board import BoardObservation
from calibration.errors import CalibrationError
from calibration.handeye import HandEyeMode, HandEyeResult
from perception.capture import CameraIntrinsics
from perception.transforms import invert_X, rotation_angle_rad

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class VerdictThresholds:
    """Limits of the verdict; each quantity is compared with its ``pass_*`` and ``fail_*`` limit.

    ``rms_px``: RMS reprojection error of all corners of all views with the robot poses as reported, pixels.
    ``worst_view_px``: the largest per-view RMS, pixels. ``rms_mm`` / ``rms_deg``: RMS over views of the
    distance / angle between the board pose the camera measured and the one the solution predicts.
    ``holdout_rms_px``: RMS distance between the corners seen at the held-out pose and where the solution
    predicts them, pixels. Verdict: ``fail`` when any quantity exceeds its ``fail_*`` limit, ``marginal`` when
    any exceeds its ``pass_*`` limit, else ``pass``. The pixel limits assume ~0.4-0.8 mm per pixel at the board
    (a 640-1280 px wide image 0.3-0.4 m away); see docs/calibration.md for the reasoning.
    """

    pass_rms_px: float = 1.0
    fail_rms_px: float = 2.0
    pass_worst_view_px: float = 2.0
    fail_worst_view_px: float = 4.0
    pass_rms_mm: float = 1.0
    fail_rms_mm: float = 3.0
    pass_rms_deg: float = 0.3
    fail_rms_deg: float = 1.0
    pass_holdout_rms_px: float = 1.5
    fail_holdout_rms_px: float = 3.0

    def __post_init__(self) -> None:
        for name in ("rms_px", "worst_view_px", "rms_mm", "rms_deg", "holdout_rms_px"):
            ok, bad = getattr(self, f"pass_{name}"), getattr(self, f"fail_{name}")
            if not 0.0 < ok <= bad:
                raise CalibrationError(f"verdict thresholds: need 0 < pass_{name} <= fail_{name}, got {ok}, {bad}")


@dataclass(frozen=True)
class Verification:
    """The solution checked at a pose it was not solved from.

    ``X_base_tool``: (4, 4) the held-out pose. ``n_corners``: corners seen there. ``rms_px`` / ``max_px``:
    RMS and largest distance between the seen corners and where the solved transforms put them, pixels.
    ``translation_mm`` / ``rotation_deg``: the board pose measured there (PnP) against the predicted one.
    """

    X_base_tool: FloatArray
    n_corners: int
    rms_px: float
    max_px: float
    translation_mm: float
    rotation_deg: float


class Verdict(StrEnum):
    PASS = "pass"
    MARGINAL = "marginal"
    FAIL = "fail"


@dataclass(frozen=True)
class Assessment:
    """The verdict and, for each quantity over its ``pass_*`` limit, one line saying which and by how much."""

    verdict: Verdict
    reasons: tuple[str, ...]


def predict_X_camera_board(
    X_base_tool: ArrayLike, *, mode: HandEyeMode, X_hand_eye: ArrayLike, X_board: ArrayLike
) -> FloatArray:
    """(4, 4) board pose in the camera at tool pose ``X_base_tool`` (4, 4).

    Eye-in-hand: ``X_hand_eye = X_tool_camera``, ``X_board = X_base_board``,
    ``X_camera_board = inv(X_tool_camera) @ inv(X_base_tool) @ X_base_board``.
    Eye-to-hand: ``X_hand_eye = X_base_camera``, ``X_board = X_tool_board``,
    ``X_camera_board = inv(X_base_camera) @ X_base_tool @ X_tool_board``.
    """
    T = np.asarray(X_base_tool, dtype=np.float64)
    if HandEyeMode(mode) is HandEyeMode.EYE_IN_HAND:
        return invert_X(X_hand_eye) @ invert_X(T) @ np.asarray(X_board, dtype=np.float64)
    return invert_X(X_hand_eye) @ T @ np.asarray(X_board, dtype=np.float64)


def verify(
    observation: BoardObservation,
    X_base_tool: ArrayLike,
    result: HandEyeResult,
    intrinsics: CameraIntrinsics,
) -> Verification:
    """Compare the corners of ``observation`` (seen at tool pose ``X_base_tool``, (4, 4)) with where ``result``
    puts them: the board pose its transforms predict, projected with ``intrinsics``."""
    X_hand_eye, X_board = solved_transforms(result)
    X_cb = predict_X_camera_board(X_base_tool, mode=result.mode, X_hand_eye=X_hand_eye, X_board=X_board)
    p_camera = observation.corners_board @ X_cb[:3, :3].T + X_cb[:3, 3]
    if np.any(p_camera[:, 2] <= 0):
        raise CalibrationError("verification: the solution puts the board behind the camera at the held-out pose")
    err = np.linalg.norm(intrinsics.project(p_camera) - observation.corners_px, axis=1)
    seen = observation.X_camera_board
    return Verification(
        X_base_tool=np.asarray(X_base_tool, dtype=np.float64),
        n_corners=observation.n_corners,
        rms_px=float(np.sqrt(np.mean(err**2))),
        max_px=float(np.max(err)),
        translation_mm=float(np.linalg.norm(seen[:3, 3] - X_cb[:3, 3])) * 1000.0,
        rotation_deg=float(np.degrees(rotation_angle_rad(seen, X_cb))),
    )


def solved_transforms(result: HandEyeResult) -> tuple[FloatArray, FloatArray]:
    """(hand-eye transform, board pose) of ``result``: (X_tool_camera, X_base_board) for eye-in-hand,
    (X_base_camera, X_tool_board) for eye-to-hand."""
    if result.mode is HandEyeMode.EYE_IN_HAND:
        X, Y = result.X_tool_camera, result.X_base_board
    else:
        X, Y = result.X_base_camera, result.X_tool_board
    assert X is not None and Y is not None
    return X, Y


def assess(result: HandEyeResult, verification: Verification, thresholds: VerdictThresholds) -> Assessment:
    """The verdict of a solution and its verification (see :class:`VerdictThresholds`)."""
    assert result.view_residuals_px is not None and result.rms_px is not None
    quantities = (
        ("RMS reprojection", result.rms_px, "px", "rms_px"),
        ("worst view", float(np.max(result.view_residuals_px)), "px", "worst_view_px"),
        ("RMS board position", result.rms_mm, "mm", "rms_mm"),
        ("RMS board orientation", result.rms_deg, "deg", "rms_deg"),
        ("held-out view", verification.rms_px, "px", "holdout_rms_px"),
    )
    verdict = Verdict.PASS
    reasons = []
    for label, value, unit, key in quantities:
        ok, bad = getattr(thresholds, f"pass_{key}"), getattr(thresholds, f"fail_{key}")
        if value > bad:
            verdict = Verdict.FAIL
            reasons.append(f"{label} {value:.3g} {unit} > {bad:g} {unit} (fail)")
        elif value > ok:
            verdict = Verdict.MARGINAL if verdict is Verdict.PASS else verdict
            reasons.append(f"{label} {value:.3g} {unit} > {ok:g} {unit} (pass limit)")
    return Assessment(verdict=verdict, reasons=tuple(reasons))
