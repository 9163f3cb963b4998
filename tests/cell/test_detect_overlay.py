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
