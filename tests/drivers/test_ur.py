"""URRobot (drivers/ur.py) against the fake UR controller (sim_fakes/fake_ur/) through the real ur-rtde client.

One fake per module on a free loopback address of this session, returned to its initial state before each test;
a fresh driver per test.
"""

from __future__ import annotations

import math
import socket
import statistics
import struct
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="ur-rtde is not installed")

from drivers.errors import (
    ConnectionLost,
    DriverNotInstalled,
    EmergencyStop,
    MotionRejected,
    MotionTimeout,
    ProtectiveStop,
)
from drivers.protocols import RobotMode
from drivers.ur import URRobot
from perception.transforms import make_X, rotation_angle_rad
from sim_fakes.fake_ur import Q_HOME, Arm, FakeURController, Motion, Waypoint, build_segments
from sim_fakes.faults import FaultInjectable
from sim_fakes.loopback import free_loopback_host
from tests.drivers.robot_contract import RobotContract, assert_pose_close, offset

# loopback addresses of this test session (the UR ports are fixed; another session may use them elsewhere)
HOST = free_loopback_host()
HOST_B = free_loopback_host()
UNUSED_HOST = free_loopback_host()  # nothing listens here

# ur-rtde writes path poses into URScript with 6 significant digits
PATH_ROUNDING_M = 5e-6
PATH_ROUNDING_RAD = 1e-5


@pytest.fixture(scope="module")
def fake():
    with FakeURController(HOST, protective_stop_unlock_delay_s=0.5) as controller:
        yield controller


@pytest.fixture
def robot_and_fake(fake):
    fake.reset()
    robot = URRobot(HOST, name="ur-test")
    robot.connect()
    try:
        yield robot, fake
    finally:
        robot.disconnect()


class TestURRobotContract(RobotContract):
    pass


# ------------------------------------------------------------------------------------------- the fake itself


def _run_motion(waypoints: list[Waypoint], dt: float = 0.001) -> tuple[float, list[int], list[float], Motion]:
    """Integrate from the origin (identity orientation); returns (duration, waypoints entered, speeds, motion)."""
    entered: list[int] = []
    motion = Motion(build_segments(np.zeros(3), np.eye(3), waypoints), entered.append)
    t, speeds = 0.0, []
    while not motion.done:
        motion.step(dt)
        t += dt
        speeds.append(motion.u)
    return t, entered, speeds, motion


