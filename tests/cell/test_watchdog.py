"""cell.watchdog: what stops the cell (read from the devices' own states), the answer deadline while the robot
moves, one fault per job, and the readings kept for the status view. Against stand-in devices whose answers the
test sets."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from cell.machine import CellState
from cell.watchdog import DeviceReadings, DeviceWatchdog, read_devices
from drivers.errors import ConnectionLost
from drivers.protocols import RobotMode, RobotState, TrackStatus

S = CellState


def robot_state(**changes: Any) -> RobotState:
    values: dict[str, Any] = dict(mode=RobotMode.IDLE, X_base_tool=np.eye(4), is_moving=False, protective_stop=False,
                                  emergency_stop=False, digital_outputs=(False,) * 8, message="")  # fmt: skip
    values.update(changes)
    return RobotState(**values)


TRACK_OK = TrackStatus(position_m=0.5, enabled=True, moving=False, in_position=True, fault=False)


class Robot:
    name = "arm"

    def __init__(self) -> None:
        self.answer: RobotState | Exception = robot_state()
        self.hang = threading.Event()
        self.calls = 0

    def state(self) -> RobotState:
        self.calls += 1
        if self.hang.is_set():
            time.sleep(2.0)
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


class Track:
    name = "rail"

    def __init__(self) -> None:
        self.answer: TrackStatus | Exception = TRACK_OK

    def status(self) -> TrackStatus:
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


@pytest.mark.parametrize(
    ("robot", "track", "problem"),
    [
        (robot_state(), TRACK_OK, None),
        (robot_state(emergency_stop=True, message="E-stop"), TRACK_OK, "arm: emergency stop (E-stop)"),
        (robot_state(protective_stop=True, message="bump"), TRACK_OK, "arm: protective stop (bump)"),
        (robot_state(mode=RobotMode.FAULT, message="servo"), TRACK_OK, "arm: fault (servo)"),
        (ConnectionLost("gone"), TRACK_OK, "arm unreachable: ConnectionLost: gone"),
        (robot_state(), TrackStatus(0.25, True, False, False, True, 7), "rail: fault latched (code 7) at 0.2500 m"),
        (robot_state(), ConnectionLost("cable"), "rail unreachable: ConnectionLost: cable"),
    ],
)
def test_what_stops_the_cell(robot: Any, track: Any, problem: str | None) -> None:
    r, t = Robot(), Track()
    r.answer, t.answer = robot, track
    readings = read_devices(SimpleNamespace(robot=r, track=t))  # type: ignore[arg-type]
    assert readings.problem("arm", "rail") == problem
    if isinstance(robot, Exception):
        assert readings.track is None  # not read once the robot is known lost


def make(robot: Robot, state: CellState) -> tuple[DeviceWatchdog, list[str]]:
    faults: list[str] = []
    dog = DeviceWatchdog(SimpleNamespace(robot=robot, track=None), state=lambda: state,  # type: ignore[arg-type]
                         fault_now=faults.append, period_s=0.02, answer_timeout_s=0.3)  # fmt: skip
    return dog, faults


@pytest.mark.timeout(20)
def test_a_device_that_hangs_while_the_robot_moves_is_a_fault_once() -> None:
    robot = Robot()
    robot.hang.set()
    dog, faults = make(robot, S.WELDING)
    t0 = time.monotonic()
    dog.start()
    while not faults and time.monotonic() - t0 < 5.0:
        time.sleep(0.01)
    assert faults == ["watchdog: no status from the robot or the track within 0.3 s"]
    assert 0.3 <= time.monotonic() - t0 < 1.5
    time.sleep(0.5)
    dog.stop()
    assert len(faults) == 1  # once per job


@pytest.mark.timeout(20)
def test_nothing_is_polled_while_paused_and_a_protective_stop_is_noticed_within_a_few_periods() -> None:
    robot = Robot()
    dog, faults = make(robot, S.PAUSED)
    dog.start()
    time.sleep(0.2)
    dog.stop()
    assert robot.calls == 0 and faults == []
    robot.answer = robot_state(protective_stop=True, message="bump")
    dog, faults = make(robot, S.DETECTING)
    dog.start()
    time.sleep(0.3)
    dog.stop()
    assert faults == ["watchdog: arm: protective stop (bump)"]
    assert isinstance(dog.last, DeviceReadings) and dog.last.robot is not None and dog.last.robot.protective_stop


def test_read_takes_fresh_readings_only_when_the_last_are_too_old_and_never_waits_for_a_hung_device() -> None:
    robot = Robot()
    dog, _ = make(robot, S.IDLE)
    first = dog.read(max_age_s=10.0)
    assert first is not None and first.robot is not None
    assert dog.read(max_age_s=10.0) is first and robot.calls == 1
    second = dog.read(max_age_s=0.0)
    assert second is not first and robot.calls == 2
    robot.hang.set()  # the next poll takes 2 s
    t0 = time.monotonic()
    assert dog.read(max_age_s=0.0, wait_s=0.2) is second  # the last readings, at once; their time says how old
    assert time.monotonic() - t0 < 0.5
    assert dog.read(max_age_s=0.0, wait_s=0.2) is second and robot.calls == 3  # one poll at a time


@pytest.mark.timeout(20)
def test_while_the_watchdog_polls_read_polls_nothing_beside_it_but_it_does_while_paused() -> None:
    robot = Robot()
    faults: list[str] = []
    state = {"now": S.WELDING}
    dog = DeviceWatchdog(SimpleNamespace(robot=robot, track=None), state=lambda: state["now"],  # type: ignore[arg-type]
                         fault_now=faults.append, period_s=30.0, answer_timeout_s=0.3)  # fmt: skip
    dog.start()  # its first poll comes after 30 s
    try:
        assert dog.read(max_age_s=0.0) is None and robot.calls == 0
        state["now"] = S.PAUSED  # the watchdog does not poll while paused: the view must not go stale
        readings = dog.read(max_age_s=0.0)
        assert readings is not None and robot.calls == 1
    finally:
        dog.stop()
    assert faults == []
