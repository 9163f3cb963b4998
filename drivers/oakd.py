"""Luxonis OAK-D through depthai v3: colour + stereo depth aligned to the colour camera, as a ``Capture``.

Pipeline (depthai v3 API)::

    device = dai.Device(...);  pipeline = dai.Pipeline(device)
    rgb   = pipeline.create(dai.node.Camera).build(CAM_A)   -> requestOutput((W, H), undistorted)
    left  = pipeline.create(dai.node.Camera).build(CAM_B)   -> requestOutput(stereo size) -> stereo.left
    right = pipeline.create(dai.node.Camera).build(CAM_C)   -> requestOutput(stereo size) -> stereo.right
    stereo = pipeline.create(dai.node.StereoDepth)          depth aligned to the colour output:
        RVC2: rgb output -> stereo.inputAlignTo;  RVC4: stereo.depth -> ImageAlign(inputAlignTo = rgb output)
    sync = pipeline.create(dai.node.Sync)                   {"rgb", "depth"} -> one MessageGroup
    queue = sync.out.createOutputQueue(); pipeline.start()

Conversions (pure functions, unit-tested without hardware):

- :func:`scale_intrinsics`: the calibration matrix of the colour socket at its calibration size to
  :class:`CameraIntrinsics` at the output size, by the same rule as depthai v3's
  ``CalibrationHandler.getCameraIntrinsics(socket, W, H)`` (keepAspectRatio; the tests compare the two): the
  device registers depth to the colour output with that matrix, so backprojecting with it reproduces the
  device's 3D points.
- :func:`depth_m_from_mm`: depthai's uint16 depth in millimetres to float32 metres, NaN where 0 (no data)
  or beyond ``max_depth_m``, as the capture format wants.
- :func:`check_frames` / :func:`validated_capture`: refuse a frame that is not what was asked for
  (:class:`CorruptFrame`).

depthai is imported lazily (only :meth:`OakDCamera.connect` needs it) with an install hint when missing.
Hardware behaviour (device discovery, alignment on RVC2 vs RVC4, undistortion) is exercised only by the test
that runs when ``WELDCELL_OAKD=1`` names a connected camera.
"""

from __future__ import annotations

import contextlib
import datetime
import logging
import threading
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.errors import CameraTimeout, ConnectionLost, CorruptFrame, DriverNotInstalled
from perception.capture import CameraIntrinsics, Capture
from perception.errors import BadCapture

logger = logging.getLogger(__name__)

OAKD_DEPTH_SCALE = 1000.0
"""depthai's depth frames count millimetres: 1000 units per metre (the capture's ``depth_scale``)."""

INSTALL_HINT = "the OAK-D driver needs depthai v3: pip install 'depthai>=3.0,<4' (it is in weldcell's dependencies)"


def _import_depthai() -> Any:
    try:
        import depthai
    except ImportError as err:
        raise DriverNotInstalled(f"cannot import depthai ({err}); {INSTALL_HINT}") from err
    version = getattr(depthai, "__version__", "0")
    if not str(version).startswith("3."):
        raise DriverNotInstalled(f"depthai {version} is installed but this driver is written for v3; {INSTALL_HINT}")
    return depthai


# ================================================================================================ pure
def scale_intrinsics(K: ArrayLike, *, calib_size: tuple[int, int], output_size: tuple[int, int]) -> CameraIntrinsics:
    """Intrinsics of the colour output at ``output_size`` from the calibration matrix at ``calib_size``.

    ``K``: (3, 3) camera matrix (pixels) at ``calib_size`` = (width, height). The rule is depthai v3's
    ``CalibrationHandler.getCameraIntrinsics(socket, W, H)`` with ``keepAspectRatio`` (what the Camera node's
    outputs follow):

    - a 4:3-or-taller output (W/H <= 1.34) of a 16:9-like calibration (1.5 < W0/H0 <= 1.778) shows more of the
      sensor: scale = min(W/W0, H/H0), and the principal point moves by half the extra rows (or columns);
    - otherwise the image is scaled to cover the output, scale = max(W/W0, H/H0), and centre-cropped: the
      principal point moves back by half the cropped excess.
    """
    M = np.asarray(K, dtype=np.float64)
    if M.shape != (3, 3) or not np.all(np.isfinite(M)):
        raise CorruptFrame(f"the calibration matrix must be a finite 3x3 array, got shape {M.shape}")
    w0, h0 = int(calib_size[0]), int(calib_size[1])
    w, h = int(output_size[0]), int(output_size[1])
    if min(w0, h0, w, h) <= 0:
        raise CorruptFrame(f"image sizes must be positive, got calibration {w0}x{h0}, output {w}x{h}")
    fx, fy, cx, cy = M[0, 0], M[1, 1], M[0, 2], M[1, 2]
    calib_ratio, output_ratio = w0 / h0, w / h
    if output_ratio <= 1.34 and 1.5 < calib_ratio <= 1.778:
        scale = min(w / w0, h / h0)
        fx, fy, cx, cy = fx * scale, fy * scale, cx * scale, cy * scale
        if scale * h0 < h:
            cy += (h - h0 * scale) / 2.0
        elif scale * w0 > w:
            cx += (w - w0 * scale) / 2.0
    else:
        scale = h / h0
        if scale * w0 < w:
            scale = w / w0
        fx, fy, cx, cy = fx * scale, fy * scale, cx * scale, cy * scale
        if scale * h0 > h:
            cy -= (h0 * scale - h) / 2.0
        elif scale * w0 > w:
            cx -= (w0 * scale - w) / 2.0
    try:
        return CameraIntrinsics(w, h, float(fx), float(fy), float(cx), float(cy))
    except BadCapture as err:
        raise CorruptFrame(f"the device calibration gives implausible intrinsics at {w}x{h}: {err}") from err


