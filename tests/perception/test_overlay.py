"""perception.overlay: tints, seam and torch axes land on the pixels the camera model gives, in either frame."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from perception.capture import CameraIntrinsics, Capture, GroundTruthSeam
from perception.overlay import PALETTE, SEAM_COLOR, _wrap, draw_overlay, write_png
from perception.seams import DetectionResult, Seam
from perception.segmentation import SurfaceMasks
from perception.transforms import make_X

# 160 x 120 pixels, f = 100 px, centre (79.5, 59.5); everything 1 m away. Camera point (x, y, 1) is at pixel
# (79.5 + 100 x, 59.5 + 100 y).
INTRINSICS = CameraIntrinsics(160, 120, 100.0, 100.0, 79.5, 59.5)
GRAY = 100


def capture(**kwargs) -> Capture:
    return Capture(
        color_rgb=np.full((120, 160, 3), GRAY, dtype=np.uint8),
        depth_m=np.ones((120, 160), dtype=np.float32),
        intrinsics=INTRINSICS,
        **kwargs,
    )


def seam_along_row(v: float, frame: str = "camera", X_frame_camera: np.ndarray | None = None) -> Seam:
    """A seam from pixel (29.5, v) to (129.5, v), its torch pointing away from the camera (z = +z camera)."""
    y = (v - 59.5) / 100.0
    pts_cam = np.array([[x, y, 1.0] for x in np.linspace(-0.5, 0.5, 5)])
    poses_cam = np.array([make_X(np.eye(3), p) for p in pts_cam])
    X = np.eye(4) if X_frame_camera is None else X_frame_camera
    pts = pts_cam @ X[:3, :3].T + X[:3, 3]
    poses = np.array([X @ P for P in poses_cam])
    return Seam(id=7, kind="linear", points=pts, poses=poses, length_m=1.0, confidence=1.0, frame=frame)  # type: ignore[arg-type]


def masks() -> SurfaceMasks:
    labels = np.full((120, 160), -1, dtype=np.int32)
    labels[:, :80] = 0  # the left half is surface 0
    labels[:40, 80:] = 1
    return SurfaceMasks(labels=labels, prompts_px=np.array([[40.0, 60.0], [120.0, 20.0]]), scores=(1.0, 1.0))


def test_surfaces_are_tinted_by_their_palette_colour_and_the_rest_darkened() -> None:
    out = draw_overlay(capture(), DetectionResult(frame="camera", seams=()), masks=masks())
    assert out.shape == (120, 160, 3) and out.dtype == np.uint8
    expected_0 = np.floor(0.55 * GRAY + 0.45 * PALETTE[0]).astype(np.uint8)
    expected_1 = np.floor(0.55 * GRAY + 0.45 * PALETTE[1]).astype(np.uint8)
    np.testing.assert_array_equal(out[60, 40], expected_0)
    np.testing.assert_array_equal(out[20, 120], expected_1)
    np.testing.assert_array_equal(out[100, 120], [75, 75, 75])  # background: three quarters of its gray
    # without masks nothing is tinted: the image comes back as it was
    plain = draw_overlay(capture(), DetectionResult(frame="camera", seams=()))
    assert np.all(plain == GRAY)


def test_the_seam_is_drawn_where_its_points_project_in_the_camera_and_in_the_base_frame() -> None:
    cam = draw_overlay(capture(), DetectionResult(frame="camera", seams=(seam_along_row(89.5),)))
    red = np.all(cam == SEAM_COLOR, axis=2)
    rows, cols = np.nonzero(red)
    assert set(rows) <= {88, 89, 90, 91} and 89 in rows  # a 2 px line along row 89.5
    assert cols.min() <= 31 and cols.max() >= 128  # from u = 29.5 to 129.5
    # the same seam given in a base frame, with the capture's pose: the same red pixels
    X_base_tool = make_X(np.eye(3), [0.4, -0.2, 0.3])
    X_tool_camera = make_X(cv2.Rodrigues(np.array([0.0, 0.0, 0.7]))[0], [0.0, 0.05, 0.1])
    X_base_camera = X_base_tool @ X_tool_camera
    posed = capture(X_base_tool=X_base_tool, X_tool_camera=X_tool_camera)
    base = draw_overlay(posed, DetectionResult(frame="base", seams=(seam_along_row(89.5, "base", X_base_camera),)))
    # (to a pixel or two of anti-aliasing: the points went through two transforms and back)
    assert np.count_nonzero(np.all(base == SEAM_COLOR, axis=2) != red) <= 2 and red.sum() > 150
    # far from the seam and its label nothing changed
    assert np.all(cam[:60] == GRAY)


def test_the_truth_is_drawn_in_green_only_when_asked() -> None:
    truth = GroundTruthSeam("linear", np.array([[-0.5, -0.3, 1.0], [0.5, -0.3, 1.0]]))  # along row 29.5
    cap = capture(ground_truth=(truth,))
    result = DetectionResult(frame="camera", seams=())
    out = draw_overlay(cap, result, truth=True).astype(int)
    greenness = out[..., 1] - out[..., 0]  # (60, 255, 60) anti-aliased over the gray
    assert np.all(np.argmax(greenness[:, 40:120], axis=0) == 30)  # the 1 px line along v = 29.5 lights row 30
    assert greenness[30, 31:129].min() > 150 and not greenness[:28].any() and not greenness[33:].any()
    assert not (draw_overlay(cap, result).astype(int)[..., 1] - GRAY).any()


def test_the_roi_is_outlined_in_white_and_a_note_is_written_wrapped() -> None:
    roi = np.zeros((120, 160), dtype=bool)
    roi[50:70, 20:140] = True
    out = draw_overlay(capture(), DetectionResult(frame="camera", seams=()), roi=roi)
    bright = out[..., 0].astype(int)  # the outline is white, anti-aliased over the gray
    assert bright[50, 25:135].min() > 230 and bright[69, 25:135].min() > 230 and bright[55:65, 20].min() > 230
    assert np.all(bright[55:65, 25:135] == GRAY) and np.all(bright[:47] == GRAY)  # the outline, not the band
    assert _wrap("no seam: the two masks never meet in the band", 20) == [
        "no seam: the two",
        "masks never meet in",
        "the band",
    ]
    assert _wrap("", 20) == []
    noted = draw_overlay(capture(), DetectionResult(frame="camera", seams=()), note="no seam found")
    assert (noted[:30] != GRAY).any() and np.all(noted[40:] == GRAY)  # the note sits across the top


def test_write_png_stores_rgb_and_refuses_a_path_it_cannot_write(tmp_path: Path) -> None:
    rgb = np.zeros((4, 6, 3), dtype=np.uint8)
    rgb[..., 0] = 200  # red
    write_png(str(tmp_path / "o.png"), rgb)
    back = cv2.imread(str(tmp_path / "o.png"))[:, :, ::-1]
    np.testing.assert_array_equal(back, rgb)
    try:
        write_png(str(tmp_path / "missing" / "o.png"), rgb)
    except OSError as err:
        assert "could not write" in str(err)
    else:
        raise AssertionError("write_png wrote into a folder that does not exist")
