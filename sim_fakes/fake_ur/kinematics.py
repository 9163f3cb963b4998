"""The fake UR's arm: DH kinematics of the UR5 and UR5e, and UR pose vectors.

Part of :mod:`sim_fakes.fake_ur` (its docstring describes the fake as a whole).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

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
            J = np.zeros((6, 6))
            p_end = T[:3, 3]
            for i in range(6):
                z = frames[i][:3, 2]
                J[:3, i] = np.cross(z, p_end - frames[i][:3, 3])
                J[3:, i] = z
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), e)
            q += dq / max(1.0, float(np.abs(dq).max()) / 0.3)
        return q, residual


def rotvec(R: FloatArray) -> FloatArray:
    """Rotation vector (3,) in radians of the (3, 3) rotation ``R``; angle in [0, π].

    Not scipy's ``Rotation.from_matrix`` (which :mod:`perception.transforms` uses): the fake solves inverse kinematics
    and integrates its motion with this every controller cycle (8 ms on a CB3), and from_matrix, which first finds
    the nearest rotation, is about 15 times slower; with it the fake missed its cycles under load."""
    c = min(1.0, max(-1.0, (float(np.trace(R)) - 1.0) / 2.0))
    angle = math.acos(c)
    vee = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-9:
        return 0.5 * vee
    if math.pi - angle < 1e-5:  # near π the formula loses its axis: the general route
        return np.asarray(Rotation.from_matrix(R).as_rotvec(), dtype=np.float64)
    return angle / (2.0 * math.sin(angle)) * vee


def rotation(w: FloatArray) -> FloatArray:
    """(3, 3) rotation of the rotation vector ``w`` (radians)."""
    return np.asarray(Rotation.from_rotvec(w).as_matrix(), dtype=np.float64)


def ur_pose(p: FloatArray, R: FloatArray) -> list[float]:
    """UR pose vector ``[x, y, z, rx, ry, rz]`` of position ``p`` (m) and rotation ``R``."""
    return [*map(float, p), *map(float, rotvec(R))]


def pose_to_X(pose: Sequence[float]) -> FloatArray:
    """4x4 ``X_base_tool`` of a UR pose vector."""
    return X_from_ur_pose(pose)
