"""perception.seams: the Seam value type, its frames, and seams.json written and read back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.errors import BadCapture
from perception.seams import DetectionResult, Seam, check_seam_path, read_seams_json, seams_to_json, write_seams_json
from perception.transforms import make_X

RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def straight_seam(seam_id: int = 0, frame: str = "camera") -> Seam:
    pts = np.array([[0.0, 0.0, 0.5], [0.05, 0.0, 0.5], [0.1, 0.0, 0.5]])
    R = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # travel +x, torch pointing -z
    poses = np.stack([make_X(R, p) for p in pts])
    return Seam(seam_id, "linear", pts, poses, 0.1, 0.875, (1, 2), frame=frame, joint="fillet")  # type: ignore[arg-type]


def test_the_seam_rule_names_the_field_and_the_shape() -> None:
    pts = np.zeros((3, 3))
    poses = np.tile(np.eye(4), (3, 1, 1))
    a, b = check_seam_path(pts.tolist(), poses, what="seam")
    assert a.dtype == np.float64 and b.shape == (3, 4, 4)
    with pytest.raises(ValueError, match=r"^seam points must be \(N>=2, 3\), got \(1, 3\)$"):
        check_seam_path(pts[:1], poses[:1], what="seam")
    with pytest.raises(ValueError, match=r"^seam poses must be \(3, 4, 4\), got \(2, 4, 4\)$"):
        check_seam_path(pts, poses[:2], what="seam")
    bad = pts.copy()
    bad[1, 2] = math.inf
    with pytest.raises(ValueError, match=r"^seam points or poses contain NaN or inf$"):
        Seam(0, "linear", bad, poses, 0.1, 0.5)


def test_transformed_moves_points_and_poses_into_the_new_frame() -> None:
    seam = straight_seam()
    X_base_camera = make_X(RZ90, [1.0, 2.0, 0.0])
    moved = seam.transformed(X_base_camera, "base")
    assert moved.frame == "base" and (moved.id, moved.joint, moved.surfaces) == (0, "fillet", (1, 2))
    np.testing.assert_allclose(moved.points, [[1.0, 2.0, 0.5], [1.0, 2.05, 0.5], [1.0, 2.1, 0.5]], atol=1e-15)
    np.testing.assert_allclose(moved.poses[1], X_base_camera @ seam.poses[1], atol=1e-15)
    np.testing.assert_allclose(moved.poses[:, :3, 3], moved.points, atol=1e-15)


def test_seams_json_round_trips_points_and_poses(tmp_path) -> None:
    result = DetectionResult(
        frame="camera",
        seams=(straight_seam(3),),
        point_counts={"raw": 100, "cropped": 40},
        timing_s={"total": 0.123456789},
    )
    doc = seams_to_json(result)
    assert (doc["format_version"], doc["units"], doc["frame"]) == ("1.1", "m", "camera")
    (s,) = doc["seams"]
    assert (s["id"], s["kind"], s["joint"], s["length_m"], s["confidence"], s["surfaces"]) == (
        3, "linear", "fillet", 0.1, 0.875, [1, 2],
    )  # fmt: skip
    assert s["poses"][0] == [0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0]  # R = diag(1, -1, -1): 180 deg about x
    assert s["fanuc_xyzwpr_mm_deg"][2] == [100.0, 0.0, 500.0, 180.0, 0.0, 0.0]
    assert doc["timing_s"] == {"total": 0.12346} and doc["points"] == {"raw": 100, "cropped": 40}
    back = read_seams_json(write_seams_json(result, tmp_path / "out" / "seams.json"))
    assert back.frame == "camera" and back.kinds == ("linear",)
    np.testing.assert_array_equal(back.points[0], result.seams[0].points)
    np.testing.assert_allclose(back.poses[0], result.seams[0].poses, atol=1e-7)
    np.testing.assert_allclose(back.points_in_camera(None)[0], result.seams[0].points)


def test_a_base_frame_file_needs_the_camera_pose_and_bad_files_are_refused(tmp_path) -> None:
    base = DetectionResult(frame="base", seams=(straight_seam(0, frame="base"),))
    back = read_seams_json(write_seams_json(base, tmp_path / "seams.json"))
    with pytest.raises(BadCapture, match=r"seams\.json is in the base frame but the capture has no pose\.json"):
        back.points_in_camera(None)
    X_base_camera = make_X(np.eye(3), [0.0, 0.0, 0.5])
    np.testing.assert_allclose(back.points_in_camera(X_base_camera)[0][:, 2], [0.0, 0.0, 0.0], atol=1e-15)
    path = tmp_path / "bad.json"
    for text, reason in (
        ('{"seams": [], "format_version": "2.0"}', "format_version '2.0' is not 1.x"),
        ('{"seams": [], "units": "mm"}', "units 'mm': seams.json lengths are in metres"),
        ('{"seams": [], "frame": "tool"}', "'frame' must be 'camera' or 'base', got 'tool'"),
        ('{"seams": [{"points": [[0, 0, "x"]]}]}', "seam 0: malformed points or poses"),
        ('{"seams": [{"points": [[0, 0, NaN]]}]}', "seam 0: points contain NaN or inf"),
        ("[]", "expected an object with a 'seams' list"),
    ):
        path.write_text(text)
        with pytest.raises(BadCapture, match=reason):
            read_seams_json(path)
    with pytest.raises(BadCapture, match="seams file does not exist"):
        read_seams_json(tmp_path / "missing.json")
