"""calibration.axxb: the numpy port of cv2.calibrateHandEye against values recorded from OpenCV."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.axxb import LinearMethod, calibrate_hand_eye_linear, opencv_has_hand_eye, relative_motions
from calibration.errors import CalibrationError
from perception.transforms import invert_X, make_X

REFERENCE = json.loads((Path(__file__).parent / "data" / "opencv_handeye_reference.json").read_text())


def test_reference_data_exercises_the_hard_cases():
    A, _ = relative_motions(np.array(REFERENCE["X_base_tool"]), np.array(REFERENCE["X_camera_board"]))
    angles = np.degrees(Rotation.from_matrix(A[:, :3, :3]).magnitude())
    assert angles.max() > 170  # quaternion sign handling
    assert angles.min() < 17  # Tsai's pair filter


@pytest.mark.parametrize("method", list(LinearMethod), ids=lambda m: m.value)
def test_numpy_port_matches_opencv_412(method):
    X = calibrate_hand_eye_linear(REFERENCE["X_base_tool"], REFERENCE["X_camera_board"], method=method, backend="numpy")
    expected = np.array(REFERENCE["X_tool_camera_by_method"][method.value])
    np.testing.assert_allclose(X, expected, atol=1e-12)
    # The methods differ from each other on noisy data, so matching is not an accident of the truth.
    others = [np.array(v) for k, v in REFERENCE["X_tool_camera_by_method"].items() if k != method.value]
    assert min(np.abs(X - o).max() for o in others) > 1e-6


@pytest.mark.skipif(not opencv_has_hand_eye(), reason="this cv2 build does not expose calibrateHandEye")
@pytest.mark.parametrize("method", list(LinearMethod), ids=lambda m: m.value)
def test_numpy_port_matches_the_installed_opencv(method):
    args = (REFERENCE["X_base_tool"], REFERENCE["X_camera_board"])
    np.testing.assert_allclose(
        calibrate_hand_eye_linear(*args, method=method, backend="numpy"),
        calibrate_hand_eye_linear(*args, method=method, backend="opencv"),
        atol=1e-10,
    )


def test_opencv_backend_without_opencv_support_is_a_clear_error():
    if opencv_has_hand_eye():
        pytest.skip("cv2.calibrateHandEye is available here")
    with pytest.raises(CalibrationError, match="does not expose calibrateHandEye"):
        calibrate_hand_eye_linear(
            REFERENCE["X_base_tool"], REFERENCE["X_camera_board"], method="park", backend="opencv"
        )


def test_tsai_needs_two_informative_motions():
    X = make_X(Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), [0.05, 0.0, 0.1])
    Y = make_X(np.eye(3), [0.6, 0.0, 0.0])
    # Three views, 8 degrees about x and about y from the first: no pair rotates the 17 degrees Tsai
    # requires, but the axes differ, so the problem itself is well posed.
    rotvecs = np.radians([[0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [0.0, 8.0, 0.0]])
    H = [make_X(Rotation.from_rotvec(r).as_matrix(), [0.5, 0.1 * i, 0.4]) for i, r in enumerate(rotvecs)]
    C = [invert_X(X) @ invert_X(h) @ Y for h in H]
    angles = np.degrees(Rotation.from_matrix(relative_motions(np.array(H), np.array(C))[0][:, :3, :3]).magnitude())
    assert angles.max() < 17.2
    with pytest.raises(CalibrationError, match="Tsai: only"):
        calibrate_hand_eye_linear(H, C, method="tsai", backend="numpy")
    # The other methods still work on these small but non-degenerate motions.
    np.testing.assert_allclose(calibrate_hand_eye_linear(H, C, method="park", backend="numpy"), X, atol=1e-9)
