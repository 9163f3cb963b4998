"""``weldcell devices check`` (cell/commands/devices.py): each device's line and state from stand-in devices, the
address it names, the reason it gives. (tests/cell/test_sim_cli.py runs the command against real simulators.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cell.commands.devices import DeviceResult, _address, _check
from cell.config import load_config
from drivers.errors import ConnectionLost
from drivers.protocols import RobotMode, RobotState, TrackStatus
from perception.errors import BadCapture

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
FANUC = load_config(EXAMPLES / "sim-cell-fanuc.toml")
UR = load_config(EXAMPLES / "sim-cell.toml")


class Arm:
    def __init__(self, state: RobotState) -> None:
        self._state = state
        self.connected = False

    def connect(self) -> None:
        self.connected = True

    def state(self) -> RobotState:
        return self._state


class Drive:
    def __init__(self, status: TrackStatus | None = None, error: Exception | None = None) -> None:
        self._status, self._error = status, error

    def connect(self) -> None:
        if self._error is not None:
            raise self._error

    def status(self) -> TrackStatus:
        assert self._status is not None
        return self._status


class Lens:
    def __init__(self, depth: np.ndarray) -> None:
        self.depth, self.timeouts = depth, []  # type: ignore[var-annotated]

    def connect(self) -> None:
        pass

    def capture(self, *, timeout_s: float) -> object:
        self.timeouts.append(timeout_s)
        return type("Cap", (), {"shape": self.depth.shape, "depth_m": self.depth})()


def pose(x: float, y: float, z: float) -> np.ndarray:
    X = np.eye(4)
    X[:3, 3] = (x, y, z)
    return X


def test_the_address_is_the_one_each_device_is_reached_at() -> None:
    assert _address("robot", FANUC) == f"{FANUC.robot.host}:{FANUC.robot.rmi_port}"
    assert _address("robot", UR) == "127.0.0.41:30004"  # RTDE's port on the controller's address
    assert _address("track", FANUC) == f"127.0.0.1:{FANUC.track.port}"
    assert _address("camera", FANUC) == "in-process"  # the fake camera renders in this process


def test_a_ready_robot_is_ok_with_its_mode_and_tool_position_in_metres() -> None:
    arm = Arm(RobotState(RobotMode.IDLE, pose(0.55, -0.1, 0.3), False, False, False))
    r = _check("robot", arm, FANUC)
    assert arm.connected and r.ok and r.error == ""
    assert (r.role, r.kind) == ("robot", "fake-fanuc")
    assert r.summary == "mode=idle tool at (0.5500, -0.1000, 0.3000) m"
    assert r.state["X_base_tool"][0][3] == 0.55 and r.state["protective_stop"] is False


def test_a_robot_in_a_protective_stop_fails_with_its_mode_and_message() -> None:
    arm = Arm(RobotState(RobotMode.PROTECTIVE_STOP, pose(0, 0, 0), False, True, False, message="joint 3 limit"))
    r = _check("robot", arm, FANUC)
    assert not r.ok and r.error == "not ready: mode=protective_stop joint 3 limit"


def test_a_track_with_a_latched_fault_fails_with_its_code_and_position() -> None:
    ok = _check("track", Drive(TrackStatus(1.25, True, False, True, False)), FANUC)
    assert ok.ok and ok.summary == "position=1.2500 m enabled=yes moving=no in_position=yes fault=no"
    assert ok.state == {"position_m": 1.25, "enabled": True, "moving": False, "in_position": True, "fault": False,
                        "fault_code": 0}  # fmt: skip
    bad = _check("track", Drive(TrackStatus(0.5, False, False, False, True, 0x2310)), FANUC)
    assert not bad.ok and bad.error == "fault latched (code 8976) at 0.5000 m; reset it on the drive"


def test_an_unreachable_device_and_a_device_error_give_their_reasons() -> None:
    gone = _check("track", Drive(error=ConnectionLost("track: connection refused")), FANUC)
    assert not gone.ok and gone.error.startswith("unreachable: ") and "connection refused" in gone.error
    broken = _check("track", Drive(error=BadCapture("a frame without depth")), FANUC)
    assert not broken.ok and "a frame without depth" in broken.error and not broken.error.startswith("unreachable")


def test_the_camera_reports_its_frame_size_and_the_share_of_valid_depth() -> None:
    depth = np.full((4, 5), 0.8)
    depth[0, :] = 0.0  # no depth
    depth[1, 0] = np.nan
    lens = Lens(depth)
    r = _check("camera", lens, FANUC)
    assert lens.timeouts == [FANUC.camera.timeout_s]
    assert r.ok and r.state["width"] == 5 and r.state["height"] == 4
    assert r.state["valid_depth_share"] == pytest.approx(14 / 20)
    assert r.summary == "frame 5x4, valid depth 70.0%"
    assert DeviceResult("camera", "fake", "in-process").ok is False  # not ok until checked
