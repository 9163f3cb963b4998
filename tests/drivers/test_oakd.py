"""OAK-D driver: the pure conversions (intrinsics at the output size, depth units, frame checks) without hardware,
and one hardware test that runs only when WELDCELL_OAKD=1 names a connected camera."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.errors import ConnectionLost, CorruptFrame, DriverNotInstalled
from drivers.oakd import (
    OakDCamera,
    check_frames,
    depth_m_from_mm,
    rgb_from_bgr,
    scale_intrinsics,
    valid_depth_share,
    validated_capture,
)
from perception.capture import CameraIntrinsics
from tests.drivers.camera_contract import CameraContract

K_1080P = [[1500.0, 0.0, 950.0], [0.0, 1490.0, 540.0], [0.0, 0.0, 1.0]]


# ---------------------------------------------------------------------------------------------- intrinsics
def test_same_aspect_ratio_scales_everything() -> None:
    intr = scale_intrinsics(K_1080P, calib_size=(1920, 1080), output_size=(1280, 720))
    assert (intr.width, intr.height) == (1280, 720)
    assert intr.fx == pytest.approx(1000.0, abs=1e-12)
    assert intr.fy == pytest.approx(1490.0 * 2 / 3, abs=1e-12)
    assert intr.cx == pytest.approx(950.0 * 2 / 3, abs=1e-12)
    assert intr.cy == pytest.approx(360.0, abs=1e-12)


def test_a_wider_output_covers_and_crops_rows_a_narrower_one_crops_columns() -> None:
    # 640x400 from 1920x1080: scale 400/1080 covers the width (711.1 px), 35.56 px cropped on each side
    intr = scale_intrinsics(K_1080P, calib_size=(1920, 1080), output_size=(640, 400))
    s = 400 / 1080
    assert intr.fx == pytest.approx(1500.0 * s, abs=1e-12)
    assert intr.cx == pytest.approx(950.0 * s - (1920 * s - 640) / 2, abs=1e-12)
    assert intr.cy == pytest.approx(540.0 * s, abs=1e-12)
    # 1920x800 from 1920x1080: the width scale 1.0 covers, 140 rows cropped top and bottom
    intr = scale_intrinsics(K_1080P, calib_size=(1920, 1080), output_size=(1920, 800))
    assert (intr.fx, intr.cx, intr.cy) == (1500.0, 950.0, 540.0 - 140.0)


def test_a_4_by_3_output_of_a_16_by_9_calibration_sees_more_rows() -> None:
    intr = scale_intrinsics(K_1080P, calib_size=(1920, 1080), output_size=(1280, 960))
    assert intr.fx == pytest.approx(1000.0, abs=1e-12)
    assert intr.cx == pytest.approx(950.0 * 2 / 3, abs=1e-12)
    assert intr.cy == pytest.approx(360.0 + 120.0, abs=1e-12)


@pytest.mark.parametrize(
    "size", [(1280, 720), (640, 400), (1280, 960), (1920, 1080), (2028, 1520), (640, 480), (800, 800), (3840, 2160)]
)
def test_matches_depthai_calibration_handler(size: tuple[int, int]) -> None:
    dai = pytest.importorskip("depthai")
    calib = dai.CalibrationHandler()
    calib.setCameraIntrinsics(dai.CameraBoardSocket.CAM_A, K_1080P, 1920, 1080)
    expected = np.array(calib.getCameraIntrinsics(dai.CameraBoardSocket.CAM_A, size[0], size[1]))
    ours = scale_intrinsics(K_1080P, calib_size=(1920, 1080), output_size=size)
    assert np.abs(ours.K - expected).max() < 1e-3  # depthai computes in float32


def test_bad_calibration_is_a_corrupt_frame() -> None:
    with pytest.raises(CorruptFrame):
        scale_intrinsics([[1.0, 0.0], [0.0, 1.0]], calib_size=(1920, 1080), output_size=(1280, 720))
    with pytest.raises(CorruptFrame):
        scale_intrinsics(K_1080P, calib_size=(0, 1080), output_size=(1280, 720))
    with pytest.raises(CorruptFrame, match="implausible"):
        scale_intrinsics(
            [[1.0, 0.0, 950.0], [0.0, 1.0, 540.0], [0.0, 0.0, 1.0]], calib_size=(1920, 1080), output_size=(640, 360)
        )


# ---------------------------------------------------------------------------------------------- depth, colour
def test_depth_millimetres_become_metres_with_nan_for_no_data() -> None:
    mm = np.array([[0, 1000, 523], [65535, 9999, 10001]], dtype=np.uint16)
    depth = depth_m_from_mm(mm, max_depth_m=10.0)
    assert depth.dtype == np.float32
    expected = np.array([[np.nan, 1.0, 0.523], [np.nan, 9.999, np.nan]], dtype=np.float32)
    assert np.array_equal(depth, expected, equal_nan=True)
    assert np.array_equal(depth_m_from_mm(mm)[1], np.array([65.535, 9.999, 10.001], dtype=np.float32))
    with pytest.raises(CorruptFrame):
        depth_m_from_mm(mm.astype(np.float32))
    with pytest.raises(CorruptFrame):
        depth_m_from_mm(np.zeros((2, 2, 1), np.uint16))


def test_colour_frames_become_rgb() -> None:
    bgr = np.array([[[1, 2, 3], [10, 20, 30]]], dtype=np.uint8)
    assert rgb_from_bgr(bgr).tolist() == [[[3, 2, 1], [30, 20, 10]]]
    bgra = np.array([[[1, 2, 3, 255]]], dtype=np.uint8)
    assert rgb_from_bgr(bgra).tolist() == [[[3, 2, 1]]]
    assert rgb_from_bgr(np.array([[7]], dtype=np.uint8)).tolist() == [[[7, 7, 7]]]
    with pytest.raises(CorruptFrame):
        rgb_from_bgr(np.zeros((2, 2, 3), np.float32))


# ---------------------------------------------------------------------------------------------- frame checks
def _frames(w: int = 64, h: int = 48) -> tuple[np.ndarray, np.ndarray, CameraIntrinsics]:
    color = np.full((h, w, 3), 90, np.uint8)
    depth = np.full((h, w), 0.5, np.float32)
    depth[:, :16] = np.nan  # a quarter without data
    return color, depth, CameraIntrinsics(w, h, 60.0, 60.0, (w - 1) / 2, (h - 1) / 2)


def test_a_good_frame_passes_and_becomes_a_capture() -> None:
    color, depth, intr = _frames()
    check_frames(color, depth, expected_size=(64, 48), min_valid_depth_share=0.75)
    cap = validated_capture(color, depth, intr, source="oakd:test:7")
    assert cap.shape == (48, 64) and cap.depth_scale == 1000.0 and cap.source == "oakd:test:7"
    assert valid_depth_share(cap.depth_m) == 0.75
    assert cap.X_base_tool is None


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda c, d: (c[:, :, 0], d), "colour frame must be"),
        (lambda c, d: (c.astype(np.uint16), d), "colour frame must be"),
        (lambda c, d: (c[:-1], d[:-1]), "expected 64x48"),
        (lambda c, d: (c, d[:-8]), "not registered"),
        (lambda c, d: (c, np.nan_to_num(d).astype(np.uint16)), "float metres"),
        (lambda c, d: (c, np.where(np.isnan(d), np.inf, d)), "infinite"),
        (lambda c, d: (c, -d), "negative"),
        (lambda c, d: (c, np.full_like(d, np.nan)), "have depth"),
        (lambda c, d: (c, np.where(np.arange(64) < 60, np.nan, d).astype(np.float32)), "6.25%"),
    ],
)
def test_broken_frames_are_refused(change, message: str) -> None:
    color, depth, intr = _frames()
    bad_color, bad_depth = change(color, depth)
    with pytest.raises(CorruptFrame, match=message):
        check_frames(bad_color, bad_depth, expected_size=(64, 48), min_valid_depth_share=0.1)
    with pytest.raises(CorruptFrame):
        validated_capture(bad_color, bad_depth, intr, min_valid_depth_share=0.1)


def test_implausible_depth_is_refused_by_the_capture_rules() -> None:
    color, depth, intr = _frames()
    with pytest.raises(CorruptFrame, match="implausible"):
        validated_capture(color, depth * 100.0, intr, source="oakd:x")  # 50 m: a unit error


# ---------------------------------------------------------------------------------------------- driver shell
def test_missing_depthai_gives_the_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "depthai", None)  # makes `import depthai` raise ImportError
    with pytest.raises(DriverNotInstalled, match="pip install"):
        OakDCamera().connect()


def test_capture_before_connect_is_connection_lost() -> None:
    camera = OakDCamera()
    with pytest.raises(ConnectionLost):
        camera.capture(timeout_s=0.1)
    camera.disconnect()
    with pytest.raises(ValueError):
        OakDCamera(resolution=(1000, 720))  # aligned depth needs a width that is a multiple of 16


# ---------------------------------------------------------------------------------------------- hardware
@pytest.mark.hardware
@pytest.mark.skipif(os.environ.get("WELDCELL_OAKD") != "1", reason="set WELDCELL_OAKD=1 with an OAK-D connected")
class TestOakDHardware(CameraContract):
    @pytest.fixture
    def camera_and_fake(self) -> Iterator[tuple[OakDCamera, None]]:
        camera = OakDCamera(device_id=os.environ.get("WELDCELL_OAKD_ID") or None, resolution=(1280, 720))
        camera.connect()
        try:
            yield camera, None
        finally:
            camera.disconnect()


def test_the_pipeline_turns_the_median_post_filter_off() -> None:
    from unittest.mock import MagicMock

    dai, device = MagicMock(), MagicMock()
    OakDCamera()._build(dai, device)
    stereo = dai.Pipeline.return_value.create.return_value
    stereo.initialConfig.setMedianFilter.assert_called_once_with(dai.StereoDepthConfig.MedianFilter.MEDIAN_OFF)
    stereo.setSubpixel.assert_called_once_with(True)


def test_the_median_off_setting_exists_in_the_installed_depthai() -> None:
    dai = pytest.importorskip("depthai")
    cfg = dai.StereoDepthConfig()
    cfg.setMedianFilter(dai.StereoDepthConfig.MedianFilter.KERNEL_5x5)
    cfg.setMedianFilter(dai.StereoDepthConfig.MedianFilter.MEDIAN_OFF)
    assert cfg.getMedianFilter() == dai.StereoDepthConfig.MedianFilter.MEDIAN_OFF