def depth_m_from_mm(depth_mm: ArrayLike, *, max_depth_m: float | None = None) -> NDArray[np.float32]:
    """(H, W) float32 metres from depthai's (H, W) uint16 millimetres; 0 (no data) and > ``max_depth_m`` -> NaN."""
    raw = np.asarray(depth_mm)
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise CorruptFrame(f"depth frame must be (H, W) uint16 millimetres, got {raw.dtype} {raw.shape}")
    depth = raw.astype(np.float32) / np.float32(OAKD_DEPTH_SCALE)
    invalid = raw == 0
    if max_depth_m is not None:
        invalid |= depth > np.float32(max_depth_m)
    depth[invalid] = np.nan
    return depth


def rgb_from_bgr(frame: ArrayLike) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 RGB from an OpenCV frame: BGR (H, W, 3), BGRA (H, W, 4) or grey (H, W)."""
    img = np.asarray(frame)
    if img.dtype != np.uint8:
        raise CorruptFrame(f"colour frame must be 8-bit, got {img.dtype}")
    if img.ndim == 2:
        return np.ascontiguousarray(np.repeat(img[:, :, None], 3, axis=2))
    if img.ndim == 3 and img.shape[2] in (3, 4):
        return np.ascontiguousarray(img[:, :, 2::-1])
    raise CorruptFrame(f"colour frame must be (H, W), (H, W, 3) or (H, W, 4), got {img.shape}")


def check_frames(
    color_rgb: ArrayLike,
    depth_m: ArrayLike,
    *,
    expected_size: tuple[int, int],
    min_valid_depth_share: float = 0.0,
) -> None:
    """Raise :class:`CorruptFrame` unless colour and depth are the registered (W, H) images that were asked for.

    ``color_rgb``: (H, W, 3) uint8. ``depth_m``: (H, W) float metres, NaN = no data.
    ``min_valid_depth_share``: the least fraction of pixels with depth (a frame below it is refused).
    """
    color = np.asarray(color_rgb)
    depth = np.asarray(depth_m)
    w, h = expected_size
    if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise CorruptFrame(f"colour frame must be (H, W, 3) uint8, got {color.dtype} {color.shape}")
    if depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
        raise CorruptFrame(f"depth frame must be (H, W) float metres, got {depth.dtype} {depth.shape}")
    if color.shape[:2] != (h, w):
        raise CorruptFrame(f"colour frame is {color.shape[1]}x{color.shape[0]}, expected {w}x{h}")
    if depth.shape != (h, w):
        raise CorruptFrame(
            f"depth frame is {depth.shape[1]}x{depth.shape[0]} but colour is {w}x{h}: not registered to it"
        )
    if np.isinf(depth).any():
        raise CorruptFrame(f"depth frame contains {int(np.isinf(depth).sum())} infinite values")
    valid = np.isfinite(depth) & (depth > 0)
    if (depth[np.isfinite(depth)] < 0).any():
        raise CorruptFrame("depth frame contains negative values")
    share = float(valid.mean()) if valid.size else 0.0
    if share == 0.0 or share < min_valid_depth_share:
        raise CorruptFrame(
            f"only {share * 100:.2f}% of the pixels have depth (at least {min_valid_depth_share * 100:.2f}% "
            "and one pixel needed): the stereo pair saw nothing or the frame is broken"
        )


def validated_capture(
    color_rgb: ArrayLike,
    depth_m: ArrayLike,
    intrinsics: CameraIntrinsics,
    *,
    depth_scale: float = OAKD_DEPTH_SCALE,
    source: str = "",
    min_valid_depth_share: float = 0.0,
    **extra_fields: Any,
) -> Capture:
    """A :class:`Capture` of checked frames; any problem is a :class:`CorruptFrame` naming ``source``.

    ``extra_fields`` are passed on to ``Capture`` (``prompts_px``, ``ground_truth``...).
    """
    try:
        check_frames(
            color_rgb,
            depth_m,
            expected_size=(intrinsics.width, intrinsics.height),
            min_valid_depth_share=min_valid_depth_share,
        )
        return Capture(
            color_rgb=np.asarray(color_rgb),
            depth_m=np.asarray(depth_m, dtype=np.float32),
            intrinsics=intrinsics,
            depth_scale=depth_scale,
            source=source,
            **extra_fields,
        )
    except CorruptFrame as err:
        raise CorruptFrame(f"{source}: {err}" if source else str(err)) from err
    except BadCapture as err:
        raise CorruptFrame(f"{source}: invalid frame: {err}" if source else f"invalid frame: {err}") from err


# ================================================================================================ driver
class OakDCamera:
    """An OAK-D (OAK-D, OAK-D Pro, OAK-D S2...) as a :class:`drivers.protocols.Camera`.

    ``device_id``: the device's id or IP address (None: the first one found). ``resolution``: (W, H) of the
    colour output and of the aligned depth. ``stereo_resolution``: (W, H) requested from the mono cameras.
    ``max_depth_m``: depth beyond it becomes NaN. ``rgb_socket``/``left_socket``/``right_socket``: depthai
    ``CameraBoardSocket`` names. ``min_valid_depth_share``: a frame with less depth is refused as corrupt.
    """

    def __init__(
        self,
        *,
        device_id: str | None = None,
        name: str = "oakd",
        resolution: tuple[int, int] = (1280, 720),
        stereo_resolution: tuple[int, int] = (1280, 800),
        fps: float = 10.0,
        max_depth_m: float = 10.0,
        rgb_socket: str = "CAM_A",
        left_socket: str = "CAM_B",
        right_socket: str = "CAM_C",
        min_valid_depth_share: float = 0.01,
    ) -> None:
        if resolution[0] % 16:
            raise ValueError(f"the aligned depth output needs a width that is a multiple of 16, got {resolution}")
        if not (fps > 0 and max_depth_m > 0):
            raise ValueError(f"fps and max_depth_m must be > 0, got {fps}, {max_depth_m}")
        self.name = name
        self.device_id = device_id
        self.resolution = (int(resolution[0]), int(resolution[1]))
        self.stereo_resolution = (int(stereo_resolution[0]), int(stereo_resolution[1]))
        self.fps = float(fps)
        self.max_depth_m = float(max_depth_m)
        self.rgb_socket = rgb_socket
        self.left_socket = left_socket
        self.right_socket = right_socket
        self.min_valid_depth_share = min_valid_depth_share
        self._device: Any = None
        self._pipeline: Any = None
        self._queue: Any = None
        self._intrinsics: CameraIntrinsics | None = None
        self._lock = threading.Lock()

    @property
    def intrinsics(self) -> CameraIntrinsics:
        if self._intrinsics is None:
            raise ConnectionLost(f"{self.name}: not connected; call connect() first")
        return self._intrinsics

    def connect(self) -> None:
        """Open the device, build and start the pipeline, read the colour socket's calibration."""
        dai = _import_depthai()
        with self._lock:
            self._close()
            try:
                if self.device_id:
                    device = dai.Device(dai.DeviceInfo(self.device_id))
                else:
                    device = dai.Device()
            except RuntimeError as err:
                which = self.device_id or "any OAK device"
                raise ConnectionLost(
                    f"{self.name}: cannot open {which}: {err}; check the USB/PoE connection and [camera] device_id"
                ) from err
            try:
                pipeline, queue = self._build(dai, device)
                calib = device.readCalibration()
                socket = getattr(dai.CameraBoardSocket, self.rgb_socket)
                K, calib_w, calib_h = calib.getDefaultIntrinsics(socket)
                intrinsics = scale_intrinsics(K, calib_size=(calib_w, calib_h), output_size=self.resolution)
                pipeline.start()
            except RuntimeError as err:
                with contextlib.suppress(Exception):
                    device.close()
                raise ConnectionLost(f"{self.name}: cannot start the depthai pipeline: {err}") from err
            self._device, self._pipeline, self._queue, self._intrinsics = device, pipeline, queue, intrinsics
            logger.info(
                "%s: OAK %s started, %dx%d @ %.1f fps, fx=%.2f fy=%.2f cx=%.2f cy=%.2f px",
                self.name,
                self.device_id or "(first found)",
                intrinsics.width,
                intrinsics.height,
                self.fps,
                intrinsics.fx,
                intrinsics.fy,
                intrinsics.cx,
                intrinsics.cy,
            )

    def _build(self, dai: Any, device: Any) -> tuple[Any, Any]:
        pipeline = dai.Pipeline(device)
        sockets = dai.CameraBoardSocket
        rgb = pipeline.create(dai.node.Camera).build(getattr(sockets, self.rgb_socket))
        left = pipeline.create(dai.node.Camera).build(getattr(sockets, self.left_socket))
        right = pipeline.create(dai.node.Camera).build(getattr(sockets, self.right_socket))
        stereo = pipeline.create(dai.node.StereoDepth)
        sync = pipeline.create(dai.node.Sync)
        stereo.setLeftRightCheck(True)  # needed for alignment, and drops occluded pixels
        stereo.setSubpixel(True)
        # no median post-filter: it rounds corners and grooves over its window, correlates the noise the
        # detector measures, and takes invalid (zero) disparities into its windows, pushing a face seen with
        # dropouts (a wall at a grazing angle) back by a few tenths of a millimetre. The detector's fits
        # average the noise themselves
        stereo.initialConfig.setMedianFilter(dai.StereoDepthConfig.MedianFilter.MEDIAN_OFF)
        stereo.setExtendedDisparity(False)
        sync.setSyncThreshold(datetime.timedelta(seconds=0.5 / self.fps))
        rgb_out = rgb.requestOutput(self.resolution, fps=self.fps, enableUndistortion=True)
        left.requestOutput(self.stereo_resolution, fps=self.fps).link(stereo.left)
        right.requestOutput(self.stereo_resolution, fps=self.fps).link(stereo.right)
        rgb_out.link(sync.inputs["rgb"])
        if device.getPlatform() == dai.Platform.RVC4:
            align = pipeline.create(dai.node.ImageAlign)
            stereo.depth.link(align.input)
            rgb_out.link(align.inputAlignTo)
            align.outputAligned.link(sync.inputs["depth"])
        else:
            stereo.setOutputSize(*self.resolution)
            rgb_out.link(stereo.inputAlignTo)
            stereo.depth.link(sync.inputs["depth"])
        queue = sync.out.createOutputQueue(maxSize=2, blocking=False)
        return pipeline, queue

    def disconnect(self) -> None:
        """Stop the pipeline and close the device; safe to call twice."""
        with self._lock:
            self._close()

    def _close(self) -> None:
        pipeline, device = self._pipeline, self._device
        self._pipeline = self._device = self._queue = None
        self._intrinsics = None
        if pipeline is not None:
            with contextlib.suppress(Exception):
                pipeline.stop()
        if device is not None:
            with contextlib.suppress(Exception):
                device.close()

    def capture(self, *, timeout_s: float = 5.0) -> Capture:
        """A colour + aligned depth pair taken after this call (older queued frames are dropped)."""
        with self._lock:
            queue, pipeline, intrinsics = self._queue, self._pipeline, self._intrinsics
            if queue is None or pipeline is None or intrinsics is None:
                raise ConnectionLost(f"{self.name}: not connected; call connect() first")
            try:
                if not pipeline.isRunning():
                    raise ConnectionLost(f"{self.name}: the depthai pipeline stopped (device lost?); reconnect")
                queue.tryGetAll()  # frames exposed before this call may show the robot still moving
                group = queue.get(datetime.timedelta(seconds=timeout_s))
            except RuntimeError as err:
                raise ConnectionLost(f"{self.name}: lost the device while waiting for a frame: {err}") from err
            if group is None:
                raise CameraTimeout(f"{self.name}: no synchronised colour + depth frame within {timeout_s:.1f} s")
            return self._to_capture(group, intrinsics)

    def _to_capture(self, group: Any, intrinsics: CameraIntrinsics) -> Capture:
        try:
            color_frame, depth_frame = group["rgb"], group["depth"]
        except (KeyError, IndexError, RuntimeError) as err:
            raise CorruptFrame(f"{self.name}: the synchronised group lacks rgb or depth: {err}") from err
        if color_frame is None or depth_frame is None:
            raise CorruptFrame(f"{self.name}: the synchronised group lacks rgb or depth")
        color = rgb_from_bgr(color_frame.getCvFrame())
        depth = depth_m_from_mm(depth_frame.getFrame(), max_depth_m=self.max_depth_m)
        seq = color_frame.getSequenceNum()
        return validated_capture(
            color,
            depth,
            intrinsics,
            source=f"{self.name}:{self.device_id or 'oak'}:{seq}",
            min_valid_depth_share=self.min_valid_depth_share,
        )


def valid_depth_share(depth_m: NDArray[np.floating[Any]]) -> float:
    """The fraction of pixels with a depth value (finite and > 0)."""
    d = np.asarray(depth_m)
    return float((np.isfinite(d) & (d > 0)).mean()) if d.size else 0.0
