"""The fake UR's arm: DH kinematics of the UR5 and UR5e, and UR pose vectors.

Part of :mod:`sim_fakes.fake_ur` (its docstring describes the fake as a whole).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from perception.transforms import X_from_ur_pose

FloatArray = NDArray[np.float64]

SUPPORTED_FAULTS = frozenset({"drop_connection", "no_answer", "protective_stop", "emergency_stop"})

ROT_RADIUS_M = 0.1  # a rotation of θ rad counts as 0.1·θ m of path
_GRAVITY_M_S2 = 9.81

# DH parameters (d, a) in metres; alpha is the same for both models
_DH: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "UR5": ((0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823), (0.0, -0.425, -0.39225, 0.0, 0.0, 0.0)),
    "UR5e": ((0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996), (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)),
}
_DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
Q_HOME = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)


class Arm:
    """Forward and inverse kinematics of a UR arm from its DH parameters (``model``: "UR5" or "UR5e")."""

    def __init__(self, model: str) -> None:
        if model not in _DH:
            raise ValueError(f"unknown robot model {model!r}; the fake knows {sorted(_DH)}")
        self.d, self.a = _DH[model]

    def chain(self, q: FloatArray) -> list[FloatArray]:
        """The 7 frames (4, 4) from the base to the tool flange for joint angles ``q`` (6,) in radians."""
        T = np.eye(4)
        frames = [T]
        for i in range(6):
            ct, st = math.cos(q[i]), math.sin(q[i])
            ca, sa = math.cos(_DH_ALPHA[i]), math.sin(_DH_ALPHA[i])
            A = np.array(
                [
                    [ct, -st * ca, st * sa, self.a[i] * ct],
                    [st, ct * ca, -ct * sa, self.a[i] * st],
                    [0.0, sa, ca, self.d[i]],
                    [0.0, 0.0, 0.0, 1.0],
                ]
            )
            T = T @ A
            frames.append(T)
        return frames

    def fk(self, q: FloatArray) -> FloatArray:
        return self.chain(q)[-1]

    def solve(
        self, X_target: FloatArray, q_seed: FloatArray, *, max_iter: int, tol: float = 1e-10
    ) -> tuple[FloatArray, float]:
        """Joint angles near ``q_seed`` reaching ``X_target`` (damped least squares); returns (q, residual).

        The residual is the norm of [position error (m), rotation error (rad)].
        """
        q = np.array(q_seed, dtype=np.float64)
        for _ in range(max_iter + 1):
            frames = self.chain(q)
            T = frames[-1]
            e = np.concatenate([X_target[:3, 3] - T[:3, 3], rotvec(X_target[:3, :3] @ T[:3, :3].T)])
            residual = float(np.linalg.norm(e))
            if residual < tol:
                return q, residual
            J = _jacobian(frames)
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), e)
            q += dq / max(1.0, float(np.abs(dq).max()) / 0.3)
        return q, residual


def rotvec(R: FloatArray) -> FloatArray:
    """Rotation vector (3,) in radians of the (3, 3) rotation ``R``; angle in [0, π].

    scipy's own route (Shepperd's quaternion from the largest of the trace and the diagonal, its scalar part made
    non-negative, then angle and axis), written out: the fake solves inverse kinematics, integrates its motion and
    streams its pose with this every controller cycle (8 ms on a CB3), and ``Rotation.from_matrix`` costs about
    0.3 ms a call. The fake's home pose, tool pointing down, is a rotation of exactly π, where the shorter formula
    from the trace and the skew part loses its axis (7e-6 rad off at π - 1e-5); with scipy there the fake spent a
    fifth of a core at rest and missed its cycles on a loaded machine."""
    trace = float(R[0, 0] + R[1, 1] + R[2, 2])
    diagonal = (float(R[0, 0]), float(R[1, 1]), float(R[2, 2]))
    i = max(range(3), key=lambda n: diagonal[n])
    if diagonal[i] >= trace:
        j, k = (i + 1) % 3, (i + 2) % 3
        quat = [0.0, 0.0, 0.0, float(R[k, j] - R[j, k])]  # x, y, z, w
        quat[i] = 1.0 - trace + 2.0 * diagonal[i]
        quat[j] = float(R[j, i] + R[i, j])
        quat[k] = float(R[k, i] + R[i, k])
    else:
        quat = [float(R[2, 1] - R[1, 2]), float(R[0, 2] - R[2, 0]), float(R[1, 0] - R[0, 1]), 1.0 + trace]
    norm = math.sqrt(sum(v * v for v in quat))
    x, y, z, w = (v / norm for v in quat)
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    angle = 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
    scale = 2.0 + angle**2 / 12.0 + 7.0 * angle**4 / 2880.0 if angle <= 1e-3 else angle / math.sin(angle / 2.0)
    return np.array([scale * x, scale * y, scale * z])


def rotation(w: FloatArray) -> FloatArray:
    """(3, 3) rotation of the rotation vector ``w`` (radians), by Rodrigues' formula (the motion integrates with
    it every controller cycle: scipy's ``Rotation.from_rotvec`` costs ten times as much per call)."""
    wx, wy, wz = float(w[0]), float(w[1]), float(w[2])
    angle = math.sqrt(wx * wx + wy * wy + wz * wz)
    if angle < 1e-12:
        return np.array([[1.0, -wz, wy], [wz, 1.0, -wx], [-wy, wx, 1.0]])
    kx, ky, kz = wx / angle, wy / angle, wz / angle
    s, c = math.sin(angle), math.cos(angle)
    v = 1.0 - c
    return np.array(
        [
            [c + kx * kx * v, kx * ky * v - kz * s, kx * kz * v + ky * s],
            [ky * kx * v + kz * s, c + ky * ky * v, ky * kz * v - kx * s],
            [kz * kx * v - ky * s, kz * ky * v + kx * s, c + kz * kz * v],
        ]
    )


def _jacobian(frames: Sequence[FloatArray]) -> FloatArray:
    """The (6, 6) geometric Jacobian of the chain ``frames`` (revolute joints about each frame's z): rows 0-2 the
    tool's linear velocity per joint rate (z_i x (p_end - p_i)), rows 3-5 its angular velocity (z_i)."""
    Z = np.array([frames[i][:3, 2] for i in range(6)])
    P = frames[-1][:3, 3] - np.array([frames[i][:3, 3] for i in range(6)])
    J = np.empty((6, 6))
    J[0] = Z[:, 1] * P[:, 2] - Z[:, 2] * P[:, 1]
    J[1] = Z[:, 2] * P[:, 0] - Z[:, 0] * P[:, 2]
    J[2] = Z[:, 0] * P[:, 1] - Z[:, 1] * P[:, 0]
    J[3:] = Z.T
    return J


def ur_pose(p: FloatArray, R: FloatArray) -> list[float]:
    """UR pose vector ``[x, y, z, rx, ry, rz]`` of position ``p`` (m) and rotation ``R``."""
    return [*map(float, p), *map(float, rotvec(R))]


def pose_to_X(pose: Sequence[float]) -> FloatArray:
    """4x4 ``X_base_tool`` of a UR pose vector."""
    return X_from_ur_pose(pose)
