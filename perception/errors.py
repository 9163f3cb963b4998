"""The root of weldcell's one exception hierarchy, and perception's branch of it.

``perception`` imports nothing from the other packages, so the root lives here; ``drivers``,
``calibration`` and ``cell`` each add their branch below it (see ``cell.errors`` for the whole tree).

    WeldcellError
    ├── PerceptionError
    │   ├── BadCapture        input files or arrays that cannot be trusted
    │   └── NoSeamFound       a valid capture in which no seam could be detected
    ├── DriverError           (drivers.errors)
    ├── CalibrationError      (calibration.errors)
    └── ConfigError           (cell.errors)

A message says what was wrong, with which value, and what to do.
"""

from __future__ import annotations


class WeldcellError(Exception):
    """Base of every error weldcell raises on purpose."""


class PerceptionError(WeldcellError):
    """Seam detection could not produce a trustworthy result."""


class BadCapture(PerceptionError):
    """A capture (folder, file or array) is missing, malformed or physically implausible.

    ``path`` names the offending file when there is one.
    """

    def __init__(self, message: str, *, path: object | None = None) -> None:
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)


class NoSeamFound(PerceptionError):
    """The capture was valid but no seam survived detection; ``reason`` says which step emptied it."""

    def __init__(self, reason: str, *, artifacts: dict[str, object] | None = None) -> None:
        self.reason = reason
        self.artifacts = artifacts or {}  # what the detector saw (masks, surfaces), for an overlay of why
        super().__init__(f"no seam found: {reason}")
