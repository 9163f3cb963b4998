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
