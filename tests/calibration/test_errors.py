"""calibration.errors: CalibrationError is calibration's branch of the one hierarchy."""

from __future__ import annotations

import pytest

from calibration.errors import CalibrationError
from calibration.result_file import ResultFileError
from perception.errors import PerceptionError, WeldcellError


def test_calibration_errors_are_weldcell_errors_and_keep_their_message() -> None:
    assert issubclass(CalibrationError, WeldcellError) and not issubclass(CalibrationError, PerceptionError)
    assert issubclass(ResultFileError, CalibrationError)
    with pytest.raises(WeldcellError, match=r"^only 4 of 9 views are usable$"):
        raise CalibrationError("only 4 of 9 views are usable")