@pytest.mark.timeout(30)
def test_motion_profiles_follow_speed_and_acceleration():
    dt = 0.001
    # 0.1 m at 0.2 m/s with 1 m/s^2: 0.2 s up, 0.3 s cruise, 0.2 s down
    t, entered, speeds, motion = _run_motion([Waypoint((0.0, 0.0, 0.1, 0.0, 0.0, 0.0), 0.2, 1.0, 0.0)], dt)
    assert 0.7 - dt / 2 <= t <= 0.7 + dt
    assert max(speeds) == pytest.approx(0.2)
    assert entered == [0]
    assert np.array_equal(motion.pose()[0], [0.0, 0.0, 0.1])
    # a pure 90 deg turn counts as 0.1 m/rad of path: 0.15708 m at 0.1 m/s with 1 m/s^2 -> 1.5708 + 0.1 s
    t, _, _, motion = _run_motion([Waypoint((0.0, 0.0, 0.0, 0.0, 0.0, math.pi / 2), 0.1, 1.0, 0.0)], dt)
    assert 1.6708 - dt <= t <= 1.6708 + dt
    assert np.allclose(motion.pose()[1], [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-12)
    # three 10 mm moves without blending stop at each waypoint: 3 x 0.2 s (triangular profiles)
    stops = [Waypoint((0.01 * i, 0.0, 0.0, 0.0, 0.0, 0.0), 0.1, 1.0, 0.0) for i in (1, 2, 3)]
    t, entered, _, _ = _run_motion(stops, dt)
    assert 0.6 - dt <= t <= 0.6 + 3 * dt
    assert entered == [0, 1, 2]
    # the same 200 x 1 mm path blended: the speed carries through every waypoint, 2.0 s cruise + 0.1 s ramps
    blended = [
        Waypoint((0.001 * i, 0.0, 0.0, 0.0, 0.0, 0.0), 0.1, 1.0, 0.0001 if i < 200 else 0.0) for i in range(1, 201)
    ]
    t, entered, speeds, motion = _run_motion(blended, dt)
    assert 2.1 - dt <= t <= 2.1 + dt
    assert entered == list(range(200))
    assert min(speeds[100:2000]) == pytest.approx(0.1)
    assert np.array_equal(motion.pose()[0], [0.2, 0.0, 0.0])


def _rtde_send(sock: socket.socket, msg_type: str, payload: bytes = b"") -> None:
    sock.sendall(struct.pack(">HB", 3 + len(payload), ord(msg_type)) + payload)


def _rtde_read(sock: socket.socket) -> tuple[str, bytes]:
    def exactly(n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            assert chunk, "the fake closed the connection"
            data += chunk
        return data

    size, msg_type = struct.unpack(">HB", exactly(3))
    return chr(msg_type), exactly(size - 3)


def _rtde_call(sock: socket.socket, msg_type: str, payload: bytes = b"") -> tuple[str, bytes]:
    _rtde_send(sock, msg_type, payload)
    return _rtde_read(sock)


@pytest.mark.timeout(30)
def test_fake_rtde_wire_protocol(fake):
    """The RTDE server byte by byte: negotiation, recipes (NOT_FOUND, frequency limit), start, stream, inputs."""
    fake.reset()
    with socket.create_connection((HOST, 30004), timeout=5.0) as sock:
        assert _rtde_call(sock, "V", struct.pack(">H", 3)) == ("V", b"\x00")
        assert _rtde_call(sock, "V", struct.pack(">H", 2)) == ("V", b"\x01")
        msg_type, body = _rtde_call(sock, "v")
        assert (msg_type, struct.unpack(">IIII", body)) == ("v", (3, 15, 8, 106339))
        freq = struct.pack(">d", 125.0)
        assert _rtde_call(sock, "O", freq + b"timestamp,actual_q,no_such_thing") == (
            "O",
            b"\x00DOUBLE,VECTOR6D,NOT_FOUND",
        )
        assert _rtde_call(sock, "O", struct.pack(">d", 250.0) + b"timestamp")[1][:1] == b"\x00"  # CB3: <= 125 Hz
        outputs = b"timestamp,actual_digital_output_bits,runtime_state,input_int_register_30,"
        assert _rtde_call(sock, "O", freq + outputs) == ("O", b"\x01DOUBLE,UINT64,UINT32,INT32")
        inputs = b"standard_digital_output_mask,standard_digital_output,input_int_register_30"
        assert _rtde_call(sock, "I", inputs) == ("I", b"\x01UINT8,UINT8,INT32")
        assert _rtde_call(sock, "I", b"actual_q") == ("I", b"\x00NOT_FOUND")
        assert _rtde_call(sock, "S") == ("S", b"\x01")
        _rtde_send(sock, "U", struct.pack(">BBBi", 1, 0b1000, 0b1000, 42))
        samples = []
        for _ in range(200):
            msg_type, body = _rtde_read(sock)
            assert msg_type == "U"
            samples.append(struct.unpack(">BdQIi", body))
            if len(samples) > 30 and samples[-1][2] == 0b1000:
                break
        recipe_id, _, digital_bits, runtime_state, register_30 = samples[-1]
        assert (recipe_id, digital_bits, runtime_state, register_30) == (1, 0b1000, 1, 42)
        spacing = statistics.median(b[1] - a[1] for a, b in zip(samples[-26:-1], samples[-25:], strict=True))
        assert 0.006 <= spacing <= 0.010  # 125 Hz
        _rtde_send(sock, "P")
        while (reply := _rtde_read(sock))[0] == "U":
            pass
        assert reply == ("P", b"\x01")
    assert fake.io_changes() == [(3, True)]
    assert fake.snapshot()["digital_outputs"][3] is True


@pytest.mark.timeout(30)
def test_fake_is_fault_injectable_and_starts_at_ur5_home(fake: FakeURController):
    fake.reset()
    assert isinstance(fake, FaultInjectable)
    assert fake.supported_faults == {"drop_connection", "no_answer", "protective_stop", "emergency_stop"}
    with pytest.raises(ValueError):
        fake.inject("rmi_error")
    # UR5 DH forward kinematics of q = [0, -90, 90, -90, -90, 0] deg: the tool points down at
    # x = a3 - d5 = -0.4869 m, y = -d4 = -0.10915 m, z = d1 - a2 - d6 = 0.431859 m
    expected = make_X([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], [-0.4869, -0.10915, 0.431859])
    X = fake.X_base_tool()
    assert np.allclose(X, expected, atol=1e-12)
    snap = fake.snapshot()
    assert snap["q"] == pytest.approx(list(Q_HOME), abs=1e-12)
    assert snap["program_running"] is False
    assert snap["digital_outputs"] == [False] * 8


@pytest.mark.timeout(30)
def test_fake_serves_ur_rtde_default_receive_recipe(fake):
    """RTDEReceiveInterface with its default variable list: every name is served with the right type."""
    import rtde_receive

    fake.reset()
    receive = rtde_receive.RTDEReceiveInterface(HOST)
    try:
        assert receive.isConnected()
        assert receive.getActualQ() == pytest.approx(list(Q_HOME), abs=1e-12)
        assert receive.getTargetQ() == pytest.approx(list(Q_HOME), abs=1e-12)
        assert receive.getActualTCPPose() == pytest.approx(
            [-0.4869, -0.10915, 0.431859, math.pi / math.sqrt(2), math.pi / math.sqrt(2), 0.0], abs=1e-9
        )
        assert receive.getActualTCPSpeed() == [0.0] * 6
        assert receive.getRobotMode() == 7  # RUNNING
        assert receive.getSafetyMode() == 1  # NORMAL
        assert receive.getSafetyStatusBits() == 1  # normal mode bit only
        assert receive.getRuntimeState() == 1  # STOPPED: no program yet
        assert receive.getRobotStatus() == 1  # powered, no program running
        assert receive.getActualDigitalOutputBits() == 0
        assert receive.getJointMode() == [253] * 6
        assert receive.getActualMainVoltage() == 48.0
        assert receive.getPayload() == 0.0
        t0 = receive.getTimestamp()
        time.sleep(0.2)
        assert receive.getTimestamp() - t0 == pytest.approx(0.2, abs=0.05)
    finally:
        receive.disconnect()


@pytest.mark.timeout(30)
def test_fake_dashboard_answers_ur_rtde_dashboard_client(fake):
    import dashboard_client

    fake.reset()
    client = dashboard_client.DashboardClient(HOST)
    client.connect()
    try:
        assert client.polyscopeVersion() == "3.15.8.106339"
        assert client.robotmode() == "Robotmode: RUNNING"
        assert client.safetystatus() == "Safetystatus: NORMAL"
        assert client.running() is False
        assert client.getRobotModel() == "UR5"
        client.stop()  # "Stopped" even when nothing runs, as ur-rtde's control interface expects
        client.unlockProtectiveStop()  # nothing to unlock: still "Protective stop releasing"
        for command, reply in [
            ("pause", "Failed to execute: pause"),  # nothing is running
            ("load /programs/weld.urp", "Loading program: /programs/weld.urp"),
            ("get loaded program", "Loaded program: /programs/weld.urp"),
            ("play", "Failed to execute: play"),  # the fake cannot run .urp files
            ("make coffee", "could not understand: 'make coffee'"),
        ]:
            client.send(command + "\n")
            assert client.receive() == reply
    finally:
        client.disconnect()


# ------------------------------------------------------------------------------------------- the driver


@pytest.mark.timeout(30)
def test_commanded_target_and_io_reach_the_fake_exactly(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    target = offset(X0, dx=0.03, dy=-0.02, dz=0.01)
    robot.move_linear(target, speed_m_s=0.2, accel_m_s2=1.0, timeout_s=10)
    moves = [e for e in fake.events() if e["kind"] == "move_linear"]
    assert len(moves) == 1
    assert moves[0]["speed"] == 0.2
    assert moves[0]["accel"] == 1.0
    assert moves[0]["asynchronous"] is True
    (commanded,) = fake.commanded_targets()
    assert np.allclose(commanded, target, atol=1e-12)
    assert np.allclose(fake.X_base_tool(), target, atol=1e-9)
    robot.set_digital_output(2, True)
    robot.set_digital_output(5, True)
    robot.set_digital_output(2, False)
    assert fake.io_changes() == [(2, True), (5, True), (2, False)]
    assert robot.state().digital_outputs == (False, False, False, False, False, True, False, False)


@pytest.mark.timeout(30)
def test_move_linear_takes_the_trapezoid_time(robot_and_fake):
    robot, fake = robot_and_fake
    # 0.1 m at 0.2 m/s with 1 m/s^2: 0.2 s up, 0.3 s cruise, 0.2 s down = 0.7 s of motion
    target = offset(robot.get_X_base_tool(), dz=-0.1)
    t0 = time.monotonic()
    robot.move_linear(target, speed_m_s=0.2, accel_m_s2=1.0, timeout_s=10)
    assert time.monotonic() - t0 >= 0.7 - 0.02
    assert_pose_close(robot.get_X_base_tool(), target)
    # the joints moved with the tool: the fake's q reproduces the pose through the UR5 kinematics
    q = np.array(fake.snapshot()["q"])
    assert np.allclose(Arm("UR5").fk(q), target, atol=1e-9)


@pytest.mark.timeout(40)
def test_fake_streams_200_pose_blended_path_and_arrives_at_last_pose(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    # a 60 mm long S-curve in x/y with the tool tilting by up to 10 deg about base x: 200 waypoints 0.3 mm apart
    path = []
    for i in range(1, 201):
        s = i / 200
        X = offset(X0, dx=0.06 * s, dy=0.01 * math.sin(2 * math.pi * s))
        tilt = math.radians(10.0) * s
        c, n = math.cos(tilt), math.sin(tilt)
        X[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, c, -n], [0.0, n, c]]) @ X0[:3, :3]
        path.append(X)
    done: list[int] = []
    robot.stream_path(path, speed_m_s=0.1, blend_m=0.0001, accel_m_s2=1.0, timeout_s=30, on_progress=done.append)
    assert done == list(range(200))
    final = robot.get_X_base_tool()
    assert np.linalg.norm(final[:3, 3] - path[-1][:3, 3]) < PATH_ROUNDING_M
    assert rotation_angle_rad(final, path[-1]) < PATH_ROUNDING_RAD
    (event,) = [e for e in fake.events() if e["kind"] == "path"]
    assert len(event["poses"]) == 200
    assert event["blends"] == [0.0001] * 199 + [0.0]
    assert event["speeds"] == [0.1] * 200
    received = fake.commanded_targets()
    assert len(received) == 200
    for X_sent, X_got in zip(path, received, strict=True):
        assert np.linalg.norm(X_sent[:3, 3] - X_got[:3, 3]) < PATH_ROUNDING_M
        assert rotation_angle_rad(X_sent, X_got) < PATH_ROUNDING_RAD


@pytest.mark.timeout(30)
def test_unreachable_target_is_rejected(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    with pytest.raises(MotionRejected):
        robot.move_linear(offset(X0, dx=-1.5), speed_m_s=0.25, timeout_s=10)
    assert any("no inverse kinematics solution" in e for e in fake.errors())
    assert_pose_close(robot.get_X_base_tool(), X0)  # never moved
    # the driver restarts the control script for the next motion
    robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.25, timeout_s=10)
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))


