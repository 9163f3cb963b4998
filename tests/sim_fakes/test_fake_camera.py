"""The fake camera renders the workpiece from the live robot and track pose: a known world point lands on the
pixel the pose predicts, moving the robot or the track moves it there; playback; faults; the Camera contract."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.errors import ConnectionLost, CorruptFrame
from drivers.fanuc import FanucRobot
from drivers.track import ModbusTrack
from perception.capture import Capture, load_capture, save_capture
from perception.transforms import X_from_xyzwpr_mm_deg, invert_X, make_X, transform_points
from sim_fakes.fake_camera import FakeCamera
from sim_fakes.fake_fanuc import FakeFanucController
from sim_fakes.fake_track import FakeTrack
from sim_fakes.faults import FaultInjectable
from sim_fakes.render import X_BASE_WORLD, X_TOOL_CAMERA, render
from sim_fakes.scenes import get_scene, with_resolution
from tests.drivers.camera_contract import CameraContract, assert_valid_capture
from tests.leftovers import assert_no_threads_left

X_BASE_TOOL_A = X_from_xyzwpr_mm_deg((500.0, 0.0, 400.0, 180.0, 0.0, 0.0))  # the fake FANUC's start pose
# The centre of the top face of the ribs scene's bar2 (x 0.05, y 0.07, 40 x 120 mm, top at 12 + 30 mm).
P_WORLD = np.array([0.05, 0.07, 0.042])
TOP_Z_M = 0.042
RESOLUTION = (320, 180)
OUR_THREAD_PREFIXES = ("fake-track", "fake-fanuc", "fanuc-rmi")


@pytest.fixture(autouse=True)
def no_leftover_threads() -> Iterator[None]:
    yield
    assert_no_threads_left(OUR_THREAD_PREFIXES)


def expected_X_world_camera(X_base_tool: np.ndarray, track_m: float) -> np.ndarray:
    """The composition the fake camera documents, written out independently."""
    X_base0_base = make_X(np.eye(3), [0.0, track_m, 0.0])  # the track runs along base +y
    return invert_X(X_BASE_WORLD) @ X_base0_base @ X_base_tool @ X_TOOL_CAMERA


def predicted_pixel(cap: Capture, X_world_camera: np.ndarray, p_world: np.ndarray) -> np.ndarray:
    p_camera = transform_points(invert_X(X_world_camera), p_world)
    return cap.intrinsics.project(p_camera)[0]


def world_point_seen_at(cap: Capture, X_world_camera: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The world point the frame's depth shows at the pixel nearest ``uv``."""
    u, v = (int(np.rint(c)) for c in uv)
    assert 0 <= u < cap.shape[1] and 0 <= v < cap.shape[0], f"pixel {uv} outside the image"
    p_camera = cap.points_camera()[v, u].astype(np.float64)
    assert np.isfinite(p_camera).all(), f"no depth at pixel ({u}, {v})"
    return transform_points(X_world_camera, p_camera)[0]


def assert_point_imaged_at_prediction(cap: Capture, X_world_camera: np.ndarray) -> np.ndarray:
    """P_WORLD appears at its predicted pixel: the depth there lies on bar2's top face within the pixel's
    footprint around P_WORLD. Returns the predicted pixel."""
    uv = predicted_pixel(cap, X_world_camera, P_WORLD)
    seen = world_point_seen_at(cap, X_world_camera, uv)
    z_camera = float(transform_points(invert_X(X_world_camera), P_WORLD)[0, 2])
    footprint_m = np.hypot(0.5, 0.5) * z_camera / cap.intrinsics.fx  # rounding to the nearest pixel centre
    assert abs(seen[2] - TOP_Z_M) < 1e-6, f"pixel {uv} shows z = {seen[2]:.6f} m, not the bar's top face"
    assert np.linalg.norm(seen[:2] - P_WORLD[:2]) <= footprint_m + 1e-6
    return uv


def assert_rendered_from(cap: Capture, X_world_camera: np.ndarray) -> None:
    """The frame is exactly the scene seen from ``X_world_camera``: an independent noise-free render from that
    pose has the same depth in every pixel, and one from 1 mm beside it does not."""
    scene = with_resolution(get_scene("ribs"), *RESOLUTION)
    assert np.array_equal(
        cap.depth_m, render(scene, noise="none", X_world_camera=X_world_camera).capture.depth_m, equal_nan=True
    )
    beside = X_world_camera @ make_X(np.eye(3), [0.001, 0.0, 0.0])
    assert not np.array_equal(
        cap.depth_m, render(scene, noise="none", X_world_camera=beside).capture.depth_m, equal_nan=True
    )


