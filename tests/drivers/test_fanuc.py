"""FanucRobot and the RMI client against the fake RMI controller (loopback), plus the Robot contract."""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections.abc import Coroutine, Iterator
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.errors import (
    ConnectionLost,
    DeviceFault,
    EmergencyStop,
    MotionAborted,
    MotionRejected,
    ProtectiveStop,
    RMIError,
    SystemFault,
)
from drivers.fanuc import FanucRobot
from drivers.fanuc_rmi import (
    MAX_INSTRUCTIONS_IN_FLIGHT,
    ErrorID,
    LinearMotion,
    RMIClient,
    describe_error_id,
)
from drivers.protocols import RobotMode
from perception.transforms import X_from_xyzwpr_mm_deg, make_X, rotation_angle_rad
from sim_fakes.fake_fanuc import DEFAULT_START_XYZWPR_MM_DEG, FakeFanucController
from sim_fakes.faults import FaultInjectable
from tests.drivers.robot_contract import RobotContract, assert_pose_close, offset
from tests.leftovers import assert_no_threads_left

OUR_THREAD_PREFIXES = ("fanuc-rmi", "fake-fanuc")


@pytest.fixture(autouse=True)
def no_leftover_threads() -> Iterator[None]:
    yield
    assert_no_threads_left(OUR_THREAD_PREFIXES)


@pytest.fixture
def fake() -> Iterator[FakeFanucController]:
    with FakeFanucController() as controller:
        yield controller


@pytest.fixture
def robot(fake: FakeFanucController) -> Iterator[FanucRobot]:
    arm = FanucRobot("127.0.0.1", port=fake.port, timeout_s=1.0, status_poll_s=0.02)
    arm.connect()
    try:
        yield arm
    finally:
        arm.disconnect()


class TestFanucRobotContract(RobotContract):
    @pytest.fixture
    def robot_and_fake(self, robot: FanucRobot, fake: FakeFanucController) -> Iterator[tuple[FanucRobot, Any]]:
        assert isinstance(fake, FaultInjectable)
        yield robot, fake


# ---------------------------------------------------------------------------------------------- helpers
def run(coro: Coroutine[Any, Any, Any], timeout_s: float = 15.0) -> Any:
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


async def initialized_client(fake: FakeFanucController) -> RMIClient:
    client = RMIClient("127.0.0.1", fake.port, timeout_s=1.0)
    await client.connect()
    await client.initialize()
    return client


def start_plus(dx_mm: float = 0.0, dy_mm: float = 0.0, dz_mm: float = 0.0) -> tuple[float, ...]:
    x, y, z, w, p, r = DEFAULT_START_XYZWPR_MM_DEG
    return (x + dx_mm, y + dy_mm, z + dz_mm, w, p, r)


def after(delay_s: float, fn: Any, *args: Any) -> threading.Timer:
    timer = threading.Timer(delay_s, fn, args=args)
    timer.start()
    return timer


# ---------------------------------------------------------------------------------------------- streaming
@pytest.mark.timeout(30)
def test_stream_of_200_poses_keeps_at_most_8_in_flight_and_arrives_in_order(
    robot: FanucRobot, fake: FakeFanucController
) -> None:
    X0 = robot.get_X_base_tool()
    path = [offset(X0, dx=0.001 * i, dy=0.0005 * (i % 2)) for i in range(1, 201)]
    done: list[int] = []
    robot.stream_path(path, speed_m_s=1.0, blend_m=0.001, timeout_s=20, on_progress=done.append)

    records = fake.records()
    assert all(r.error_id == 0 for r in records), [r for r in records if r.error_id]
    assert [r.sequence_id for r in records] == list(range(1, 201))
    assert fake.max_in_flight() == MAX_INSTRUCTIONS_IN_FLIGHT  # streamed ahead, never past the limit
    assert max(r.in_flight for r in records) <= MAX_INSTRUCTIONS_IN_FLIGHT
    for record, X in zip(records, path, strict=True):
        assert np.allclose(record.xyzwpr_mm_deg[:3], X[:3, 3] * 1000.0, atol=1e-3)
        assert record.speed == 1000.0 and record.speed_type == "mmSec"
    assert [r.term_type for r in records] == ["CNT"] * 199 + ["FINE"]
    assert {r.term_value for r in records[:-1]} == {10}  # 1 mm blend -> CNT10
    assert done == list(range(200))
    assert_pose_close(robot.get_X_base_tool(), path[-1])