@pytest.mark.timeout(30)
def test_bad_motion_parameters_are_refused_before_sending(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    with pytest.raises(MotionRejected):
        robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.0)
    with pytest.raises(MotionRejected):
        robot.move_linear(offset(X0, dz=0.01), speed_m_s=3.5)
    bad = offset(X0, dz=0.01)
    bad[0, 0] = 2.0
    with pytest.raises(MotionRejected):
        robot.move_linear(bad, speed_m_s=0.1)
    assert fake.commanded_targets() == []


@pytest.mark.timeout(30)
def test_protective_stop_unlock_then_move(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    fake.inject("protective_stop")
    with pytest.raises(ProtectiveStop):
        robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.1, timeout_s=5)
    time.sleep(0.5)  # the fake, like a CB3, refuses an unlock right after the stop
    robot.unlock_protective_stop()
    assert robot.state().mode == RobotMode.IDLE
    robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.1, timeout_s=10)
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))


@pytest.mark.timeout(30)
def test_emergency_stop_needs_release_and_power_on(robot_and_fake):
    robot, fake = robot_and_fake
    fake.inject("emergency_stop")
    assert fake.snapshot()["robot_mode"] == 3  # POWER_OFF
    fake.clear_faults()  # button released: still latched until powered on
    deadline = time.monotonic() + 2.0
    while not robot.state().emergency_stop and time.monotonic() < deadline:
        time.sleep(0.01)
    assert robot.state().mode == RobotMode.EMERGENCY_STOP
    import dashboard_client

    client = dashboard_client.DashboardClient(HOST)
    client.connect()
    try:
        client.powerOn()
        client.brakeRelease()
    finally:
        client.disconnect()
    deadline = time.monotonic() + 2.0
    while robot.state().mode != RobotMode.IDLE and time.monotonic() < deadline:
        time.sleep(0.01)
    assert robot.state().mode == RobotMode.IDLE


