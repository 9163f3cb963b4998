"""sim_fakes/fake_ur/motion.py: the motion profile of a straight move.

No fake process here: tests/drivers/test_ur.py runs the whole fake against the real ur-rtde client.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_fakes.fake_ur import Motion, Waypoint, build_segments, pose_to_X

# the UR5 flange at Q_HOME from its DH table: x = -(a3 + d5), y = -d4, z = d1 + (-a2) - d6; tool pointing down
HOME_POSE = (-(0.39225 + 0.09465), -0.10915, 0.089159 + 0.425 - 0.0823, math.pi / 2**0.5, math.pi / 2**0.5, 0.0)


def test_a_straight_move_accelerates_cruises_and_stops_on_its_target() -> None:
    start = pose_to_X(HOME_POSE)
    target = list(HOME_POSE)
    target[0] += 0.1
    segments = build_segments(start[:3, 3], start[:3, :3], [Waypoint(tuple(target), 0.1, 1.0, 0.0)])
    assert len(segments) == 1 and math.isclose(segments[0].length, 0.1)
    motion = Motion(segments)
    t, dt = 0.0, 0.002
    while not motion.done and t < 5.0:
        motion.step(dt)
        t += dt
    # 0.1 m at 0.1 m/s with 1 m/s² ramps: 0.1 s up, 0.9 s cruising, 0.1 s down = 1.1 s
    assert t == pytest.approx(1.1, abs=0.01)
    p, _ = motion.pose()
    np.testing.assert_allclose(p, np.array(target[:3]), atol=1e-12)