@pytest.mark.timeout(20)
def test_xyzwpr_conversion_happens_at_the_boundary(robot: FanucRobot, fake: FakeFanucController) -> None:
    X0 = robot.get_X_base_tool()
    R_turn = Rotation.from_euler("z", 30.0, degrees=True).as_matrix()
    target = make_X(R_turn @ X0[:3, :3], X0[:3, 3] + [0.02, -0.01, 0.03])
    robot.move_linear(target, speed_m_s=0.5, timeout_s=10)

    record = fake.records()[-1]
    # what went on the wire is the same pose in mm / fixed-axis W, P, R degrees
    assert np.allclose(record.xyzwpr_mm_deg[:3], target[:3, 3] * 1000.0, atol=1e-3)
    assert rotation_angle_rad(X_from_xyzwpr_mm_deg(record.xyzwpr_mm_deg), target) < 1e-6
    w_deg, p_deg, r_deg = record.xyzwpr_mm_deg[3:]
    assert abs(abs(w_deg) - 180.0) < 1e-4 and abs(p_deg) < 1e-4 and abs(r_deg - 30.0) < 1e-4
    # and what comes back is converted the other way
    assert_pose_close(robot.get_X_base_tool(), target)
    assert_pose_close(X_from_xyzwpr_mm_deg(fake.xyzwpr_mm_deg()), target)


@pytest.mark.timeout(20)
def test_invalid_pose_or_speed_is_refused_before_sending(robot: FanucRobot, fake: FakeFanucController) -> None:
    X0 = robot.get_X_base_tool()
    bad = X0.copy()
    bad[:3, :3] *= -1.0  # a reflection, not a rotation
    with pytest.raises(MotionRejected):
        robot.move_linear(bad, speed_m_s=0.1)
    with pytest.raises(MotionRejected):
        robot.move_linear(offset(X0, dx=0.01), speed_m_s=0.0001)  # rounds to 0 mm/s
    assert fake.records() == []


# ---------------------------------------------------------------------------------------------- raw rules
@pytest.mark.timeout(20)
def test_ninth_instruction_in_flight_gets_rmit_028(fake: FakeFanucController) -> None:
    async def scenario() -> None:
        client = await initialized_client(fake)
        try:
            sent = [
                await client.submit(LinearMotion(start_plus(dx_mm=20.0 * (i + 1)), speed_mm_s=10), respect_window=False)
                for i in range(MAX_INSTRUCTIONS_IN_FLIGHT + 1)
            ]
            seq9, fut9 = sent[-1]
            assert seq9 == 9
            with pytest.raises(RMIError) as info:
                await RMIClient.wait_instruction(seq9, fut9, timeout_s=2.0)
            assert info.value.code == ErrorID.WAIT_FOR_INSTRUCTION_DONE == 2556956
            assert "RMIT-028" in describe_error_id(info.value.code)
            assert not any(fut.done() for _, fut in sent[:-1])  # the first 8 are still moving
            await client.abort()
            assert all(isinstance(fut.exception(), MotionAborted) for _, fut in sent[:-1])
        finally:
            await client.disconnect()

    run(scenario())
    assert [r.error_id for r in fake.records()] == [0] * 8 + [2556956]
    assert fake.max_in_flight() == 8


@pytest.mark.timeout(20)
def test_client_window_never_lets_a_ninth_out(fake: FakeFanucController) -> None:
    async def scenario() -> None:
        client = await initialized_client(fake)
        try:
            moves = [LinearMotion(start_plus(dy_mm=2.0 * (i + 1)), speed_mm_s=400) for i in range(30)]
            done: list[int] = []
            await client.run_instructions(moves, timeout_s=10.0, on_complete=done.append)
            assert done == list(range(30))
        finally:
            await client.disconnect()

    run(scenario())
    assert all(r.error_id == 0 for r in fake.records())
    assert fake.max_in_flight() == 8


@pytest.mark.timeout(30)
def test_an_abort_mid_stream_ends_it_with_motion_aborted_and_nothing_is_sent_after(fake: FakeFanucController) -> None:
    # the abort frees the in-flight window: the stream must not send into it. (The rarer case, an instruction
    # already on the wire when the abort lands and answered RMIT-009 NOT_RUNNING, is not reproducible with
    # the fake's timing; the client maps it to MotionAborted too.)
    sent_before_abort: list[int] = []

    async def scenario() -> None:
        client = await initialized_client(fake)
        aborting: list[asyncio.Task[None]] = []

        def on_complete(i: int) -> None:
            if i == 2 and not aborting:
                sent_before_abort.append(len(fake.records()))
                aborting.append(asyncio.ensure_future(client.abort()))

        try:
            moves = [LinearMotion(start_plus(dy_mm=2.0 * (i + 1)), speed_mm_s=100) for i in range(40)]
            with pytest.raises(MotionAborted):
                await client.run_instructions(moves, timeout_s=20.0, on_complete=on_complete)
            await aborting[0]
        finally:
            await client.disconnect()

    run(scenario())
    records = fake.records()
    assert sent_before_abort and len(records) <= sent_before_abort[0] + 1 < 40
    assert not any(r.error_id for r in records), [r for r in records if r.error_id]


