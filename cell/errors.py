"""The whole exception hierarchy in one place, and the controller's own branch.

WeldcellError                      perception.errors
├── PerceptionError                perception.errors
│   ├── BadCapture
│   └── NoSeamFound
├── DriverError                    drivers.errors
│   ├── ConnectionLost, DeviceTimeout (MotionTimeout, CameraTimeout), ProtectiveStop, EmergencyStop,
│   │   MotionRejected, DeviceFault (RMIError, SystemFault, TrackFault), ModbusError, CorruptFrame,
│   │   DriverNotInstalled
├── CalibrationError               calibration.errors
└── ConfigError                    here
"""

from __future__ import annotations

from drivers.errors import (
    CameraTimeout,
    ConnectionLost,
    CorruptFrame,
    DeviceFault,
    DeviceTimeout,
    DriverError,
    DriverNotInstalled,
    EmergencyStop,
    ModbusError,
    MotionRejected,
    MotionTimeout,
    ProtectiveStop,
    RMIError,
    SystemFault,
    TrackFault,
)
from perception.errors import BadCapture, NoSeamFound, PerceptionError, WeldcellError

__all__ = [
    "BadCapture",
    "CameraTimeout",
    "ConfigError",
    "ConnectionLost",
    "CorruptFrame",
    "DeviceFault",
    "DeviceTimeout",
    "DriverError",
    "DriverNotInstalled",
    "EmergencyStop",
    "ModbusError",
    "MotionRejected",
    "MotionTimeout",
    "NoSeamFound",
    "PerceptionError",
    "ProtectiveStop",
    "RMIError",
    "SafetyViolation",
    "SystemFault",
    "TrackFault",
    "WeldcellError",
]


class ConfigError(WeldcellError):
    """A configuration or job file is missing, malformed, or names something impossible."""


class SafetyViolation(WeldcellError):
    """A planned path breaks a safety rule; nothing was moved."""
