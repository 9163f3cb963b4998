"""A fake RGB-D camera on the robot's wrist: renders the simulator's workpiece from where the robot is now.

Camera pose in the scene's world frame, composed so inner names meet::

    X_world_camera = X_world_base0 @ X_base0_base(track position) @ X_base_tool(robot) @ X_tool_camera

- ``X_world_base0 = inverse(X_base_world)``: the robot base with the track at 0 (``X_base_world`` defaults to
  :data:`sim_fakes.render.X_BASE_WORLD`, where the scenes sit in front of the robot).
- ``X_base0_base``: the carriage's translation ``position_m * track_axis_base`` (the track carries the base
  along ``track_axis_base``, a unit vector in the base frame; default base +y, the scenes' long world x axis).
- ``X_base_tool``: the robot's current tool pose, read from a callable or a ``Robot`` driver at each capture.
- ``X_tool_camera``: the true camera mount (default :data:`sim_fakes.render.X_TOOL_CAMERA`), which the hand-eye
  calibration estimates; the cell's configured hand-eye is a separate thing on purpose.

So moving the fake robot (or the fake track) really changes the picture. Rendering is synchronous and takes
about 0.05 s at 320x180, 0.5 s at 640x360 and 1-2 s at 1280x720 (2-core machine): pick ``resolution``
accordingly. Alternatively the camera plays back capture folders, cycling through them.

The scene ``"charuco"`` shows a ChArUco calibration board (:class:`BoardTarget`) instead of a weldment: the
board lies at ``X_base_board`` (robot base frame with the track at 0), so the camera sees
``X_camera_board = inverse(X_base0_base @ X_base_tool @ X_tool_camera) @ X_base_board``. The board picture is
warped into the image by :func:`sim_fakes.board_render.render_view` (supersampled, lens blur, sensor noise; the
colour image is that gray picture in all three channels) and the depth is the exact distance to the board's
plane (the table it lies on). The true ``X_camera_board`` travels in ``capture.extra["X_camera_board"]``.
About 0.03 s per frame at 640x360.

Every frame goes through :func:`drivers.oakd.validated_capture`, the same validation as the real camera's, and
comes back without a pose (``X_base_tool`` None: the cell adds it); rendered frames keep their prompts and
ground truth (camera frame) for evaluation.

Faults (:class:`sim_fakes.faults.FaultInjectable`), each on until :meth:`FakeCamera.clear_faults`:

- ``"frame_timeout"``: :meth:`capture` waits its whole ``timeout_s`` and raises :class:`CameraTimeout`.
- ``"corrupt_frame"``: the frame arrives torn (the depth image loses its last rows), the validation refuses it
  and :meth:`capture` raises :class:`CorruptFrame`.
- ``"drop_connection"``: :meth:`capture` and :meth:`connect` raise :class:`ConnectionLost`.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.errors import CameraTimeout, ConnectionLost, CorruptFrame, DriverError
from drivers.oakd import validated_capture
from drivers.protocols import Robot, Track
from perception.capture import CameraIntrinsics, Capture, load_capture
from perception.errors import BadCapture
from perception.transforms import check_X, invert_X, make_X
from sim_fakes.board_render import BoardPicture, RenderParams
from sim_fakes.render import NOISE_MODELS, SIM_DEPTH_SCALE, X_BASE_WORLD, X_TOOL_CAMERA, NoiseModel, render
from sim_fakes.scenes import CameraSetup, Scene, get_scene, with_resolution

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
PoseSource = Callable[[], ArrayLike] | Robot
PositionSource = Callable[[], float] | Track

TORN_ROWS = 8
"""Rows a corrupt frame loses from its depth image."""

CHARUCO_SCENE = "charuco"
"""The scene name that shows a :class:`BoardTarget` instead of a weldment."""


@dataclass(frozen=True)
class BoardTarget:
    """The ChArUco board of the ``"charuco"`` scene and how it is imaged.

    ``board``: the board's definition (a ``calibration.board.CharucoBoardSpec``, or anything that draws its
    picture: :class:`sim_fakes.board_render.BoardPicture`). ``X_base_board``: (4, 4) its pose in the robot base
    frame with the track at 0, metres (board z points away from the printed face, into the table). ``imaging``:
    supersampling, lens blur, sensor noise, background and the picture's resolution
    (:class:`sim_fakes.board_render.RenderParams`, which checks them).
    """

    board: BoardPicture
    X_base_board: FloatArray
    imaging: RenderParams = field(default_factory=RenderParams)

    def __post_init__(self) -> None:
        object.__setattr__(self, "X_base_board", check_X(self.X_base_board, name="X_base_board"))


@dataclass(frozen=True)
class _Frame:
    """A board frame before validation (a camera looking away from the table has no depth, which the
    validation refuses as :class:`CorruptFrame`, as it does for the real camera)."""

    color_rgb: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    intrinsics: CameraIntrinsics
    extra: dict[str, Any]
    depth_scale: float = SIM_DEPTH_SCALE
    prompts_px: None = None
    ground_truth: None = None


def _board_scene() -> Scene:
    """The ``"charuco"`` scene: no parts, the same camera model as the weldment scenes (1280x720, f = 920 px)."""
    camera = CameraSetup(eye=(0.0, 0.0, 0.5), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    return Scene(CHARUCO_SCENE, "a ChArUco calibration board lying on the table", (), (), camera)


class FakeCamera:
    """A :class:`drivers.protocols.Camera` rendering ``scene`` from the live robot and track pose.

    ``scene``: a scene name from :data:`sim_fakes.scenes.SCENES` or a :class:`Scene`, or ``"charuco"`` with
    ``board`` (a :class:`BoardTarget`) for a calibration board.
    ``robot_pose``: a callable returning (4, 4) ``X_base_tool`` in metres, or a ``Robot`` (its
    ``get_X_base_tool``); None renders from the scene's own fixed camera instead.
    ``track_position_m``: a callable returning metres, or a ``Track`` (its ``position_m``); None = no track.
    ``resolution``: (W, H) of the rendered image (focal length scales with the width); None keeps the scene's.
    ``noise``/``seed``: the renderer's depth noise model; frame k uses ``seed + k`` (deterministic sequence).
    ``playback``: capture folders to play back in a cycle instead of rendering.
    ``X_tool_camera``: the camera's true mount on the tool (what a hand-eye calibration should find).
    """

    supported_faults: frozenset[str] = frozenset({"frame_timeout", "corrupt_frame", "drop_connection"})

    def __init__(
        self,
        scene: str | Scene = "ribs",
        *,
        name: str = "fake-camera",
        robot_pose: PoseSource | None = None,
        track_position_m: PositionSource | None = None,
        X_tool_camera: ArrayLike = X_TOOL_CAMERA,
        X_base_world: ArrayLike = X_BASE_WORLD,
        track_axis_base: tuple[float, float, float] = (0.0, 1.0, 0.0),
        resolution: tuple[int, int] | None = None,
        noise: NoiseModel = "stereo",
        seed: int = 0,
        playback: Sequence[str | os.PathLike[str]] | None = None,
        board: BoardTarget | None = None,
    ) -> None:
        if noise not in NOISE_MODELS:
            raise ValueError(f"unknown noise model {noise!r}; choose one of {NOISE_MODELS}")
        if (scene == CHARUCO_SCENE) != (board is not None):
            raise ValueError(f"scene {CHARUCO_SCENE!r} and board=BoardTarget(...) go together")
        if scene == CHARUCO_SCENE:
            base_scene = _board_scene()
        else:
            base_scene = get_scene(scene) if isinstance(scene, str) else scene
        if resolution is not None:
            width, height = int(resolution[0]), int(resolution[1])
            if not (16 <= width <= 8192 and 16 <= height <= 8192):
                raise ValueError(f"resolution must be between 16x16 and 8192x8192, got {resolution}")
            base_scene = with_resolution(base_scene, width, height)
        axis = np.asarray(track_axis_base, dtype=np.float64)
        if axis.shape != (3,) or not np.isclose(np.linalg.norm(axis), 1.0, atol=1e-9):
            raise ValueError(f"track_axis_base must be a unit 3-vector, got {track_axis_base}")
        self.name = name
        self.scene = base_scene
        self.noise: NoiseModel = noise
        self.seed = seed
        self.X_tool_camera = check_X(X_tool_camera, name="X_tool_camera")
        self.X_base_world = check_X(X_base_world, name="X_base_world")
        self.track_axis_base = axis
        self._robot_pose = _pose_callable(robot_pose)
        self._track_position = _position_callable(track_position_m)
        self.playback = [Path(p) for p in playback] if playback else []
        self.board = board
        self._board_picture: NDArray[np.uint8] | None = None
        self._frames = 0
        self._connected = False
        self._capture_lock = threading.Lock()
        self._fault_lock = threading.Lock()
        self._faults: set[str] = set()
        self._faults_changed = threading.Event()

    # ============================================================================== Camera
    def connect(self) -> None:
        with self._fault_lock:
            if "drop_connection" in self._faults:
                raise ConnectionLost(f"{self.name}: the simulated camera is unreachable (drop_connection injected)")
        for folder in self.playback:
            if not folder.is_dir():
                raise ConnectionLost(f"{self.name}: playback folder {folder} does not exist")
        self._connected = True
        logger.info("%s: connected (%s)", self.name, self.describe())

    def disconnect(self) -> None:
        self._connected = False

    def describe(self) -> str:
        """One line: what this fake shows."""
        if self.playback:
            return f"playback of {len(self.playback)} capture folder(s)"
        cam = self.scene.camera
        if self.board is not None:
            b = self.board
            return (
                f"scene {self.scene.name} ({b.board.squares_x}x{b.board.squares_y} board), {cam.width}x{cam.height}, "
                f"blur {b.imaging.blur_sigma_px:g} px, noise {b.imaging.noise_sigma:g} gray levels"
            )
        return f"scene {self.scene.name}, {cam.width}x{cam.height}, noise {self.noise}"

    def X_world_camera(self) -> FloatArray:
        """(4, 4) camera pose in the scene's world frame for the robot and track pose right now."""
        if self._robot_pose is None:
            return self.scene.camera.X_world_camera
        try:
            X_base_tool = check_X(self._robot_pose(), name="X_base_tool")
            position_m = 0.0 if self._track_position is None else float(self._track_position())
        except DriverError as err:
            raise ConnectionLost(f"{self.name}: the simulated camera needs the robot and track pose: {err}") from err
        X_base0_base = make_X(np.eye(3), position_m * self.track_axis_base)
        return invert_X(self.X_base_world) @ X_base0_base @ X_base_tool @ self.X_tool_camera

    def capture(self, *, timeout_s: float = 5.0) -> Capture:
        """One frame: rendered from the current pose (or the next playback folder), validated."""
        with self._capture_lock:
            if not self._connected:
                raise ConnectionLost(f"{self.name}: not connected; call connect() first")
            faults = self._wait_out_timeout_fault(timeout_s)
            if "drop_connection" in faults:
                self._connected = False
                raise ConnectionLost(f"{self.name}: the simulated camera dropped off (drop_connection injected)")
            index = self._frames
            self._frames += 1
            frame = self._playback_frame(index) if self.playback else self._rendered_frame(index)
            color, depth = frame.color_rgb, frame.depth_m
            if "corrupt_frame" in faults:
                depth = depth[:-TORN_ROWS]  # a torn transfer: the depth image lost its last rows
            return validated_capture(
                color,
                depth,
                frame.intrinsics,
                depth_scale=frame.depth_scale,
                source=f"{self.name}:{index}",
                prompts_px=frame.prompts_px,
                ground_truth=frame.ground_truth,
                extra=dict(frame.extra),
            )

    def _wait_out_timeout_fault(self, timeout_s: float) -> set[str]:
        with self._fault_lock:
            faults = set(self._faults)
            self._faults_changed.clear()
        if "frame_timeout" not in faults:
            return faults
        # A camera that stops sending frames: nothing arrives for the whole timeout (unless cleared meanwhile).
        self._faults_changed.wait(timeout_s)
        with self._fault_lock:
            faults = set(self._faults)
        if "frame_timeout" in faults:
            raise CameraTimeout(f"{self.name}: no frame within {timeout_s:.1f} s (frame_timeout injected)")
        return faults

    def X_camera_board(self) -> FloatArray:
        """(4, 4) true pose of the ``"charuco"`` scene's board in the camera frame right now, metres."""
        if self.board is None:
            raise ValueError(f"{self.name}: scene {self.scene.name!r} has no board (use scene {CHARUCO_SCENE!r})")
        X_world_board = invert_X(self.X_base_world) @ self.board.X_base_board
        return invert_X(self.X_world_camera()) @ X_world_board

    def _board_frame(self, index: int) -> _Frame:
        from sim_fakes.board_render import board_picture, render_view

        assert self.board is not None
        params = self.board.imaging
        if self._board_picture is None:
            self._board_picture = board_picture(self.board.board, params)
        cam = self.scene.camera
        intrinsics = CameraIntrinsics(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
        X_camera_board = self.X_camera_board()
        gray = render_view(
            self._board_picture,
            X_camera_board,
            K=intrinsics.K,
            image_size=(cam.width, cam.height),
            params=params,
            rng=np.random.default_rng(self.seed + index),
        )
        logger.debug("%s: frame %d: board at %s m (camera)", self.name, index, X_camera_board[:3, 3])
        return _Frame(
            color_rgb=np.repeat(gray[:, :, None], 3, axis=2),
            depth_m=_plane_depth_m(X_camera_board, intrinsics),
            intrinsics=intrinsics,
            extra={"X_camera_board": X_camera_board},
        )

    def _rendered_frame(self, index: int) -> Capture | _Frame:
        if self.board is not None:
            return self._board_frame(index)
        X_world_camera = self.X_world_camera()
        result = render(self.scene, noise=self.noise, seed=self.seed + index, X_world_camera=X_world_camera)
        logger.debug("%s: frame %d rendered from camera at %s m (world)", self.name, index, X_world_camera[:3, 3])
        return result.capture

    def _playback_frame(self, index: int) -> Capture:
        folder = self.playback[index % len(self.playback)]
        try:
            return load_capture(folder)
        except BadCapture as err:
            raise CorruptFrame(f"{self.name}: playback frame {folder} is not a valid capture: {err}") from err

    # ============================================================================== FaultInjectable
    def inject(self, fault: str, **params: Any) -> None:
        if fault not in self.supported_faults:
            raise ValueError(
                f"fake camera does not support fault {fault!r}; supported: {sorted(self.supported_faults)}"
            )
        if params:
            raise ValueError(f"fault {fault!r} takes no parameters, got {sorted(params)}")
        with self._fault_lock:
            self._faults.add(fault)
            self._faults_changed.set()
        logger.info("%s: inject %s", self.name, fault)

    def clear_faults(self) -> None:
        with self._fault_lock:
            self._faults.clear()
            self._faults_changed.set()


def _plane_depth_m(X_camera_board: FloatArray, intrinsics: CameraIntrinsics) -> NDArray[np.float32]:
    """(H, W) depth along z, metres, of the plane z_board = 0 at every pixel; NaN where the ray misses it.

    Ray of pixel (u, v): ``d = ((u - cx) / fx, (v - cy) / fy, 1)``; it meets the plane with normal ``n`` (board z
    in the camera frame) through ``t`` (board origin) at ``λ = n·t / n·d``, and since d_z = 1 the depth is λ.
    """
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64), np.arange(intrinsics.height, dtype=np.float64))
    n = X_camera_board[:3, 2]
    n_dot_d = n[0] * (u - intrinsics.cx) / intrinsics.fx + n[1] * (v - intrinsics.cy) / intrinsics.fy + n[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = float(n @ X_camera_board[:3, 3]) / n_dot_d
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)


def _pose_callable(source: PoseSource | None) -> Callable[[], ArrayLike] | None:
    if source is None:
        return None
    if isinstance(source, Robot):
        return source.get_X_base_tool
    if callable(source):
        return source
    raise TypeError(f"robot_pose must be a callable or a Robot, got {type(source).__name__}")


def _position_callable(source: PositionSource | None) -> Callable[[], float] | None:
    if source is None:
        return None
    if isinstance(source, Track):
        return source.position_m
    if callable(source):
        return source
    raise TypeError(f"track_position_m must be a callable or a Track, got {type(source).__name__}")