@pytest.mark.timeout(20)
def test_sequence_gap_gets_rmit_029_and_holds_until_reset(fake: FakeFanucController) -> None:
    async def scenario() -> None:
        client = await initialized_client(fake)
        try:
            seq1, fut1 = await client.submit(LinearMotion(start_plus(dx_mm=5.0), speed_mm_s=100))
            seq3, fut3 = await client.submit(LinearMotion(start_plus(dx_mm=10.0), speed_mm_s=100), sequence_id=3)
            with pytest.raises(RMIError) as info:
                await RMIClient.wait_instruction(seq3, fut3, timeout_s=2.0)
            assert info.value.code == ErrorID.INVALID_SEQUENCE_ID == 2556957
            # HOLD: even the right id is refused now ...
            seq2, fut2 = await client.submit(LinearMotion(start_plus(dx_mm=10.0), speed_mm_s=100))
            assert seq2 == 2
            with pytest.raises(RMIError) as held:
                await RMIClient.wait_instruction(seq2, fut2, timeout_s=2.0)
            assert held.value.code == ErrorID.HOLD
            # ... while what was queued before the gap still runs to completion
            await RMIClient.wait_instruction(seq1, fut1, timeout_s=2.0)
            await client.reset()
            seq2b, fut2b = await client.submit(LinearMotion(start_plus(dx_mm=10.0), speed_mm_s=100), sequence_id=2)
            await RMIClient.wait_instruction(seq2b, fut2b, timeout_s=2.0)
        finally:
            await client.disconnect()

    run(scenario())
    assert [(r.sequence_id, r.error_id) for r in fake.records()] == [
        (1, 0),
        (3, 2556957),
        (2, ErrorID.HOLD),
        (2, 0),
    ]


@pytest.mark.timeout(20)
def test_cnt_move_is_not_completed_until_the_next_instruction_arrives(fake: FakeFanucController) -> None:
    async def scenario() -> None:
        client = await initialized_client(fake)
        try:
            completed: list[int] = []
            cnt_target = start_plus(dx_mm=10.0)
            seq1, fut1 = await client.submit(
                LinearMotion(cnt_target, speed_mm_s=200, term_type="CNT", term_value=50)
            )  # 10 mm at 200 mm/s: there after 50 ms
            fut1.add_done_callback(lambda f: completed.append(1))
            await asyncio.sleep(0.4)
            assert np.allclose(fake.xyzwpr_mm_deg()[:3], cnt_target[:3], atol=1e-6)  # arrived ...
            assert not fut1.done() and fake.in_flight() == 1  # ... and waits to know where to blend
            seq2, fut2 = await client.submit(LinearMotion(start_plus(dx_mm=20.0), speed_mm_s=200))
            fut2.add_done_callback(lambda f: completed.append(2))
            await RMIClient.wait_instruction(seq1, fut1, timeout_s=0.5)
            assert completed == [1]  # answered as soon as the next one arrived, not when it finished
            await RMIClient.wait_instruction(seq2, fut2, timeout_s=2.0)
            assert completed == [1, 2]
        finally:
            await client.disconnect()

    run(scenario())
    assert np.allclose(fake.xyzwpr_mm_deg()[:3], start_plus(dx_mm=20.0)[:3], atol=1e-6)


@pytest.mark.timeout(20)
def test_fake_refuses_bad_instruction_fields(fake: FakeFanucController) -> None:
    base = LinearMotion(start_plus(dx_mm=1.0), speed_mm_s=100).packet(0)

    async def scenario() -> list[int]:
        client = await initialized_client(fake)
        codes = []
        try:
            for change in (
                {"SpeedType": "furlongs"},
                {"Speed": 0},
                {"TermType": "SOMETIMES"},
                {"TermValue": 101},
                {"Position": {"X": 1.0}},
                {"Position": {**base["Position"], "X": 5000.0}},
                {"Instruction": "FRC_Teleport"},
            ):
                _seq, fut = await client.submit({**base, **change})
                codes.append(int((await asyncio.wait_for(fut, 2.0))["ErrorID"]))
        finally:
            await client.disconnect()
        return codes

    assert run(scenario()) == [
        ErrorID.INVALID_SPEED_TYPE,
        ErrorID.INVALID_SPEED_VALUE,
        ErrorID.INVALID_TERM_TYPE,
        ErrorID.INVALID_TERM_VALUE,
        ErrorID.INVALID_POSITION_DATA,
        ErrorID.INVALID_DESTINATION,
        ErrorID.INVALID_INSTRUCTION,
    ]