def dashboard_commands(fake: FakeURController) -> list[tuple[str, str]]:
    """Every dashboard command the fake received, with its reply, in order."""
    return [(e["command"], e["reply"]) for e in fake.events() if e["kind"] == "dashboard"]


def event_time(fake: FakeURController, kind: str) -> float:
    (t,) = [e["t"] for e in fake.events() if e["kind"] == kind]
    return float(t)


@pytest.mark.timeout(30)
def test_reset_faults_after_an_emergency_stop_powers_on_and_releases_the_brakes_once_the_button_is_released(
    robot_and_fake,
):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    fake.inject("emergency_stop")
    deadline = time.monotonic() + 2.0
    while not robot.state().emergency_stop and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(EmergencyStop, match="still engaged"):  # the button is still pressed
        robot.reset_faults(timeout_s=5.0)
    assert fake.snapshot()["robot_mode"] == 3  # POWER_OFF
    assert dashboard_commands(fake) == [
        ("close safety popup", "closing safety popup"),
        ("power on", "Failed to execute: power on"),
    ]
    fake.clear_faults()  # the button is released: the stop stays latched, the arm powered off
    assert robot.state().mode == RobotMode.EMERGENCY_STOP
    robot.reset_faults(timeout_s=10.0)
    assert [c for c, _reply in dashboard_commands(fake)[2:]] == ["close safety popup", "power on", "brake release"]
    snap = fake.snapshot()
    assert (snap["robot_mode"], snap["emergency_stop"], snap["program_running"]) == (7, False, True)
    assert robot.state().mode == RobotMode.IDLE
    # the arm booted (0.5 s) before the brakes were released (0.5 s), and the control script came after both
    powered_on, released = event_time(fake, "powered_on"), event_time(fake, "brakes_released")
    assert powered_on - event_time(fake, "power_on") >= 0.5 and released - event_time(fake, "brake_release") >= 0.5
    programs = [e["t"] for e in fake.events() if e["kind"] == "program"]  # at connect, then after the release
    assert len(programs) == 2 and programs[1] >= released
    robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.1, timeout_s=10)
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))


