"""perception.errors: the root of the one exception hierarchy and what BadCapture and NoSeamFound carry."""

from __future__ import annotations

from pathlib import Path

from perception.errors import BadCapture, NoSeamFound, PerceptionError, WeldcellError


def test_bad_capture_names_the_file_and_no_seam_found_the_step() -> None:
    err = BadCapture("depth.png is 8-bit, expected 16-bit", path=Path("/data/shot1/depth.png"))
    assert (
        str(err) == "/data/shot1/depth.png: depth.png is 8-bit, expected 16-bit" and err.path == "/data/shot1/depth.png"
    )
    assert str(BadCapture("prompts contain NaN or inf")) == "prompts contain NaN or inf"
    none = NoSeamFound("every candidate was shorter than 12 mm", artifacts={"masks": 3})
    assert str(none) == "no seam found: every candidate was shorter than 12 mm"
    assert none.reason == "every candidate was shorter than 12 mm" and none.artifacts == {"masks": 3}
    assert NoSeamFound("x").artifacts == {}
    assert issubclass(BadCapture, PerceptionError) and issubclass(NoSeamFound, PerceptionError)
    assert issubclass(PerceptionError, WeldcellError) and not issubclass(WeldcellError, PerceptionError)
