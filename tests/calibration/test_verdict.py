"""calibration.verdict: where a solution puts the board, the held-out check and the verdict, on exact cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.board import BoardObservation
from calibration.errors import CalibrationError
from calibration.handeye import HandEyeMode, HandEyeResult
from calibration.verdict import Verdict, VerdictThresholds, Verification, assess, predict_X_camera_board, verify
from perception.capture import CameraIntrinsics
from perception.transforms import invert_X, make_X


# ---------------------------------------------------------------------------------------------- verdict, file
def _result(px: float, mm: float, deg: float, n: int = 8) -> HandEyeResult:
    return HandEyeResult(
        mode=HandEyeMode.EYE_IN_HAND,
        method="refined",
        view_residuals_px=np.full(n, px),
        rms_px=px,
        view_residuals_mm=np.full(n, mm),
        view_residuals_deg=np.full(n, deg),
        X_tool_camera=np.eye(4),
        X_base_board=np.eye(4),
    )


def _verification(px: float) -> Verification:
    return Verification(np.eye(4), 40, px, 2 * px, 0.1, 0.01)


def test_verdict_thresholds() -> None:
    t = VerdictThresholds()
    assert assess(_result(0.2, 0.3, 0.05), _verification(0.3), t).verdict is Verdict.PASS
    marginal = assess(_result(1.2, 0.3, 0.05), _verification(0.3), t)
    assert marginal.verdict is Verdict.MARGINAL
    assert marginal.reasons == ("RMS reprojection 1.2 px > 1 px (pass limit)",)
    failed = assess(_result(0.2, 0.3, 0.05), _verification(3.5), t)
    assert failed.verdict is Verdict.FAIL and failed.reasons == ("held-out view 3.5 px > 3 px (fail)",)
    both = assess(_result(0.2, 1.5, 1.2), _verification(0.3), t)
    assert both.verdict is Verdict.FAIL
    assert both.reasons == (
        "RMS board position 1.5 mm > 1 mm (pass limit)",
        "RMS board orientation 1.2 deg > 1 deg (fail)",
    )
    with pytest.raises(CalibrationError, match="pass_rms_px <= fail_rms_px"):
        VerdictThresholds(pass_rms_px=3.0, fail_rms_px=2.0)


X_TOOL_CAMERA = make_X(Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix(), [0.03, -0.04, 0.12])
X_BASE_BOARD = make_X(Rotation.from_euler("x", 180, degrees=True).as_matrix(), [0.6, 0.1, 0.0])
X_BASE_TOOL = make_X(Rotation.from_rotvec([3.0, 0.2, -0.1]).as_matrix(), [0.55, 0.05, 0.42])
K = CameraIntrinsics(width=1280, height=720, fx=900.0, fy=900.0, cx=640.0, cy=360.0)


def test_the_board_is_predicted_through_the_chain_of_frames_in_either_mode() -> None:
    X_cb = predict_X_camera_board(
        X_BASE_TOOL, mode=HandEyeMode.EYE_IN_HAND, X_hand_eye=X_TOOL_CAMERA, X_board=X_BASE_BOARD
    )
    # eye-in-hand: X_base_board = X_base_tool @ X_tool_camera @ X_camera_board
    np.testing.assert_allclose(X_BASE_TOOL @ X_TOOL_CAMERA @ X_cb, X_BASE_BOARD, atol=1e-14)
    X_base_camera, X_tool_board = X_BASE_TOOL @ X_TOOL_CAMERA, invert_X(X_BASE_TOOL) @ X_BASE_BOARD
    X_cb2 = predict_X_camera_board(
        X_BASE_TOOL, mode=HandEyeMode.EYE_TO_HAND, X_hand_eye=X_base_camera, X_board=X_tool_board
    )
    # eye-to-hand: X_base_camera @ X_camera_board = X_base_tool @ X_tool_board
    np.testing.assert_allclose(X_base_camera @ X_cb2, X_BASE_TOOL @ X_tool_board, atol=1e-14)
    np.testing.assert_allclose(X_cb2, X_cb, atol=1e-14)


def _observation(X_camera_board: np.ndarray, shift_px: float = 0.0) -> BoardObservation:
    corners_board = np.array([[x, y, 0.0] for x in (0.0, 0.04, 0.08) for y in (0.0, 0.04)])
    p_camera = corners_board @ X_camera_board[:3, :3].T + X_camera_board[:3, 3]
    px = K.project(p_camera) + np.array([shift_px, 0.0])
    return BoardObservation(np.arange(6), px, corners_board, X_camera_board, 0.0)


def test_verify_compares_seen_and_predicted_corners_in_pixels() -> None:
    result = _result(0.2, 0.3, 0.05)
    result = HandEyeResult(
        mode=HandEyeMode.EYE_IN_HAND,
        method="refined",
        view_residuals_px=result.view_residuals_px,
        rms_px=result.rms_px,
        view_residuals_mm=result.view_residuals_mm,
        view_residuals_deg=result.view_residuals_deg,
        X_tool_camera=X_TOOL_CAMERA,
        X_base_board=X_BASE_BOARD,
    )
    X_cb = invert_X(X_BASE_TOOL @ X_TOOL_CAMERA) @ X_BASE_BOARD
    exact = verify(_observation(X_cb), X_BASE_TOOL, result, K)
    assert exact.n_corners == 6 and exact.rms_px < 1e-9 and exact.translation_mm < 1e-9
    shifted = verify(_observation(X_cb, shift_px=0.75), X_BASE_TOOL, result, K)
    assert shifted.rms_px == pytest.approx(0.75, abs=1e-9) and shifted.max_px == pytest.approx(0.75, abs=1e-9)
    # the board pose seen 2 mm off along the camera's x: translation error 2 mm, rotation 0
    seen = X_cb.copy()
    seen[0, 3] += 0.002
    moved = verify(BoardObservation(np.arange(6), _observation(X_cb).corners_px, _observation(X_cb).corners_board,
                                    seen, 0.0), X_BASE_TOOL, result, K)  # fmt: skip
    assert moved.translation_mm == pytest.approx(2.0, abs=1e-9) and moved.rotation_deg == pytest.approx(0.0, abs=1e-6)
    # a held-out tool pose at which the solution puts the board 0.5 m behind the camera
    behind = make_X(np.eye(3), [0.0, 0.0, -0.5])
    X_base_tool_behind = X_BASE_BOARD @ invert_X(behind) @ invert_X(X_TOOL_CAMERA)
    with pytest.raises(CalibrationError, match="puts the board behind the camera"):
        verify(_observation(X_cb), X_base_tool_behind, result, K)