@pytest.mark.timeout(30)
def test_reset_faults_unlocks_a_protective_stop_as_soon_as_the_controller_allows_it(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    robot.reset_faults()  # nothing to recover: no dashboard command
    assert dashboard_commands(fake) == []
    fake.inject("protective_stop")
    deadline = time.monotonic() + 2.0
    while not robot.state().protective_stop and time.monotonic() < deadline:
        time.sleep(0.01)
    robot.reset_faults(timeout_s=10.0)  # at once: the fake, like a CB3, refuses the unlock for 0.5 s
    commands = dashboard_commands(fake)
    assert commands[0] == ("close safety popup", "closing safety popup")
    assert [c for c, _reply in commands[1:]] == ["unlock protective stop"] * (len(commands) - 1)
    assert commands[1][1].startswith("Cannot unlock protective stop until 0.5s after occurrence")
    assert commands[-1][1] == "Protective stop releasing"
    waited = event_time(fake, "protective_stop_unlocked") - event_time(fake, "protective_stop")
    assert 0.5 <= waited < 0.5 + 1.0  # asked again every 0.25 s: accepted soon after the delay, not at the timeout
    snap = fake.snapshot()
    assert (snap["protective_stop"], snap["robot_mode"], snap["program_running"]) == (False, 7, True)
    robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.1, timeout_s=10)
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))


