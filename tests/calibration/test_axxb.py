"""calibration.axxb: cv2.calibrateHandEye through weldcell, against values recorded from OpenCV 4.12 and against
the numpy port kept as an oracle (tests/calibration/axxb_oracle.py)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration import axxb
from calibration.axxb import LinearMethod, calibrate_hand_eye_linear, relative_motions
from calibration.errors import CalibrationError
from perception.transforms import invert_X, make_X
from tests.calibration.axxb_oracle import calibrate_hand_eye_numpy

REFERENCE = json.loads((Path(__file__).parent / "data" / "opencv_handeye_reference.json").read_text())


def test_the_installed_opencv_is_4x_with_calibrate_hand_eye():
    # constraints.txt and pyproject.toml keep OpenCV below 5 because 5.0.0 dropped the Python binding
    assert int(cv2.__version__.split(".")[0]) == 4
    assert hasattr(cv2, "calibrateHandEye")


def test_reference_data_exercises_the_hard_cases():
    A, _ = relative_motions(np.array(REFERENCE["X_base_tool"]), np.array(REFERENCE["X_camera_board"]))
    angles = np.degrees(Rotation.from_matrix(A[:, :3, :3]).magnitude())
    assert angles.max() > 170  # quaternion sign handling
    assert angles.min() < 17  # Tsai's pair filter


@pytest.mark.parametrize("method", list(LinearMethod), ids=lambda m: m.value)
def test_opencv_matches_the_values_recorded_from_opencv_412(method):
    X = calibrate_hand_eye_linear(REFERENCE["X_base_tool"], REFERENCE["X_camera_board"], method=method)
    expected = np.array(REFERENCE["X_tool_camera_by_method"][method.value])
    np.testing.assert_allclose(X, expected, atol=1e-10)
    # The methods differ from each other on noisy data, so matching is not an accident of the truth.
    others = [np.array(v) for k, v in REFERENCE["X_tool_camera_by_method"].items() if k != method.value]
    assert min(np.abs(X - o).max() for o in others) > 1e-6


@pytest.mark.parametrize("method", list(LinearMethod), ids=lambda m: m.value)
def test_the_numpy_oracle_matches_opencv(method):
    args = (REFERENCE["X_base_tool"], REFERENCE["X_camera_board"])
    np.testing.assert_allclose(
        calibrate_hand_eye_numpy(*args, method=method), calibrate_hand_eye_linear(*args, method=method), atol=1e-10
    )
    expected = np.array(REFERENCE["X_tool_camera_by_method"][method.value])
    np.testing.assert_allclose(calibrate_hand_eye_numpy(*args, method=method), expected, atol=1e-12)


@pytest.mark.parametrize("method", list(LinearMethod), ids=lambda m: m.value)
def test_noise_free_views_give_the_exact_mount(method):
    X = make_X(Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), [0.05, 0.0, 0.1])
    Y = make_X(np.eye(3), [0.6, 0.0, 0.0])
    rotvecs = np.radians([[0, 0, 0], [30, 0, 0], [0, 35, 0], [0, 0, 40], [25, -20, 10]])
    H = [make_X(Rotation.from_rotvec(r).as_matrix(), [0.5, 0.1 * i, 0.4]) for i, r in enumerate(rotvecs)]
    C = [invert_X(X) @ invert_X(h) @ Y for h in H]
    np.testing.assert_allclose(calibrate_hand_eye_linear(H, C, method=method), X, atol=1e-9)


def test_without_calibrate_hand_eye_the_error_says_how_to_install_opencv_4(monkeypatch):
    class Cv2WithoutHandEye:
        __version__ = "5.0.0"

    monkeypatch.setattr(axxb, "cv2", Cv2WithoutHandEye)
    hint = r"OpenCV 5\.0\.0 does not expose.*opencv-contrib-python-headless>=4\.10,<5"
    with pytest.raises(CalibrationError, match=hint):
        calibrate_hand_eye_linear(REFERENCE["X_base_tool"], REFERENCE["X_camera_board"], method="park")


def test_too_few_or_unpaired_views_are_refused():
    with pytest.raises(CalibrationError, match="same number"):
        calibrate_hand_eye_linear(REFERENCE["X_base_tool"][:3], REFERENCE["X_camera_board"][:4], method="park")
    with pytest.raises(CalibrationError, match="expected a sequence of"):
        calibrate_hand_eye_linear([np.eye(3)] * 3, REFERENCE["X_camera_board"][:3], method="park")


def test_oracle_tsai_needs_two_informative_motions():
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
        calibrate_hand_eye_numpy(H, C, method="tsai")
    # The other methods still work on these small but non-degenerate motions, in the oracle and in OpenCV.
    np.testing.assert_allclose(calibrate_hand_eye_numpy(H, C, method="park"), X, atol=1e-9)
    np.testing.assert_allclose(calibrate_hand_eye_linear(H, C, method="park"), X, atol=1e-9)
