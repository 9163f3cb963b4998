"""The small interfaces every device driver implements (real hardware and fakes alike).

Frames and units: poses are ``X_base_tool`` 4x4 float arrays in metres; speeds in m/s; times in s.
Every blocking call takes ``timeout_s`` and raises a :mod:`drivers.errors` timeout instead of hanging.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from perception.capture import Capture

FloatArray = NDArray[np.float64]


class RobotMode(StrEnum):
    DISCONNECTED = "disconnected"
    IDLE = "idle"
    MOVING = "moving"
    PROTECTIVE_STOP = "protective_stop"
    EMERGENCY_STOP = "emergency_stop"
    FAULT = "fault"


@dataclass(frozen=True)
class RobotState:
    """A snapshot of the robot.

    ``X_base_tool``: (4, 4) current tool pose in the base frame, metres.
    ``digital_outputs``: tuple of the first 8 standard digital outputs.
    """

    mode: RobotMode
    X_base_tool: FloatArray
    is_moving: bool
    protective_stop: bool
    emergency_stop: bool
    digital_outputs: tuple[bool, ...] = ()
    message: str = ""

    @property
    def healthy(self) -> bool:
        return self.mode in (RobotMode.IDLE, RobotMode.MOVING)


@runtime_checkable
class Robot(Protocol):
    """A 6-axis arm. Implementations: ``drivers.ur.URRobot``, ``drivers.fanuc.FanucRobot``."""

    name: str

    def connect(self) -> None:
        """Open the connection(s); raise ConnectionLost when the controller is unreachable."""

    def disconnect(self) -> None:
        """Close connections; safe to call twice."""

    def state(self) -> RobotState:
        """Current state; raises ConnectionLost when the controller does not answer."""

    def get_X_base_tool(self) -> FloatArray:
        """(4, 4) current tool pose in the base frame."""

    def move_linear(
        self, X_base_tool: FloatArray, *, speed_m_s: float, accel_m_s2: float = 0.5, timeout_s: float = 60.0
    ) -> None:
        """Move the tool in a straight line to ``X_base_tool`` and block until it arrives.

        Raises ProtectiveStop / EmergencyStop / MotionRejected / MotionTimeout / ConnectionLost.
        """

    def stream_path(
        self,
        X_base_tool_path: Sequence[FloatArray],
        *,
        speed_m_s: float,
        blend_m: float = 0.0,
        accel_m_s2: float = 0.5,
        timeout_s: float = 300.0,
        on_progress: Callable[[int], None] | None = None,
    ) -> None:
        """Move through every pose in order with blending, blocking until the last one is reached.

        ``on_progress(i)`` is called (when the device tells) as pose ``i`` is completed.
        """

    def set_digital_output(self, index: int, value: bool) -> None:
        """Set a standard digital output (arc on/off, gas...)."""

    def stop(self) -> None:
        """Decelerate and stop any motion now. Never raises for an already-stopped robot."""


@dataclass(frozen=True)
class TrackStatus:
    """Ground-track axis snapshot. ``position_m``: metres along the track from its home."""

    position_m: float
    enabled: bool
    moving: bool
    in_position: bool
    fault: bool
    fault_code: int = 0


@runtime_checkable
class Track(Protocol):
    """A linear ground track carrying the robot. Implementation: ``drivers.track.ModbusTrack``."""

    name: str

    def connect(self) -> None: ...

    def disconnect(self) -> None: ...

    def enable(self, on: bool = True) -> None: ...

    def status(self) -> TrackStatus: ...

    def position_m(self) -> float: ...

    def move_to(self, position_m: float, *, speed_m_s: float | None = None, timeout_s: float = 60.0) -> None:
        """Move to ``position_m`` and block until in position; TrackFault / MotionTimeout otherwise."""

    def stop(self) -> None: ...

    def reset_fault(self) -> None: ...


@runtime_checkable
class Camera(Protocol):
    """An RGB-D camera. Implementations: ``drivers.oakd.OakDCamera``, ``sim_fakes.fake_camera.FakeCamera``."""

    name: str

    def connect(self) -> None: ...

    def disconnect(self) -> None: ...

    def capture(self, *, timeout_s: float = 5.0) -> Capture:
        """One registered RGB + depth frame with intrinsics (no pose: the cell adds it).

        Raises CameraTimeout, CorruptFrame, ConnectionLost.
        """
