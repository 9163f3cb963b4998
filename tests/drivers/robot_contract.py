"""The checks every ``drivers.protocols.Robot`` implementation must pass.

A test module subclasses :class:`RobotContract` and provides the fixture ``robot_and_fake`` yielding
``(robot, fake)``: a connected driver and the fake's :class:`sim_fakes.faults.FaultInjectable` handle
(``fake`` is None against real hardware, where fault tests are skipped). The fake must start at a
reachable pose with no faults; each test gets a fresh fake or one returned to that state.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.errors import ConnectionLost, DeviceTimeout, EmergencyStop, ProtectiveStop
from drivers.protocols import Robot, RobotMode
from perception.transforms import make_X, rotation_angle_rad

POS_TOL_M = 1e-4  # 0.1 mm
ROT_TOL_RAD = np.deg2rad(0.1)


def offset(X: np.ndarray, dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> np.ndarray:
    out = X.copy()
    out[:3, 3] += (dx, dy, dz)
    return out


def assert_pose_close(X_a: np.ndarray, X_b: np.ndarray) -> None:
    assert np.linalg.norm(X_a[:3, 3] - X_b[:3, 3]) < POS_TOL_M, (X_a[:3, 3], X_b[:3, 3])
    assert rotation_angle_rad(X_a, X_b) < ROT_TOL_RAD


class RobotContract:
    """Subclass and provide ``robot_and_fake``. Every test has a timeout."""

    @pytest.mark.timeout(30)
    def test_is_a_robot_and_healthy(self, robot_and_fake):
        robot, _ = robot_and_fake
        assert isinstance(robot, Robot)
        state = robot.state()
        assert state.healthy
        assert state.mode in (RobotMode.IDLE, RobotMode.MOVING)
        X = robot.get_X_base_tool()
        assert X.shape == (4, 4)
        assert np.allclose(X[:3, :3] @ X[:3, :3].T, np.eye(3), atol=1e-6)

    @pytest.mark.timeout(30)
    def test_move_linear_arrives_and_takes_time(self, robot_and_fake):
        robot, _ = robot_and_fake
        X0 = robot.get_X_base_tool()
        target = offset(X0, dx=0.05, dz=-0.02)
        t0 = time.monotonic()
        robot.move_linear(target, speed_m_s=0.25, timeout_s=20)
        elapsed = time.monotonic() - t0
        assert_pose_close(robot.get_X_base_tool(), target)
        # 53.9 mm at 0.25 m/s takes at least 0.2 s: the fake integrates motion, it does not teleport
        assert elapsed > 0.15

    @pytest.mark.timeout(60)
    def test_stream_path_arrives_in_order(self, robot_and_fake):
        robot, _ = robot_and_fake
        X0 = robot.get_X_base_tool()
        path = [offset(X0, dx=0.002 * i, dy=0.001 * (i % 3)) for i in range(1, 31)]
        done: list[int] = []
        robot.stream_path(path, speed_m_s=0.25, blend_m=0.001, timeout_s=40, on_progress=done.append)
        assert_pose_close(robot.get_X_base_tool(), path[-1])
        if done:  # devices that report progress must report it in order and completely
            assert done == sorted(done)
            assert done[-1] == len(path) - 1

    @pytest.mark.timeout(30)
    def test_digital_output_round_trip(self, robot_and_fake):
        robot, _ = robot_and_fake
        robot.set_digital_output(2, True)
        deadline = time.monotonic() + 2.0
        while not robot.state().digital_outputs[2] and time.monotonic() < deadline:
            time.sleep(0.01)
        assert robot.state().digital_outputs[2] is True
        robot.set_digital_output(2, False)
        deadline = time.monotonic() + 2.0
        while robot.state().digital_outputs[2] and time.monotonic() < deadline:
            time.sleep(0.01)
        assert robot.state().digital_outputs[2] is False

    @pytest.mark.timeout(30)
    def test_stop_is_safe_when_idle(self, robot_and_fake):
        robot, _ = robot_and_fake
        robot.stop()
        robot.stop()
        assert robot.state().healthy

    @pytest.mark.timeout(30)
    def test_protective_stop_during_motion_raises(self, robot_and_fake):
        robot, fake = robot_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        X0 = robot.get_X_base_tool()
        target = offset(X0, dx=0.2)

        import threading

        timer = threading.Timer(0.3, fake.inject, args=("protective_stop",))
        timer.start()
        try:
            with pytest.raises(ProtectiveStop):
                robot.move_linear(target, speed_m_s=0.1, timeout_s=10)
        finally:
            timer.cancel()
        state = robot.state()
        assert state.protective_stop
        assert state.mode == RobotMode.PROTECTIVE_STOP
        # stopped part-way: not at the target
        assert np.linalg.norm(robot.get_X_base_tool()[:3, 3] - target[:3, 3]) > 0.01

    @pytest.mark.timeout(30)
    def test_emergency_stop_refuses_motion(self, robot_and_fake):
        robot, fake = robot_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        fake.inject("emergency_stop")
        deadline = time.monotonic() + 2.0
        while not robot.state().emergency_stop and time.monotonic() < deadline:
            time.sleep(0.01)
        assert robot.state().mode == RobotMode.EMERGENCY_STOP
        with pytest.raises(EmergencyStop):
            robot.move_linear(offset(robot.get_X_base_tool(), dz=0.01), speed_m_s=0.1, timeout_s=5)

    @pytest.mark.timeout(40)
    def test_dropped_connection_raises_then_reconnects(self, robot_and_fake):
        robot, fake = robot_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        fake.inject("drop_connection")
        with pytest.raises(ConnectionLost):
            for _ in range(200):  # the drop must be noticed within a couple of seconds
                robot.state()
                time.sleep(0.01)
        fake.clear_faults()
        robot.connect()
        assert robot.state().healthy
        X0 = robot.get_X_base_tool()
        robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.2, timeout_s=10)
        assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))

    @pytest.mark.timeout(40)
    def test_no_answer_times_out(self, robot_and_fake):
        robot, fake = robot_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        fake.inject("no_answer")
        t0 = time.monotonic()
        with pytest.raises((DeviceTimeout, ConnectionLost)):
            robot.move_linear(offset(robot.get_X_base_tool(), dz=0.01), speed_m_s=0.1, timeout_s=3)
        assert time.monotonic() - t0 < 10


def identity_pose_at(x: float, y: float, z: float) -> np.ndarray:
    """A tool pose pointing down (tool z along base -z) at (x, y, z)."""
    return make_X(np.diag([1.0, -1.0, -1.0]), [x, y, z])