@pytest.mark.timeout(30)
def test_protective_stop_during_the_path_upload_ends_the_path_at_once_and_reset_faults_reconnects(robot_and_fake):
    """ur-rtde's moveL(path) waits without a bound for its script to start; a controller in a protective stop never
    starts it (the fake stops as the path's script arrives): the driver must answer at once, keep reporting the
    state while it does, and recover on reset_faults without the abandoned upload ever moving the arm."""
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    path = [offset(X0, dz=0.002 * i) for i in range(1, 6)]
    fake.inject("protective_stop", on_next_program=True)
    readings: list[tuple[float, RobotMode]] = []
    done = threading.Event()

    def poll() -> None:
        while not done.is_set():
            t = time.monotonic()
            mode = robot.state().mode
            readings.append((time.monotonic() - t, mode))
            time.sleep(0.01)

    poller = threading.Thread(target=poll, daemon=True)
    started = time.monotonic()
    poller.start()
    try:
        with pytest.raises(ProtectiveStop, match="protective stop during the path upload"):
            robot.stream_path(path, speed_m_s=0.1, timeout_s=10)
        failed_after = time.monotonic() - started
        time.sleep(0.1)
    finally:
        done.set()
        poller.join(5.0)
    assert failed_after < 1.0  # not the 5 s command timeout
    assert max(latency for latency, _mode in readings) < 0.3  # state() never waited on the stuck upload
    assert readings[-1][1] is RobotMode.PROTECTIVE_STOP
    robot.reset_faults(timeout_s=10.0)
    robot.stream_path(path, speed_m_s=0.1, timeout_s=10)
    assert_pose_close(robot.get_X_base_tool(), path[-1])
    time.sleep(0.1)
    assert sum(e["kind"] == "path" for e in fake.events()) == 1  # the new script's path only


@pytest.mark.timeout(30)
def test_a_controller_silent_from_the_path_upload_on_ends_stream_path_within_a_second(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    fake.inject("no_answer", on_next_program=True)
    started = time.monotonic()
    with pytest.raises(ConnectionLost, match=r"stood still .* during the path upload"):
        robot.stream_path([offset(X0, dz=0.002 * i) for i in range(1, 6)], speed_m_s=0.1, timeout_s=10)
    assert time.monotonic() - started < 1.0  # 0.5 s without data, not the 5 s command timeout
    started = time.monotonic()
    with pytest.raises(ConnectionLost, match="stopped"):
        robot.set_digital_output(0, False)  # the fault's arc-off is told at once, not after the IO write's wait
    assert time.monotonic() - started < 0.2
    fake.clear_faults()
    robot.connect()  # as the acknowledgement does
    robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.2, timeout_s=5)
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))