def offset_pose(X: np.ndarray, d_m: tuple[float, float, float], yaw_deg: float) -> np.ndarray:
    out = X.copy()
    out[:3, 3] += d_m
    out[:3, :3] = out[:3, :3] @ Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    return out


# ---------------------------------------------------------------------------------------------- contract
class TestFakeCameraContract(CameraContract):
    @pytest.fixture
    def camera_and_fake(self) -> Iterator[tuple[FakeCamera, Any]]:
        camera = FakeCamera(
            "ribs", robot_pose=lambda: X_BASE_TOOL_A, track_position_m=lambda: 0.0, resolution=(160, 90)
        )
        assert isinstance(camera, FaultInjectable)
        camera.connect()
        try:
            yield camera, camera
        finally:
            camera.disconnect()


# ---------------------------------------------------------------------------------------------- pose
@pytest.mark.timeout(30)
def test_moving_the_robot_moves_a_world_point_to_the_predicted_pixel() -> None:
    pose = {"X": X_BASE_TOOL_A}
    camera = FakeCamera("ribs", robot_pose=lambda: pose["X"], resolution=RESOLUTION, noise="none")
    camera.connect()
    cap_a = camera.capture()
    assert np.allclose(camera.X_world_camera(), expected_X_world_camera(X_BASE_TOOL_A, 0.0), atol=1e-12)
    assert_rendered_from(cap_a, expected_X_world_camera(X_BASE_TOOL_A, 0.0))
    uv_a = assert_point_imaged_at_prediction(cap_a, expected_X_world_camera(X_BASE_TOOL_A, 0.0))

    X_b = offset_pose(X_BASE_TOOL_A, (0.03, -0.02, 0.02), yaw_deg=8.0)
    pose["X"] = X_b
    cap_b = camera.capture()
    X_world_camera_b = expected_X_world_camera(X_b, 0.0)
    assert_rendered_from(cap_b, X_world_camera_b)
    uv_b = assert_point_imaged_at_prediction(cap_b, X_world_camera_b)
    assert np.linalg.norm(uv_b - uv_a) > 15.0  # the picture really changed
    # and the old pixel now shows another place
    assert np.linalg.norm(world_point_seen_at(cap_b, X_world_camera_b, uv_a) - P_WORLD) > 0.01


@pytest.mark.timeout(30)
def test_moving_the_track_moves_the_camera_along_the_track_axis() -> None:
    track = {"m": 0.0}
    camera = FakeCamera(
        "ribs",
        robot_pose=lambda: X_BASE_TOOL_A,
        track_position_m=lambda: track["m"],
        resolution=RESOLUTION,
        noise="none",
    )
    camera.connect()
    uv_0 = assert_point_imaged_at_prediction(camera.capture(), expected_X_world_camera(X_BASE_TOOL_A, 0.0))
    track["m"] = 0.04
    cap = camera.capture()
    assert_rendered_from(cap, expected_X_world_camera(X_BASE_TOOL_A, 0.04))
    uv_1 = assert_point_imaged_at_prediction(cap, expected_X_world_camera(X_BASE_TOOL_A, 0.04))
    # base +y is world +x; the camera looks straight down with its image axes turned against the world's, so
    # 40 mm of track shifts the point by 40 mm * fx / z pixels along one image axis only
    z_camera = float(transform_points(invert_X(expected_X_world_camera(X_BASE_TOOL_A, 0.04)), P_WORLD)[0, 2])
    shift = uv_1 - uv_0
    assert abs(np.linalg.norm(shift) - 0.04 * cap.intrinsics.fx / z_camera) < 1e-6
    assert min(abs(shift[0]), abs(shift[1])) < 1e-6


@pytest.mark.timeout(40)
def test_real_fake_robot_and_track_drive_the_picture() -> None:
    with FakeFanucController() as fanuc_fake, FakeTrack(soft_limits_m=(0.0, 1.0), enabled=True) as track_fake:
        robot = FanucRobot("127.0.0.1", port=fanuc_fake.port, timeout_s=1.0, status_poll_s=0.02)
        track = ModbusTrack("127.0.0.1", port=track_fake.port, counts_per_m=track_fake.counts_per_m, timeout_s=0.5)
        camera = FakeCamera("ribs", robot_pose=robot, track_position_m=track, resolution=RESOLUTION, noise="none")
        robot.connect()
        track.connect()
        try:
            camera.connect()
            X_b = offset_pose(robot.get_X_base_tool(), (0.02, 0.01, 0.0), yaw_deg=0.0)
            robot.move_linear(X_b, speed_m_s=0.25, timeout_s=10)
            track.move_to(0.03, speed_m_s=0.3, timeout_s=10)
            cap = camera.capture()
            X_world_camera = expected_X_world_camera(robot.get_X_base_tool(), track.position_m())
            assert abs(track.position_m() - 0.03) < 1e-9
            assert np.allclose(robot.get_X_base_tool()[:3, 3], X_b[:3, 3], atol=1e-4)
            assert_rendered_from(cap, X_world_camera)
            assert_point_imaged_at_prediction(cap, X_world_camera)
            camera.disconnect()
        finally:
            robot.disconnect()
            track.disconnect()