# ---------------------------------------------------------------------------------------------- faults
@pytest.mark.timeout(30)
def test_system_fault_surfaces_as_system_fault_and_latches_until_reset(
    robot: FanucRobot, fake: FakeFanucController
) -> None:
    X0 = robot.get_X_base_tool()
    timer = after(0.2, fake.inject, "system_fault")
    try:
        with pytest.raises(SystemFault):
            robot.move_linear(offset(X0, dx=0.2), speed_m_s=0.1, timeout_s=10)
    finally:
        timer.cancel()
    state = robot.state()
    assert state.mode == RobotMode.FAULT and not state.healthy
    assert "FRC_SystemFault" in state.message
    stopped_at = robot.get_X_base_tool()
    assert 0.005 < stopped_at[0, 3] - X0[0, 3] < 0.15  # halted part-way
    time.sleep(0.1)
    assert_pose_close(robot.get_X_base_tool(), stopped_at)
    with pytest.raises(SystemFault):  # latched: no motion until acknowledged
        robot.move_linear(offset(stopped_at, dz=0.01), speed_m_s=0.1, timeout_s=5)
    robot.reset_faults()
    assert robot.state().healthy
    robot.move_linear(offset(stopped_at, dz=0.01), speed_m_s=0.2, timeout_s=5)
    assert_pose_close(robot.get_X_base_tool(), offset(stopped_at, dz=0.01))


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    ("code", "is_rejection"),
    [(int(ErrorID.INTERNAL_SYSTEM_ERROR), False), (int(ErrorID.INVALID_DESTINATION), True)],
)
def test_rmi_error_code_surfaces_as_rmi_error(
    robot: FanucRobot, fake: FakeFanucController, code: int, is_rejection: bool
) -> None:
    X0 = robot.get_X_base_tool()
    fake.inject("rmi_error", code=code)
    with pytest.raises(RMIError) as info:
        robot.move_linear(offset(X0, dx=0.01), speed_m_s=0.2, timeout_s=5)
    assert info.value.code == code
    assert isinstance(info.value, MotionRejected) is is_rejection
    assert_pose_close(robot.get_X_base_tool(), X0)  # refused: nothing moved
    robot.move_linear(offset(X0, dx=0.01), speed_m_s=0.2, timeout_s=5)  # one-shot: the next one goes
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dx=0.01))


@pytest.mark.timeout(30)
def test_emergency_stop_during_motion_raises_and_needs_reset(robot: FanucRobot, fake: FakeFanucController) -> None:
    X0 = robot.get_X_base_tool()
    timer = after(0.2, fake.inject, "emergency_stop")
    try:
        with pytest.raises(EmergencyStop):
            robot.move_linear(offset(X0, dy=0.2), speed_m_s=0.1, timeout_s=10)
    finally:
        timer.cancel()
    assert robot.state().mode == RobotMode.EMERGENCY_STOP
    with pytest.raises(RMIError) as info:  # the button is still pressed
        robot.reset_faults()
    assert info.value.code == ErrorID.CANNOT_RESET
    fake.clear_faults()
    assert robot.state().mode == RobotMode.EMERGENCY_STOP  # released, but latched until reset
    robot.reset_faults()
    assert robot.state().healthy
    here = robot.get_X_base_tool()
    robot.move_linear(offset(here, dy=0.01), speed_m_s=0.2, timeout_s=5)
    assert_pose_close(robot.get_X_base_tool(), offset(here, dy=0.01))


@pytest.mark.timeout(30)
def test_protective_stop_blocks_motion_until_reset(robot: FanucRobot, fake: FakeFanucController) -> None:
    fake.inject("protective_stop")
    X0 = robot.get_X_base_tool()
    with pytest.raises(ProtectiveStop):
        robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.1, timeout_s=5)
    fake.clear_faults()
    robot.reset_faults()
    robot.move_linear(offset(X0, dz=0.01), speed_m_s=0.2, timeout_s=5)
    assert_pose_close(robot.get_X_base_tool(), offset(X0, dz=0.01))