@pytest.mark.timeout(30)
def test_connect_restores_the_speed_slider_a_lost_path_upload_left_at_zero(robot_and_fake):
    import rtde_io

    robot, fake = robot_and_fake
    io = rtde_io.RTDEIOInterface(HOST)  # as a worker killed while its path upload held the arm
    io.setSpeedSlider(0.0)
    io.disconnect()
    assert fake.snapshot()["speed_fraction"] == 0.0
    robot.connect()
    assert fake.snapshot()["speed_fraction"] == 1.0
    X0 = robot.get_X_base_tool()
    robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.2, timeout_s=5)  # moves: not held at 0
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))


@pytest.mark.timeout(30)
def test_motion_timeout_stops_the_robot(robot_and_fake):
    robot, fake = robot_and_fake
    X0 = robot.get_X_base_tool()
    # 0.1 m at 0.05 m/s needs 2.1 s; give it 0.6 s
    with pytest.raises(MotionTimeout):
        robot.move_linear(offset(X0, dx=0.1), speed_m_s=0.05, accel_m_s2=0.5, timeout_s=0.6)
    deadline = time.monotonic() + 2.0
    while fake.snapshot()["moving"] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not fake.snapshot()["moving"]
    travelled = robot.get_X_base_tool()[0, 3] - X0[0, 3]
    assert 0.01 < travelled < 0.06
    assert any(e["kind"] == "stop" for e in fake.events())


@pytest.mark.timeout(20)
def test_missing_ur_rtde_raises_driver_not_installed(monkeypatch):
    monkeypatch.setitem(sys.modules, "rtde_control", None)
    with pytest.raises(DriverNotInstalled, match="pip install"):
        URRobot(HOST).connect()


@pytest.mark.timeout(20)
def test_connect_to_nothing_raises_connection_lost():
    robot = URRobot(UNUSED_HOST, connect_timeout_s=3.0)
    t0 = time.monotonic()
    with pytest.raises(ConnectionLost):
        robot.connect()
    assert time.monotonic() - t0 < 5.0
    robot.disconnect()
    robot.disconnect()


@pytest.mark.timeout(20)
def test_driver_refuses_a_non_standard_rtde_port():
    with pytest.raises(ValueError):
        URRobot(HOST, rtde_port=30005)


@pytest.mark.timeout(45)
def test_two_fakes_on_two_loopback_addresses(fake):
    """A CB3 UR5 and an e-Series UR5e (500 Hz RTDE), on two loopback addresses, moved at the same time."""
    fake.reset()
    with FakeURController(HOST_B, model="UR5e", controller_version=(5, 15, 0, 123456)) as fake_b:
        robot_a = URRobot(HOST, name="ur-a")
        robot_b = URRobot(HOST_B, name="ur-b")
        robot_a.connect()
        robot_b.connect()
        try:
            X_a = robot_a.get_X_base_tool()
            X_b = robot_b.get_X_base_tool()
            # different kinematics, different start: x = a3 - d5, y = -d4, z = d1 - a2 - d6 (UR5, then UR5e)
            assert X_a[:3, 3] == pytest.approx([-0.39225 - 0.09465, -0.10915, 0.089159 + 0.425 - 0.0823], abs=1e-12)
            assert X_b[:3, 3] == pytest.approx([-0.3922 - 0.0997, -0.1333, 0.1625 + 0.425 - 0.0996], abs=1e-12)
            target_a = offset(X_a, dx=0.04)
            target_b = offset(X_b, dy=0.03)
            errors: list[BaseException] = []

            def move_a() -> None:
                try:
                    robot_a.move_linear(target_a, speed_m_s=0.1, timeout_s=10)
                except BaseException as err:  # reported below
                    errors.append(err)

            thread = threading.Thread(target=move_a)
            thread.start()
            robot_b.move_linear(target_b, speed_m_s=0.1, timeout_s=10)
            thread.join(15)
            assert not errors
            assert_pose_close(robot_a.get_X_base_tool(), target_a)
            assert_pose_close(robot_b.get_X_base_tool(), target_b)
            (got_a,) = fake.commanded_targets()
            (got_b,) = fake_b.commanded_targets()
            assert np.allclose(got_a, target_a, atol=1e-12)
            assert np.allclose(got_b, target_b, atol=1e-12)
        finally:
            robot_a.disconnect()
            robot_b.disconnect()
