"""cell.errors: the whole hierarchy is importable from one place and every branch hangs under WeldcellError."""

from __future__ import annotations

import cell.errors as errors
from calibration.errors import CalibrationError
from drivers.errors import DriverError


def test_every_exported_error_is_a_weldcell_error_on_its_documented_branch() -> None:
    assert sorted(errors.__all__) == sorted(set(errors.__all__))
    for name in errors.__all__:
        assert issubclass(getattr(errors, name), errors.WeldcellError), name
    branch = {
        "ConfigError": errors.WeldcellError,
        "SafetyViolation": errors.WeldcellError,
        "BadCapture": errors.PerceptionError,
        "MotionTimeout": errors.DeviceTimeout,
        "TrackFault": errors.DeviceFault,
        "ProtectiveStop": DriverError,
    }
    for name, parent in branch.items():
        assert issubclass(getattr(errors, name), parent), name
    assert issubclass(CalibrationError, errors.WeldcellError)
    assert not issubclass(errors.ConfigError, DriverError) and not issubclass(
        errors.SafetyViolation, errors.ConfigError
    )
