"""calibration.result_file: the hand-eye result file is written and read in one place, and its format checked."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.errors import CalibrationError
from calibration.result_file import (
    RESULT_FORMAT,
    ResultFileError,
    read_result_file,
    read_X_tool_camera,
    write_result_file,
)
from perception.transforms import make_X

X_TOOL_CAMERA = make_X(Rotation.from_euler("xyz", [0.1, -0.2, 1.5]).as_matrix(), [0.031, -0.052, 0.118])


def test_result_file_is_written_atomically_and_keeps_the_previous_one(tmp_path: Path) -> None:
    out = tmp_path / "calib" / "hand_eye.json"
    assert write_result_file(out, {"format": RESULT_FORMAT, "X_tool_camera": np.eye(4).tolist(), "n": 1}) is None
    first = out.read_bytes()
    assert json.loads(first)["X_tool_camera"][1] == [0.0, 1.0, 0.0, 0.0]
    assert b"[0.0, 1.0, 0.0, 0.0]" in first  # a matrix row on one line
    prev = write_result_file(out, {"format": RESULT_FORMAT, "X_tool_camera": np.eye(4).tolist(), "n": 2})
    assert prev == out.with_name("hand_eye.json.prev") and prev.read_bytes() == first
    second = out.read_bytes()
    # a document that cannot be written (NaN is not JSON) changes nothing and leaves no temporary file
    with pytest.raises(ValueError):
        write_result_file(out, {"format": RESULT_FORMAT, "X_tool_camera": [[float("nan")]]})
    assert out.read_bytes() == second and prev.read_bytes() == first
    assert sorted(p.name for p in out.parent.iterdir()) == ["hand_eye.json", "hand_eye.json.prev"]


def test_what_is_written_reads_back_bit_for_bit(tmp_path: Path) -> None:
    out = tmp_path / "hand_eye.json"
    write_result_file(out, {"format": RESULT_FORMAT, "X_tool_camera": X_TOOL_CAMERA.tolist(), "mode": "eye_in_hand"})
    X = read_X_tool_camera(out)
    assert X.shape == (4, 4) and np.array_equal(X, X_TOOL_CAMERA)  # repr(float) round-trips exactly
    assert read_result_file(out)["mode"] == "eye_in_hand"


def test_the_writer_refuses_a_document_of_another_format(tmp_path: Path) -> None:
    out = tmp_path / "hand_eye.json"
    for bad in ({"X_tool_camera": np.eye(4).tolist()}, {"format": "weldcell-hand-eye/2"}):
        with pytest.raises(ResultFileError, match="refusing to write a hand-eye file whose format is"):
            write_result_file(out, bad)
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_a_missing_or_other_format_is_refused_with_a_reason(tmp_path: Path) -> None:
    path = tmp_path / "pose.json"
    path.write_text(json.dumps({"X_base_tool": np.eye(4).tolist(), "X_tool_camera": X_TOOL_CAMERA.tolist()}))
    with pytest.raises(ResultFileError) as info:
        read_X_tool_camera(path)
    assert str(info.value) == (
        f"the hand-eye file {path} has no 'format' key; this weldcell reads 'weldcell-hand-eye/1' files, as "
        '`weldcell calibrate hand-eye` writes them (add "format": "weldcell-hand-eye/1" to a file written by hand)'
    )
    path.write_text(json.dumps({"format": "weldcell-hand-eye/2", "X_tool_camera": X_TOOL_CAMERA.tolist()}))
    with pytest.raises(ResultFileError, match=r"has format 'weldcell-hand-eye/2'; this weldcell reads"):
        read_X_tool_camera(path)
    assert issubclass(ResultFileError, CalibrationError)


def test_other_mistakes_name_the_file_and_what_is_wrong(tmp_path: Path) -> None:
    path = tmp_path / "he.json"
    with pytest.raises(ResultFileError, match=r"cannot read the hand-eye file .*he\.json"):
        read_X_tool_camera(path)
    path.write_text("{not json")
    with pytest.raises(ResultFileError, match="is not valid JSON"):
        read_X_tool_camera(path)
    path.write_text("[1, 2]")
    with pytest.raises(ResultFileError, match="holds a JSON list, not an object"):
        read_X_tool_camera(path)
    path.write_text(json.dumps({"format": RESULT_FORMAT, "X_base_camera": np.eye(4).tolist()}))
    with pytest.raises(ResultFileError, match=r"has no 'X_tool_camera' key \(it is an eye-to-hand result\)"):
        read_X_tool_camera(path)
    reflected = np.diag([1.0, 1.0, -1.0, 1.0])
    path.write_text(json.dumps({"format": RESULT_FORMAT, "X_tool_camera": reflected.tolist()}))
    with pytest.raises(ResultFileError, match="X_tool_camera: rotation part is a reflection"):
        read_X_tool_camera(path)