@pytest.mark.timeout(30)
def test_an_alarm_that_pauses_the_program_mid_motion_is_a_fault_at_the_next_status_poll(
    robot: FanucRobot, fake: FakeFanucController
) -> None:
    # servo power stays on and the paused program leaves the instruction unanswered: only the status says so
    X0 = robot.get_X_base_tool()
    timer = after(0.3, lambda: fake.inject("alarm", text="UALM[2] welder fault input"))
    t0 = time.monotonic()
    try:
        with pytest.raises(DeviceFault, match=r"paused the RMI program during a motion \(RMIMotionStatus=2") as info:
            robot.move_linear(offset(X0, dy=0.2), speed_m_s=0.1, timeout_s=10)
    finally:
        timer.cancel()
    took_s = time.monotonic() - t0
    assert type(info.value) is DeviceFault  # not a MotionTimeout after the 10 s
    assert 0.3 <= took_s < 1.3  # the alarm, one status poll (20 ms), the abort: a second is plenty on a loaded host
    stopped_at = robot.get_X_base_tool()
    assert 0.005 < stopped_at[1, 3] - X0[1, 3] < 0.1  # halted where it was at 0.1 m/s
    assert robot.state().healthy  # servo power on, no safety stop: the alarm is on the pendant
    with pytest.raises(RMIError) as refused:  # RMI_MOVE cannot start again while the alarm stands
        robot.move_linear(offset(stopped_at, dz=0.01), speed_m_s=0.2, timeout_s=5)
    assert refused.value.code == ErrorID.INVALID_CONTROLLER_STATE
    robot.reset_faults()
    robot.move_linear(offset(stopped_at, dz=0.01), speed_m_s=0.2, timeout_s=5)
    assert_pose_close(robot.get_X_base_tool(), offset(stopped_at, dz=0.01))


@pytest.mark.timeout(30)
def test_stop_from_another_thread_aborts_the_motion(robot: FanucRobot, fake: FakeFanucController) -> None:
    X0 = robot.get_X_base_tool()
    timer = after(0.2, robot.stop)
    try:
        with pytest.raises(MotionAborted):
            robot.move_linear(offset(X0, dx=0.2), speed_m_s=0.1, timeout_s=10)
    finally:
        timer.cancel()
    stopped_at = robot.get_X_base_tool()
    assert 0.005 < stopped_at[0, 3] - X0[0, 3] < 0.15
    time.sleep(0.1)
    assert_pose_close(robot.get_X_base_tool(), stopped_at)
    assert robot.state().healthy


@pytest.mark.timeout(30)
def test_reconnect_after_connection_dropped_mid_motion(robot: FanucRobot, fake: FakeFanucController) -> None:
    X0 = robot.get_X_base_tool()
    timer = after(0.2, fake.inject, "drop_connection")
    try:
        with pytest.raises(ConnectionLost):
            robot.move_linear(offset(X0, dx=0.2), speed_m_s=0.1, timeout_s=10)
    finally:
        timer.cancel()
    with pytest.raises(ConnectionLost):  # refused while the fault is on
        robot.connect()
    fake.clear_faults()
    robot.connect()
    here = robot.get_X_base_tool()
    assert 0.005 < here[0, 3] - X0[0, 3] < 0.15  # the controller stopped when its client went away
    robot.move_linear(offset(here, dz=0.01), speed_m_s=0.2, timeout_s=5)
    assert_pose_close(robot.get_X_base_tool(), offset(here, dz=0.01))
    assert [r.sequence_id for r in fake.records()] == [1, 1]  # a fresh RMI_MOVE restarts at 1


@pytest.mark.timeout(10)
def test_connect_to_nothing_raises_connection_lost() -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        free_port = sock.getsockname()[1]
    arm = FanucRobot("127.0.0.1", port=free_port, timeout_s=0.5)
    with pytest.raises(ConnectionLost):
        arm.connect()
    with pytest.raises(ConnectionLost):
        arm.state()
    arm.disconnect()


@pytest.mark.timeout(10)
def test_fake_refuses_unknown_faults_and_non_loopback_hosts(fake: FakeFanucController) -> None:
    with pytest.raises(ValueError):
        fake.inject("meteor_strike")
    with pytest.raises(ValueError):
        fake.inject("rmi_error")  # needs code=
    with pytest.raises(ValueError):
        FakeFanucController(host="10.0.0.5")
