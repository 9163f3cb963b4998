"""Calibration branch of the exception hierarchy."""

from __future__ import annotations

from perception.errors import WeldcellError


class CalibrationError(WeldcellError):
    """Calibration input is insufficient or degenerate, or the solution fails its checks."""
