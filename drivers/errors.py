"""Driver branch of the exception hierarchy (root: :class:`perception.errors.WeldcellError`).

Every vendor error is wrapped in one of these with ``raise ... from err``; every wait raises a
timeout subclass instead of hanging.
"""

from __future__ import annotations

from perception.errors import WeldcellError


class DriverError(WeldcellError):
    """A device could not do what was asked."""


class ConnectionLost(DriverError):
    """The connection to a device dropped or could not be made."""


class DeviceTimeout(DriverError):
    """A device did not answer within its timeout."""


class MotionTimeout(DeviceTimeout):
    """A motion did not finish within its timeout."""


class ProtectiveStop(DriverError):
    """The robot controller entered a protective stop."""


class EmergencyStop(DriverError):
    """An emergency stop is active."""


class MotionRejected(DriverError):
    """The controller refused a motion (unreachable pose, limits, bad parameters)."""


class MotionAborted(DriverError):
    """A motion was cut short on purpose (a stop was sent); the remaining poses were dropped."""


class DeviceFault(DriverError):
    """The device reports a fault; ``code`` is the vendor's code when there is one."""

    def __init__(self, message: str, *, code: int | str | None = None) -> None:
        self.code = code
        super().__init__(message if code is None else f"{message} (code {code})")


class RMIError(DeviceFault):
    """FANUC Remote Motion Interface error reply (``code`` is the ErrorID)."""


class SystemFault(DeviceFault):
    """FANUC controller sent an unsolicited FRC_SystemFault."""


class TrackFault(DeviceFault):
    """The ground track's fault bit is set (``code`` is its fault-code register)."""


class ModbusError(DriverError):
    """A Modbus exception response or protocol error from the track."""


class CameraTimeout(DeviceTimeout):
    """The camera delivered no frame within its timeout."""


class CorruptFrame(DriverError):
    """The camera delivered a frame that fails validation."""


class DriverNotInstalled(DriverError):
    """The vendor SDK this driver needs is not importable; the message says what to install."""
