"""The checks every ``drivers.protocols.Camera`` implementation must pass.

A test module subclasses :class:`CameraContract` and provides the fixture ``camera_and_fake`` yielding
``(camera, fake)``: a connected camera that sees a scene (at least :data:`MIN_VALID_DEPTH_SHARE` of its pixels
have depth) and the fake's :class:`sim_fakes.faults.FaultInjectable` handle (the camera itself for the fake
camera; None against real hardware, where fault tests are skipped).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.errors import CameraTimeout, ConnectionLost, CorruptFrame
from drivers.protocols import Camera
from perception.capture import Capture

MIN_VALID_DEPTH_SHARE = 0.5
MAX_DEPTH_M = 5.0


def assert_valid_capture(cap: Capture) -> None:
    """The capture-format invariants a camera must deliver."""
    assert isinstance(cap, Capture)
    h, w = cap.shape
    intr = cap.intrinsics
    assert (intr.width, intr.height) == (w, h)
    assert cap.color_rgb.shape == (h, w, 3) and cap.color_rgb.dtype == np.uint8
    assert cap.depth_m.shape == (h, w) and cap.depth_m.dtype == np.float32
    depth = cap.depth_m
    finite = np.isfinite(depth)
    assert not np.isinf(depth).any()
    assert (depth[finite] > 0).all(), "no data must be NaN, never 0"
    assert finite.mean() >= MIN_VALID_DEPTH_SHARE
    assert float(np.nanmax(depth)) < MAX_DEPTH_M
    assert 0 <= intr.cx <= w and 0 <= intr.cy <= h and intr.fx > 0 and intr.fy > 0
    assert cap.X_base_tool is None and cap.X_tool_camera is None  # the cell adds the pose, not the camera
    assert cap.source


class CameraContract:
    """Subclass and provide ``camera_and_fake``. Every test has a timeout."""

    @pytest.mark.timeout(30)
    def test_is_a_camera_and_captures_a_valid_frame(self, camera_and_fake):
        camera, _ = camera_and_fake
        assert isinstance(camera, Camera)
        cap = camera.capture(timeout_s=5.0)
        assert_valid_capture(cap)

    @pytest.mark.timeout(30)
    def test_consecutive_frames_share_the_pixel_grid(self, camera_and_fake):
        camera, _ = camera_and_fake
        a = camera.capture(timeout_s=5.0)
        b = camera.capture(timeout_s=5.0)
        assert a.intrinsics == b.intrinsics
        assert a.source != b.source  # two frames, not one returned twice
        both = np.isfinite(a.depth_m) & np.isfinite(b.depth_m)
        # a still scene: depth agrees to within noise almost everywhere
        close = np.abs(a.depth_m[both] - b.depth_m[both]) < 0.005
        assert close.mean() > 0.95

    @pytest.mark.timeout(30)
    def test_frame_timeout_raises_after_the_timeout(self, camera_and_fake):
        camera, fake = camera_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        fake.inject("frame_timeout")
        t0 = time.monotonic()
        with pytest.raises(CameraTimeout):
            camera.capture(timeout_s=0.4)
        assert 0.4 <= time.monotonic() - t0 < 0.4 + 1.0
        fake.clear_faults()
        assert_valid_capture(camera.capture(timeout_s=5.0))

    @pytest.mark.timeout(30)
    def test_corrupt_frame_is_refused(self, camera_and_fake):
        camera, fake = camera_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        fake.inject("corrupt_frame")
        with pytest.raises(CorruptFrame):
            camera.capture(timeout_s=5.0)
        fake.clear_faults()
        assert_valid_capture(camera.capture(timeout_s=5.0))

    @pytest.mark.timeout(30)
    def test_capture_after_disconnect_raises_connection_lost(self, camera_and_fake):
        camera, _ = camera_and_fake
        camera.disconnect()
        with pytest.raises(ConnectionLost):
            camera.capture(timeout_s=1.0)
        camera.connect()
        assert_valid_capture(camera.capture(timeout_s=5.0))
