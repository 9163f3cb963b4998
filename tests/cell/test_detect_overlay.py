"""`weldcell detect --overlay` draws what was seen and why, also when no seam is found (exit 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cell.cli import main
from perception.capture import save_capture
from perception.overlay import draw_overlay
from perception.seams import DetectionResult
from perception.transforms import make_X
from sim_fakes.hull import box_corners
from sim_fakes.render import render
from sim_fakes.scenes import CameraSetup, Part, Scene


@pytest.mark.parametrize("method", ["surfaces", "refined"])
def test_a_plate_alone_gives_no_seam_and_an_overlay_that_says_why(
    method: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = Part("table", "box", (2.0, 2.0, 0.04), make_X(np.eye(3), [0, 0, -0.02]), (0.2, 0.2, 0.2), workpiece=False)
    plate = Part("plate", "hull", (0, 0, 0), make_X(np.eye(3), [0, 0, 0]), (0.5, 0.5, 0.5),
                 corners_part=box_corners(0.2, 0.15, 0.01))  # fmt: skip
    cam = CameraSetup(eye=(-0.1, -0.3, 0.35), target=(0, 0, 0), width=640, height=360, fx=460, fy=460)
    cap = render(Scene("plate", "", (table, plate), (), cam), noise="stereo", seed=0).capture
    folder = save_capture(cap, tmp_path / "plate")
    png = tmp_path / "why.png"
    # in this process (the same main() as `weldcell`; tests/cell/test_cli.py runs the entry point itself)
    code = main(["detect", str(folder), "--method", method, "--overlay", str(png), "--out", str(tmp_path / "s.json")])
    out = capsys.readouterr()
    assert code == 3, out.err
    assert "no seam found" in out.out + out.err
    import cv2

    img = cv2.imread(str(png))[:, :, ::-1]
    assert img.shape == cap.color_rgb.shape
    # the note is written across the top: white text where the colour image has none
    assert (img[5:40].astype(int) - cap.color_rgb[5:40].astype(int)).any()


def test_the_note_wraps_inside_the_image() -> None:
    cap_rgb = np.zeros((360, 640, 3), np.uint8)
    from perception.capture import CameraIntrinsics, Capture

    cap = Capture(cap_rgb, np.full((360, 640), 0.5, np.float32), CameraIntrinsics(640, 360, 460, 460, 319.5, 179.5))
    img = draw_overlay(cap, DetectionResult("camera", ()), note="word " * 60)
    rows = np.flatnonzero(img.max(axis=(1, 2)) > 0)
    assert rows.max() < 200 and img[:, -3:].max() == 0  # several lines, none running off the right edge


def _red_pixels(png: Path) -> int:
    import cv2

    img = cv2.imread(str(png)).astype(int)  # BGR
    return int(((img[..., 2] > 200) & (img[..., 1] < 60) & (img[..., 0] < 60)).sum())


def test_a_cloud_gets_its_picture_with_the_seams_and_one_that_says_why_when_there_is_none(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--overlay` on a point cloud: the plan, side and detector's views (three panels of 7 x 6 inches at 80
    dpi) with the seams in red; without a seam, the same views and no red. (It used to write nothing.)"""
    from perception.transforms import transform_points
    from tests.perception.fine.scenes import rendered

    res = rendered("tee", "none")
    p = res.capture.points_camera().reshape(-1, 3)
    X = make_X(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [0.4, -0.2, 1.0])  # a z-up frame
    np.save(tmp_path / "tee.npy", transform_points(X, p[np.isfinite(p[:, 2])].astype(np.float64)))
    png = tmp_path / "tee.png"
    assert main(["detect", str(tmp_path / "tee.npy"), "--overlay", str(png)]) == 0
    assert "overlay    -> " in capsys.readouterr().err
    import cv2

    assert cv2.imread(str(png)).shape[:2] == (480, 1680)
    assert _red_pixels(png) > 100

    rng = np.random.default_rng(0)  # a flat plate alone, 0.5 mm of noise
    plate = np.column_stack([rng.uniform(0, 0.2, 20000), rng.uniform(0, 0.15, 20000), rng.normal(0, 5e-4, 20000)])
    np.save(tmp_path / "plate.npy", plate)
    png = tmp_path / "plate.png"
    assert main(["detect", str(tmp_path / "plate.npy"), "--overlay", str(png)]) == 3
    out = capsys.readouterr()
    assert "no seam found" in out.out + out.err and "overlay    -> " in out.err
    assert cv2.imread(str(png)).shape[:2] == (480, 1680)
    assert _red_pixels(png) == 0
