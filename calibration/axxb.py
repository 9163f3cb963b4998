"""The five closed-form AX = XB hand-eye methods, computed by OpenCV's ``cv2.calibrateHandEye``.

Tsai & Lenz 1989, Park & Martin 1994, Horaud & Dornaika 1995, Andreff, Horaud & Espiau 1999 and
Daniilidis 1998. OpenCV 4.x exposes them to Python; the opencv-python 5.0.0 wheels do not
(opencv/opencv#29565), so pyproject.toml and constraints.txt keep OpenCV below 5. A numpy port of the
same five methods lives on only as a test oracle (tests/calibration/axxb_oracle.py).

Conventions, in OpenCV's terms: ``X_base_tool`` ("gripper2base"), ``X_camera_board``
("target2cam"); the result is ``X_tool_camera`` ("cam2gripper"), so that
``X_base_tool[i] @ X_tool_camera @ X_camera_board[i]`` is the same board pose for every view.
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import StrEnum

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.errors import CalibrationError
from perception.transforms import invert_X, make_X

FloatArray = NDArray[np.float64]


class LinearMethod(StrEnum):
    """The closed-form methods, named as OpenCV's ``CALIB_HAND_EYE_*`` flags (lower case)."""

    TSAI = "tsai"
    PARK = "park"
    HORAUD = "horaud"
    ANDREFF = "andreff"
    DANIILIDIS = "daniilidis"

    @property
    def opencv_flag(self) -> int:
        return int(getattr(cv2, f"CALIB_HAND_EYE_{self.name}"))


def require_opencv_hand_eye() -> None:
    """CalibrationError with the fix when the installed ``cv2`` lacks ``calibrateHandEye`` (the 5.0.0 wheels)."""
    if not hasattr(cv2, "calibrateHandEye"):
        raise CalibrationError(
            f"the installed OpenCV {cv2.__version__} does not expose cv2.calibrateHandEye (opencv/opencv#29565); "
            "install OpenCV 4.x: pip install 'opencv-contrib-python-headless>=4.10,<5' "
            "(scripts/bootstrap.sh does, from constraints.txt)"
        )


def calibrate_hand_eye_linear(
    X_base_tool: Sequence[ArrayLike] | FloatArray,
    X_camera_board: Sequence[ArrayLike] | FloatArray,
    *,
    method: LinearMethod | str,
) -> FloatArray:
    """(4, 4) ``X_tool_camera`` by one closed-form method of ``cv2.calibrateHandEye``.

    ``X_base_tool``, ``X_camera_board``: N >= 3 (4, 4) poses each, metres, paired by view. Input checks
    beyond shapes (degenerate motion) are the caller's job; see :mod:`calibration.handeye`.
    """
    m = LinearMethod(method)
    Hg = _stack(X_base_tool, "X_base_tool")
    Hc = _stack(X_camera_board, "X_camera_board")
    if Hg.shape[0] != Hc.shape[0] or Hg.shape[0] < 3:
        raise CalibrationError(f"need the same number (>= 3) of robot and board poses, got {len(Hg)} and {len(Hc)}")
    require_opencv_hand_eye()
    R, t = cv2.calibrateHandEye(
        [h[:3, :3] for h in Hg],
        [h[:3, 3].reshape(3, 1) for h in Hg],
        [c[:3, :3] for c in Hc],
        [c[:3, 3].reshape(3, 1) for c in Hc],
        method=m.opencv_flag,
    )
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        # OpenCV returns NaN rather than raising when a method's linear system has no solution
        raise CalibrationError(f"{m.value}: cv2.calibrateHandEye returned NaN; the views do not constrain it")
    return make_X(R, t)


def relative_motions(Hg: FloatArray, Hc: FloatArray) -> tuple[FloatArray, FloatArray]:
    """All pairs i < j: ``A = inv(Hg[j]) @ Hg[i]`` (tool motion) and ``B = Hc[j] @ inv(Hc[i])``
    (camera motion), each (M, 4, 4) with M = N (N - 1) / 2, so that ``A @ X = X @ B``."""
    i_idx, j_idx = np.triu_indices(Hg.shape[0], k=1)
    Hg_inv = np.stack([invert_X(h) for h in Hg])
    Hc_inv = np.stack([invert_X(h) for h in Hc])
    A = Hg_inv[j_idx] @ Hg[i_idx]
    B = Hc[j_idx] @ Hc_inv[i_idx]
    return A, B


def _stack(poses: Sequence[ArrayLike] | FloatArray, name: str) -> FloatArray:
    arr = np.asarray([np.asarray(p, dtype=np.float64) for p in poses], dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise CalibrationError(f"{name}: expected a sequence of (4, 4) poses, got shape {arr.shape}")
    return arr