@pytest.mark.timeout(20)
def test_pose_source_failure_is_connection_lost() -> None:
    def unreachable() -> np.ndarray:
        raise ConnectionLost("robot: not connected")

    camera = FakeCamera("ribs", robot_pose=unreachable, resolution=(160, 90))
    camera.connect()
    with pytest.raises(ConnectionLost, match="needs the robot and track pose"):
        camera.capture()


# ---------------------------------------------------------------------------------------------- playback
@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    scene = with_resolution(get_scene("ribs"), 160, 90)
    root = tmp_path_factory.mktemp("playback")
    folders = []
    for i, yaw in enumerate((0.0, 20.0)):
        X_world_camera = expected_X_world_camera(offset_pose(X_BASE_TOOL_A, (0, 0, 0), yaw), 0.0)
        result = render(scene, noise="none", seed=i, with_pose=True, X_world_camera=X_world_camera)
        folders.append(save_capture(result.capture, root / f"shot{i}", depth_format="npy"))
    return folders


@pytest.mark.timeout(20)
def test_playback_cycles_through_the_folders(recorded: list[Path]) -> None:
    camera = FakeCamera(playback=recorded)
    camera.connect()
    frames = [camera.capture() for _ in range(3)]
    originals = [load_capture(f) for f in recorded]
    assert originals[0].X_base_tool is not None  # the folders hold a pose ...
    for frame, original in zip(frames, [originals[0], originals[1], originals[0]], strict=True):
        assert_valid_capture(frame)  # ... which a camera does not deliver
        assert np.array_equal(frame.depth_m, original.depth_m, equal_nan=True)
        assert np.array_equal(frame.color_rgb, original.color_rgb)
        assert frame.intrinsics == original.intrinsics
    assert not np.array_equal(frames[0].depth_m, frames[1].depth_m, equal_nan=True)


@pytest.mark.timeout(20)
def test_playback_of_a_broken_or_missing_folder(recorded: list[Path], tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "camera.json").write_text('{"width": 160}')
    camera = FakeCamera(playback=[broken])
    camera.connect()
    with pytest.raises(CorruptFrame, match=r"camera\.json"):
        camera.capture()
    with pytest.raises(ConnectionLost, match="does not exist"):
        FakeCamera(playback=[tmp_path / "nowhere"]).connect()


# ---------------------------------------------------------------------------------------------- faults
@pytest.mark.timeout(20)
def test_faults_need_no_params_and_must_be_known() -> None:
    camera = FakeCamera(robot_pose=lambda: X_BASE_TOOL_A, resolution=(160, 90))
    with pytest.raises(ValueError):
        camera.inject("meteor_strike")
    with pytest.raises(ValueError):
        camera.inject("corrupt_frame", rows=3)
    camera.inject("drop_connection")
    with pytest.raises(ConnectionLost):
        camera.connect()
    camera.clear_faults()
    camera.connect()
    assert_valid_capture(camera.capture())


@pytest.mark.timeout(20)
def test_clearing_frame_timeout_releases_a_waiting_capture() -> None:
    camera = FakeCamera(robot_pose=lambda: X_BASE_TOOL_A, resolution=(160, 90))
    camera.connect()
    camera.inject("frame_timeout")
    timer = threading.Timer(0.2, camera.clear_faults)
    timer.start()
    t0 = time.monotonic()
    try:
        cap = camera.capture(timeout_s=5.0)
    finally:
        timer.cancel()
    assert time.monotonic() - t0 < 2.0
    assert_valid_capture(cap)


@pytest.mark.timeout(10)
def test_constructor_refuses_bad_arguments() -> None:
    bad: list[Callable[[], Any]] = [
        lambda: FakeCamera("no_such_scene"),
        lambda: FakeCamera(resolution=(8, 8)),
        lambda: FakeCamera(noise="fuzzy"),  # type: ignore[arg-type]
        lambda: FakeCamera(track_axis_base=(1.0, 1.0, 0.0)),
    ]
    for make in bad:
        with pytest.raises((ValueError, KeyError)):
            make()
