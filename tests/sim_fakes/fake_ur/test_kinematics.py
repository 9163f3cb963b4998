"""sim_fakes/fake_ur/kinematics.py: DH kinematics of the UR5 and the pose vectors.

No fake process here: tests/drivers/test_ur.py runs the whole fake against the real ur-rtde client.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.transforms import X_from_ur_pose, ur_pose_from_X
from sim_fakes.fake_ur import Q_HOME, Arm, pose_to_X, ur_pose

# the UR5 flange at Q_HOME from its DH table: x = -(a3 + d5), y = -d4, z = d1 + (-a2) - d6; tool pointing down
HOME_POSE = (-(0.39225 + 0.09465), -0.10915, 0.089159 + 0.425 - 0.0823, math.pi / 2**0.5, math.pi / 2**0.5, 0.0)


def test_the_ur5_home_pose_and_its_inverse_kinematics() -> None:
    arm = Arm("UR5")
    X = arm.fk(np.array(Q_HOME))
    np.testing.assert_allclose(ur_pose(X[:3, 3], X[:3, :3]), HOME_POSE, atol=1e-12)
    X_target = X.copy()
    X_target[:3, 3] += (0.05, -0.03, 0.02)
    q, residual = arm.solve(X_target, np.array(Q_HOME), max_iter=50)
    assert residual < 1e-10
    np.testing.assert_allclose(arm.fk(q), X_target, atol=1e-9)
    with pytest.raises(ValueError, match=r"unknown robot model 'UR10'; the fake knows \['UR5', 'UR5e'\]"):
        Arm("UR10")


def test_pose_vectors_are_those_of_perception_transforms() -> None:
    pose = [0.1, -0.2, 0.3, 0.4, -1.2, 2.0]
    np.testing.assert_allclose(pose_to_X(pose), X_from_ur_pose(pose), atol=1e-15)
    X = pose_to_X(pose)
    np.testing.assert_allclose(ur_pose(X[:3, 3], X[:3, :3]), ur_pose_from_X(X), atol=1e-15)


def test_rotation_vectors_and_rotations_equal_scipys_near_pi_and_elsewhere() -> None:
    # the fast formulas the fake runs every cycle against scipy's, on angles from 0 to π (the home pose is at π)
    from scipy.spatial.transform import Rotation

    from sim_fakes.fake_ur.kinematics import rotation, rotvec

    rng = np.random.default_rng(3)
    axes = rng.normal(size=(400, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-13, 1e-6, 0.3, 2.0], math.pi - np.logspace(-12, -4, 195), [math.pi] * 200])
    axes[:3] = [(1.0, 1.0, 0.0) / np.sqrt(2.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)]  # the home pose's axis first
    for axis, angle in zip(axes, angles, strict=True):
        w = angle * axis
        R_ref = Rotation.from_rotvec(w).as_matrix()
        np.testing.assert_allclose(rotation(w), R_ref, atol=2e-15)
        np.testing.assert_allclose(rotvec(R_ref), Rotation.from_matrix(R_ref).as_rotvec(), atol=1e-14)
    # the home pose exactly: (π/√2, π/√2, 0), the sign scipy gives
    R_home = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    np.testing.assert_allclose(rotvec(R_home), [math.pi / 2**0.5, math.pi / 2**0.5, 0.0], atol=1e-15)


def test_the_jacobian_is_the_derivative_of_the_forward_kinematics() -> None:
    from sim_fakes.fake_ur.kinematics import _jacobian, rotvec

    arm = Arm("UR5")
    q = np.array(Q_HOME) + np.array([0.1, -0.2, 0.3, 0.05, 0.4, -0.3])
    J = _jacobian(arm.chain(q))
    X0 = arm.fk(q)
    h = 1e-7
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        X1 = arm.fk(q + dq)
        np.testing.assert_allclose(J[:3, i], (X1[:3, 3] - X0[:3, 3]) / h, atol=1e-6)
        np.testing.assert_allclose(J[3:, i], rotvec(X1[:3, :3] @ X0[:3, :3].T) / h, atol=1e-6)
