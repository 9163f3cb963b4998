"""Rigid transforms and the pose formats of the devices weldcell talks to.

Conventions (see docs/frames.md):
- ``X_a_b`` is the 4x4 homogeneous pose of frame b in frame a, so ``p_a = X_a_b @ p_b``.
- Quaternions are scalar-last ``[qx, qy, qz, qw]`` (scipy's convention).
- Everything is SI (metres, radians) except where a device format says otherwise; those converters
  carry the unit in their name (``xyzwpr_mm_deg``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from perception.errors import WeldcellError

FloatArray = NDArray[np.float64]

_ORTHO_TOL = 1e-6


class TransformError(WeldcellError, ValueError):
    """A matrix that claims to be a rigid transform is not one."""


def check_X(X: ArrayLike, *, name: str = "X", tol: float = _ORTHO_TOL) -> FloatArray:
    """Return ``X`` as a float64 (4, 4) array after checking it is a proper rigid transform.

    Refuses NaN/inf, a wrong shape, a last row other than [0, 0, 0, 1], a non-orthonormal rotation
    or a reflection (det = -1), naming ``name`` in the message.
    """
    try:
        arr = np.asarray(X, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise TransformError(f"{name}: not a numeric 4x4 matrix ({err})") from err
    if arr.shape != (4, 4):
        raise TransformError(f"{name}: expected shape (4, 4), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = ", ".join(f"[{r}, {c}]" for r, c in zip(*np.nonzero(~np.isfinite(arr)), strict=True))
        raise TransformError(f"{name}: contains NaN or inf at {bad}")
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise TransformError(f"{name}: last row must be [0, 0, 0, 1], got {arr[3].tolist()}")
    R = arr[:3, :3]
    err_ortho = float(np.abs(R.T @ R - np.eye(3)).max())
    if err_ortho > tol * 100:
        raise TransformError(
            f"{name}: rotation part is not orthonormal (max |R^T R - I| = {err_ortho:.2e}, limit {tol * 100:.0e})"
        )
    det = float(np.linalg.det(R))
    if det < 0:
        raise TransformError(f"{name}: rotation part is a reflection (det = {det:.3f}, must be +1)")
    return arr


def make_X(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """Homogeneous transform from a (3, 3) rotation and a (3,) translation in metres."""
    X = np.eye(4)
    X[:3, :3] = np.asarray(R, dtype=np.float64)
    X[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return X


def invert_X(X: ArrayLike) -> FloatArray:
    """Inverse of a rigid transform (exact, using R^T)."""
    arr = np.asarray(X, dtype=np.float64)
    R = arr[:3, :3]
    t = arr[:3, 3]
    return make_X(R.T, -R.T @ t)


def transform_points(X_a_b: ArrayLike, p_b: ArrayLike) -> FloatArray:
    """Map (N, 3) points from frame b to frame a."""
    X = np.asarray(X_a_b, dtype=np.float64)
    p = np.asarray(p_b, dtype=np.float64).reshape(-1, 3)
    return p @ X[:3, :3].T + X[:3, 3]


def rotate_vectors(X_a_b: ArrayLike, v_b: ArrayLike) -> FloatArray:
    """Rotate (N, 3) direction vectors from frame b to frame a (no translation)."""
    X = np.asarray(X_a_b, dtype=np.float64)
    return np.asarray(v_b, dtype=np.float64).reshape(-1, 3) @ X[:3, :3].T


def xyzquat_from_X(X: ArrayLike) -> FloatArray:
    """(7,) ``[x, y, z, qx, qy, qz, qw]`` (metres, scalar-last quaternion with qw >= 0)."""
    arr = np.asarray(X, dtype=np.float64)
    q = Rotation.from_matrix(arr[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([arr[:3, 3], q])


def X_from_xyzquat(xyzquat: ArrayLike) -> FloatArray:
    """Inverse of :func:`xyzquat_from_X`; the quaternion is normalised."""
    v = np.asarray(xyzquat, dtype=np.float64).reshape(7)
    return make_X(Rotation.from_quat(v[3:]).as_matrix(), v[:3])


def ur_pose_from_X(X: ArrayLike) -> FloatArray:
    """UR pose vector ``[x, y, z, rx, ry, rz]``: metres and a rotation vector in radians."""
    arr = np.asarray(X, dtype=np.float64)
    return np.concatenate([arr[:3, 3], Rotation.from_matrix(arr[:3, :3]).as_rotvec()])


def X_from_ur_pose(pose: ArrayLike) -> FloatArray:
    """Inverse of :func:`ur_pose_from_X`."""
    v = np.asarray(pose, dtype=np.float64).reshape(6)
    return make_X(Rotation.from_rotvec(v[3:]).as_matrix(), v[:3])


def xyzwpr_mm_deg_from_X(X: ArrayLike) -> FloatArray:
    """FANUC ``[X, Y, Z, W, P, R]``: millimetres and degrees.

    FANUC's W, P, R are rotations about the fixed x, y, z axes applied in that order,
    i.e. ``R = Rz(r) @ Ry(p) @ Rx(w)`` (scipy's extrinsic ``"xyz"``).
    """
    arr = np.asarray(X, dtype=np.float64)
    wpr_deg = Rotation.from_matrix(arr[:3, :3]).as_euler("xyz", degrees=True)
    return np.concatenate([arr[:3, 3] * 1000.0, wpr_deg])


def X_from_xyzwpr_mm_deg(xyzwpr: ArrayLike) -> FloatArray:
    """Inverse of :func:`xyzwpr_mm_deg_from_X`."""
    v = np.asarray(xyzwpr, dtype=np.float64).reshape(6)
    return make_X(Rotation.from_euler("xyz", v[3:], degrees=True).as_matrix(), v[:3] / 1000.0)


def look_at_X(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> FloatArray:
    """``X_world_camera`` of an OpenCV camera (z forward, y down) at ``eye`` looking at ``target``.

    ``up`` is the world direction that should appear upward in the image.
    """
    eye_w = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye_w
    norm = np.linalg.norm(z)
    if norm < 1e-9:
        raise TransformError("look_at: eye and target coincide")
    z /= norm
    up_w = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up_w)
    if np.linalg.norm(x) < 1e-9:
        raise TransformError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_X(np.column_stack([x, y, z]), eye_w)


def rotation_angle_rad(R_a: ArrayLike, R_b: ArrayLike) -> float:
    """Angle in radians of the rotation taking ``R_a`` to ``R_b``."""
    Ra = np.asarray(R_a, dtype=np.float64)[:3, :3]
    Rb = np.asarray(R_b, dtype=np.float64)[:3, :3]
    # the rotation vector's norm stays accurate near zero, where arccos of the trace loses precision
    return float(Rotation.from_matrix(Ra.T @ Rb).magnitude())
