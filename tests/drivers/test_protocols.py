"""The device interfaces (drivers/protocols.py): which robot modes are healthy, and that every driver and fake
satisfies the Protocol it claims (checked at run time on the classes' attributes, nothing connects)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.fanuc import FanucRobot
from drivers.oakd import OakDCamera
from drivers.protocols import Camera, Robot, RobotMode, RobotState, Track, TrackStatus
from drivers.track import ModbusTrack
from drivers.ur import URRobot
from sim_fakes.fake_camera import FakeCamera


@pytest.mark.parametrize(
    ("mode", "healthy"),
    [
        (RobotMode.IDLE, True),
        (RobotMode.MOVING, True),
        (RobotMode.DISCONNECTED, False),
        (RobotMode.PROTECTIVE_STOP, False),
        (RobotMode.EMERGENCY_STOP, False),
        (RobotMode.FAULT, False),
    ],
)
def test_only_an_idle_or_moving_robot_is_healthy(mode: RobotMode, healthy: bool) -> None:
    state = RobotState(mode, np.eye(4), is_moving=mode is RobotMode.MOVING, protective_stop=False, emergency_stop=False)
    assert state.healthy is healthy
    assert (state.digital_outputs, state.message) == ((), "")


def test_the_modes_are_their_names_on_the_wire_and_in_files() -> None:
    assert [str(m) for m in RobotMode] == [
        "disconnected", "idle", "moving", "protective_stop", "emergency_stop", "fault",
    ]  # fmt: skip
    assert RobotMode("protective_stop") is RobotMode.PROTECTIVE_STOP


def test_a_track_status_has_no_fault_code_unless_given() -> None:
    st = TrackStatus(position_m=1.5, enabled=True, moving=False, in_position=True, fault=False)
    assert st.fault_code == 0
    with pytest.raises(AttributeError):
        st.position_m = 2.0  # type: ignore[misc]  # a snapshot: frozen


def test_every_driver_and_fake_is_the_device_it_claims_to_be() -> None:
    members = {
        Robot: ("name", "connect", "disconnect", "state", "get_X_base_tool", "move_linear", "stream_path",
                "set_digital_output", "stop"),
        Track: ("name", "connect", "disconnect", "enable", "status", "position_m", "move_to", "stop", "reset_fault"),
        Camera: ("name", "connect", "disconnect", "capture"),
    }  # fmt: skip
    for proto, names in members.items():
        declared = {n for n in vars(proto) if not n.startswith("_")} | set(proto.__annotations__)
        assert sorted(declared) == sorted(names)
    # classes: a Protocol with data members cannot be checked with issubclass, so check the methods by name
    for cls, proto in ((URRobot, Robot), (FanucRobot, Robot), (ModbusTrack, Track), (OakDCamera, Camera),
                       (FakeCamera, Camera)):  # fmt: skip
        missing = [n for n in members[proto] if n != "name" and not callable(getattr(cls, n, None))]
        assert missing == [], f"{cls.__name__} lacks {missing} of {proto.__name__}"


def test_an_object_missing_a_method_is_not_the_device() -> None:
    class HalfCamera:
        name = "half"

        def connect(self) -> None: ...

        def disconnect(self) -> None: ...

    class WholeCamera(HalfCamera):
        def capture(self, *, timeout_s: float = 5.0) -> object: ...

    assert not isinstance(HalfCamera(), Camera)
    assert isinstance(WholeCamera(), Camera)
    assert not isinstance(WholeCamera(), Track)
