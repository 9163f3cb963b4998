"""The capture value type and its folder format (docs: ../shared/spec/capture-format.md).

A capture is one registered RGB-D shot: colour and depth on the same pixel grid, pinhole intrinsics,
and optionally the robot pose at the shot with the hand-eye result, operator prompts, and ground truth.

Pixel convention (OpenCV): pixel (u, v) is column u, row v, and its ray is
``((u - cx) / fx, (v - cy) / fy, 1)``. Depth is along the optical axis (z), in metres.

Every reader here refuses bad input with :class:`BadCapture` naming the file and the problem; nothing
returns a half-valid capture.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from perception.errors import BadCapture
from perception.transforms import TransformError, check_X

FloatArray = NDArray[np.float64]

COLOR_FILE = "color.png"
DEPTH_PNG_FILE = "depth.png"
DEPTH_NPY_FILE = "depth.npy"
CAMERA_FILE = "camera.json"
POSE_FILE = "pose.json"
PROMPTS_FILE = "prompts.json"
GROUND_TRUTH_FILE = "ground_truth.json"
JOINT_TYPES = ("fillet", "inside_corner", "lap", "v_groove", "butt")

# Depth beyond this is not a weld cell; it is a unit error (millimetres read as metres, say).
MAX_PLAUSIBLE_DEPTH_M = 20.0


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels (OpenCV convention: pixel centres at integer coordinates)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise BadCapture(f"image size must be positive, got {self.width}x{self.height}")
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in vals):
            raise BadCapture(f"intrinsics contain NaN or inf: fx={self.fx} fy={self.fy} cx={self.cx} cy={self.cy}")
        if self.fx <= 0 or self.fy <= 0:
            raise BadCapture(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if not (0.0 <= self.cx <= self.width and 0.0 <= self.cy <= self.height):
            raise BadCapture(
                f"principal point ({self.cx}, {self.cy}) lies outside the {self.width}x{self.height} image"
            )
        # A focal length far outside 0.2x..20x the width is a wrong file (other camera, other units).
        for f_name, f in (("fx", self.fx), ("fy", self.fy)):
            if not 0.2 * self.width <= f <= 20.0 * self.width:
                raise BadCapture(
                    f"{f_name}={f} px is implausible for an image {self.width} px wide "
                    "(wrong intrinsics file or resolution?)"
                )

    @property
    def K(self) -> FloatArray:
        """(3, 3) camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_json(self, *, depth_scale: float | None = None) -> dict[str, Any]:
        """Open3D-style dict; ``intrinsic_matrix`` is column-major as Open3D writes it."""
        out: dict[str, Any] = {
            "width": self.width,
            "height": self.height,
            "intrinsic_matrix": [self.fx, 0.0, 0.0, 0.0, self.fy, 0.0, self.cx, self.cy, 1.0],
        }
        if depth_scale is not None:
            out["depth_scale"] = depth_scale
        return out

    def project(self, p_camera: FloatArray) -> FloatArray:
        """(N, 2) pixel coordinates (u, v) of (N, 3) camera-frame points (z > 0)."""
        p = np.asarray(p_camera, dtype=np.float64).reshape(-1, 3)
        return np.column_stack([self.fx * p[:, 0] / p[:, 2] + self.cx, self.fy * p[:, 1] / p[:, 2] + self.cy])


@dataclass(frozen=True)
class GroundTruthSeam:
    """One true seam centre line, ordered along the seam; camera frame, metres, shape (N, 3), N >= 2."""

    kind: Literal["linear", "curved"]
    points_camera: FloatArray
    joint: str | None = None  # fillet, inside_corner, lap, v_groove, butt (optional in the file)

    def __post_init__(self) -> None:
        if self.joint is not None and self.joint not in JOINT_TYPES:
            raise BadCapture(f"ground-truth joint must be one of {', '.join(JOINT_TYPES)}, got {self.joint!r}")
        pts = np.asarray(self.points_camera, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 2:
            raise BadCapture(f"a ground-truth seam needs (N>=2, 3) points, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise BadCapture("ground-truth seam points contain NaN or inf")
        if self.kind not in ("linear", "curved"):
            raise BadCapture(f"ground-truth seam kind must be 'linear' or 'curved', got {self.kind!r}")
        object.__setattr__(self, "points_camera", pts)

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.points_camera, axis=0), axis=1).sum())


@dataclass(frozen=True)
class Capture:
    """One registered RGB-D shot.

    Attributes:
        color_rgb: (H, W, 3) uint8, RGB order.
        depth_m: (H, W) float32 depth along z in metres; NaN where there is no data.
        intrinsics: pinhole intrinsics of the (shared) pixel grid.
        depth_scale: depth PNG units per metre used when this capture is saved (1000 = mm).
        X_base_tool: (4, 4) robot pose at the shot, or None.
        X_tool_camera: (4, 4) hand-eye result, or None (given together with X_base_tool).
        prompts_px: (N, 2) float pixel coordinates (u, v) of one point per workpiece surface, or None.
        ground_truth: true seams (camera frame), evaluation only, or None.
        source: where the capture came from (a folder path, a device name), for messages.
    """

    color_rgb: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    intrinsics: CameraIntrinsics
    depth_scale: float = 1000.0
    X_base_tool: FloatArray | None = None
    X_tool_camera: FloatArray | None = None
    prompts_px: FloatArray | None = None
    ground_truth: tuple[GroundTruthSeam, ...] | None = None
    source: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        src = self.source or None
        color = np.asarray(self.color_rgb)
        if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
            raise BadCapture(f"colour must be (H, W, 3) uint8, got {color.shape} {color.dtype}", path=src)
        depth = np.asarray(self.depth_m, dtype=np.float32)
        if depth.ndim != 2:
            raise BadCapture(f"depth must be (H, W), got shape {depth.shape}", path=src)
        if depth.shape != color.shape[:2]:
            raise BadCapture(
                f"colour is {color.shape[1]}x{color.shape[0]} but depth is {depth.shape[1]}x{depth.shape[0]}; "
                "they must be registered to the same pixel grid",
                path=src,
            )
        if (self.intrinsics.width, self.intrinsics.height) != (depth.shape[1], depth.shape[0]):
            raise BadCapture(
                f"intrinsics are for {self.intrinsics.width}x{self.intrinsics.height} but the images are "
                f"{depth.shape[1]}x{depth.shape[0]}",
                path=src,
            )
        if np.isinf(depth).any():
            raise BadCapture("depth contains inf values", path=src)
        valid = np.isfinite(depth)
        if (depth[valid] < 0).any():
            raise BadCapture("depth contains negative values", path=src)
        depth = np.where(valid & (depth > 0), depth, np.float32(np.nan)).astype(np.float32)
        n_valid = int(np.isfinite(depth).sum())
        if n_valid == 0:
            raise BadCapture("all depth is invalid (no pixel has a depth value)", path=src)
        if float(np.nanmax(depth)) > MAX_PLAUSIBLE_DEPTH_M:
            raise BadCapture(
                f"depth up to {float(np.nanmax(depth)):.1f} m is implausible; check depth_scale (units per metre)",
                path=src,
            )
        if not (math.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise BadCapture(f"depth_scale must be a positive number, got {self.depth_scale}", path=src)
        if (self.X_base_tool is None) != (self.X_tool_camera is None):
            raise BadCapture("X_base_tool and X_tool_camera must be given together", path=src)
        if self.X_base_tool is not None and self.X_tool_camera is not None:
            try:
                object.__setattr__(self, "X_base_tool", check_X(self.X_base_tool, name="X_base_tool"))
                object.__setattr__(self, "X_tool_camera", check_X(self.X_tool_camera, name="X_tool_camera"))
            except TransformError as err:
                raise BadCapture(str(err), path=src) from err
        if self.prompts_px is not None:
            object.__setattr__(self, "prompts_px", _check_prompts(self.prompts_px, self.intrinsics, src))
        object.__setattr__(self, "color_rgb", color)
        object.__setattr__(self, "depth_m", depth)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return (int(self.depth_m.shape[0]), int(self.depth_m.shape[1]))

    @property
    def X_base_camera(self) -> FloatArray | None:
        """Camera pose in the robot base frame at the shot, when the pose is known."""
        if self.X_base_tool is None or self.X_tool_camera is None:
            return None
        return self.X_base_tool @ self.X_tool_camera

    def points_camera(self) -> NDArray[np.float32]:
        """Organized (H, W, 3) cloud in the camera frame, NaN where depth is invalid."""
        return backproject(self.depth_m, self.intrinsics)


def backproject(depth_m: NDArray[np.floating[Any]], intrinsics: CameraIntrinsics) -> NDArray[np.float32]:
    """Organized (H, W, 3) float32 cloud, camera frame, metres; NaN where depth is invalid.

    Pixel (u, v) maps to ``z * ((u - cx) / fx, (v - cy) / fy, 1)``: integer pixel coordinates are
    pixel centres (OpenCV), which is what every reader of the spec assumes.
    """
    z = np.asarray(depth_m, dtype=np.float64)
    h, w = z.shape
    ray_x = (np.arange(w, dtype=np.float64) - intrinsics.cx) / intrinsics.fx
    ray_y = (np.arange(h, dtype=np.float64) - intrinsics.cy) / intrinsics.fy
    out = np.empty((h, w, 3), np.float32)  # computed in float64, stored once (no stacked temporaries)
    np.multiply(ray_x[None, :], z, out=out[..., 0])
    np.multiply(ray_y[:, None], z, out=out[..., 1])
    out[..., 2] = z
    return out


def _check_prompts(prompts: Any, intr: CameraIntrinsics, src: str | None) -> FloatArray:
    arr = np.asarray(prompts, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise BadCapture(f"prompts must be a list of [u, v] pairs, got shape {arr.shape}", path=src)
    if not np.all(np.isfinite(arr)):
        raise BadCapture("prompts contain NaN or inf", path=src)
    bad = (arr[:, 0] < 0) | (arr[:, 0] > intr.width - 1) | (arr[:, 1] < 0) | (arr[:, 1] > intr.height - 1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BadCapture(
            f"prompt {i} at (u={arr[i, 0]:g}, v={arr[i, 1]:g}) lies outside the {intr.width}x{intr.height} image",
            path=src,
        )
    return arr


# --------------------------------------------------------------------------------------------------
# Reading


def _read_json(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise BadCapture(f"cannot read file: {err.strerror or err}", path=path) from err
    except UnicodeDecodeError as err:
        raise BadCapture("not UTF-8 text (is this really a JSON file?)", path=path) from err
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as err:
        raise BadCapture(f"malformed JSON at line {err.lineno}, column {err.colno}: {err.msg}", path=path) from err
    except ValueError as err:
        raise BadCapture(str(err), path=path) from err


def _reject_constant(name: str) -> float:
    raise ValueError(f"JSON contains {name}, which is not a number weldcell accepts")


def _number(obj: Any, key: str, path: Path) -> float:
    if key not in obj:
        raise BadCapture(f"missing key {key!r}", path=path)
    val = obj[key]
    if isinstance(val, bool) or not isinstance(val, int | float):
        raise BadCapture(f"{key!r} must be a number, got {val!r}", path=path)
    if not math.isfinite(val):
        raise BadCapture(f"{key!r} is not finite: {val!r}", path=path)
    return float(val)


def read_camera_json(path: Path) -> tuple[CameraIntrinsics, float | None]:
    """Parse camera.json into intrinsics and ``depth_scale`` (None when the key is absent)."""
    obj = _read_json(path)
    if not isinstance(obj, dict):
        raise BadCapture("expected a JSON object with width, height, intrinsic_matrix", path=path)
    width = _number(obj, "width", path)
    height = _number(obj, "height", path)
    if width != int(width) or height != int(height):
        raise BadCapture(f"width and height must be integers, got {width} x {height}", path=path)
    mat = obj.get("intrinsic_matrix")
    if not isinstance(mat, list) or len(mat) != 9:
        raise BadCapture("'intrinsic_matrix' must be a list of 9 numbers (column-major 3x3)", path=path)
    if not all(isinstance(m, int | float) and not isinstance(m, bool) for m in mat):
        raise BadCapture("'intrinsic_matrix' must contain only numbers", path=path)
    m = [float(x) for x in mat]
    if not all(math.isfinite(x) for x in m):
        raise BadCapture("'intrinsic_matrix' contains NaN or inf", path=path)
    # Column-major [fx, 0, 0, 0, fy, 0, cx, cy, 1]. A row-major matrix has cx, cy at 2 and 5.
    if abs(m[8] - 1.0) > 1e-9 or abs(m[2]) > 1e-9 or abs(m[5]) > 1e-9:
        raise BadCapture(
            "'intrinsic_matrix' is not column-major [fx,0,0, 0,fy,0, cx,cy,1] "
            f"(got {m}); a row-major matrix must be transposed",
            path=path,
        )
    depth_scale: float | None = None
    if "depth_scale" in obj:
        depth_scale = _number(obj, "depth_scale", path)
        if depth_scale <= 0:
            raise BadCapture(f"'depth_scale' must be positive (units per metre), got {depth_scale}", path=path)
    try:
        intr = CameraIntrinsics(int(width), int(height), m[0], m[4], m[6], m[7])
    except BadCapture as err:
        raise BadCapture(str(err), path=path) from err
    return intr, depth_scale


def _read_color(path: Path) -> NDArray[np.uint8]:
    import cv2

    if not path.is_file():
        raise BadCapture("missing colour image (color.png is required)", path=path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise BadCapture("cannot decode colour image (corrupt or not a PNG)", path=path)
    if img.dtype != np.uint8:
        raise BadCapture(f"colour image must be 8-bit, got {img.dtype}", path=path)
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    if img.shape[2] == 4:
        img = img[:, :, :3]
    if img.shape[2] != 3:
        raise BadCapture(f"colour image has {img.shape[2]} channels; expected 1, 3 or 4", path=path)
    return np.ascontiguousarray(img[:, :, ::-1])


def _read_depth(folder: Path, depth_scale: float | None, camera_path: Path) -> tuple[NDArray[np.float32], Path]:
    import cv2

    png = folder / DEPTH_PNG_FILE
    npy = folder / DEPTH_NPY_FILE
    if png.is_file():
        if depth_scale is None:
            raise BadCapture("'depth_scale' is missing; it is required to read depth.png", path=camera_path)
        raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise BadCapture("cannot decode depth image (corrupt or not a PNG)", path=png)
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise BadCapture(
                f"depth.png must be single-channel 16-bit, got {raw.dtype} with shape {raw.shape}", path=png
            )
        depth = raw.astype(np.float32) / np.float32(depth_scale)
        depth[raw == 0] = np.nan
        return depth, png
    if npy.is_file():
        try:
            arr = np.load(npy, allow_pickle=False)
        except (ValueError, OSError, EOFError) as err:
            raise BadCapture(f"cannot read depth array: {err}", path=npy) from err
        if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.floating):
            raise BadCapture(f"depth.npy must be a float (H, W) array, got {arr.dtype} {arr.shape}", path=npy)
        if np.isinf(arr).any():
            raise BadCapture(f"depth contains {int(np.isinf(arr).sum())} inf values", path=npy)
        return arr.astype(np.float32), npy
    raise BadCapture("missing depth: the folder needs depth.png or depth.npy", path=folder)


def _read_pose(path: Path) -> tuple[FloatArray, FloatArray]:
    obj = _read_json(path)
    if not isinstance(obj, dict):
        raise BadCapture("expected an object with X_base_tool and X_tool_camera", path=path)
    out = []
    for key in ("X_base_tool", "X_tool_camera"):
        if key not in obj:
            raise BadCapture(f"missing key {key!r}", path=path)
        try:
            out.append(check_X(np.asarray(obj[key], dtype=np.float64), name=key))
        except (TypeError, ValueError) as err:
            raise BadCapture(str(err), path=path) from err
    return out[0], out[1]


def _read_prompts(path: Path) -> FloatArray:
    obj = _read_json(path)
    if not isinstance(obj, dict) or "points" not in obj:
        raise BadCapture('expected an object {"points": [[u, v], ...]}', path=path)
    try:
        arr = np.asarray(obj["points"], dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise BadCapture(f"'points' must be a list of [u, v] pairs: {err}", path=path) from err
    if arr.size and (arr.ndim != 2 or arr.shape[1] != 2):
        raise BadCapture(f"'points' must be a list of [u, v] pairs, got shape {arr.shape}", path=path)
    return arr.reshape(-1, 2)


def read_ground_truth(path: Path) -> tuple[GroundTruthSeam, ...]:
    """Parse ground_truth.json (camera frame)."""
    obj = _read_json(path)
    if not isinstance(obj, dict) or not isinstance(obj.get("seams"), list):
        raise BadCapture("expected an object with a 'seams' list", path=path)
    if obj.get("frame", "camera") != "camera":
        raise BadCapture(f"ground truth must be in the camera frame, got {obj.get('frame')!r}", path=path)
    seams = []
    for i, s in enumerate(obj["seams"]):
        if not isinstance(s, dict):
            raise BadCapture(f"seam {i} is not an object", path=path)
        try:
            seams.append(
                GroundTruthSeam(
                    kind=s.get("kind"),  # type: ignore[arg-type]
                    points_camera=np.asarray(s.get("points"), float),
                    joint=s.get("joint"),
                )
            )
        except (TypeError, ValueError, BadCapture) as err:
            raise BadCapture(f"seam {i}: {err}", path=path) from err
    return tuple(seams)


def load_capture(folder: str | os.PathLike[str]) -> Capture:
    """Read and validate a capture folder; raise :class:`BadCapture` naming the file on any problem."""
    root = Path(folder)
    if not root.exists():
        raise BadCapture("capture folder does not exist", path=root)
    if not root.is_dir():
        raise BadCapture("not a folder (a capture is a folder with color.png, depth and camera.json)", path=root)
    camera_path = root / CAMERA_FILE
    if not camera_path.is_file():
        raise BadCapture("missing camera.json (intrinsics are required)", path=camera_path)
    intr, depth_scale = read_camera_json(camera_path)
    color_path = root / COLOR_FILE
    color = _read_color(color_path)
    depth, depth_path = _read_depth(root, depth_scale, camera_path)
    if depth.shape != color.shape[:2]:
        raise BadCapture(
            f"size mismatch: {color_path.name} is {color.shape[1]}x{color.shape[0]} but {depth_path.name} is "
            f"{depth.shape[1]}x{depth.shape[0]}",
            path=depth_path,
        )
    if (intr.width, intr.height) != (depth.shape[1], depth.shape[0]):
        raise BadCapture(
            f"size mismatch: camera.json says {intr.width}x{intr.height} but the images are "
            f"{depth.shape[1]}x{depth.shape[0]}",
            path=camera_path,
        )
    finite = np.isfinite(depth) & (depth > 0)
    if not finite.any():
        raise BadCapture("all depth is invalid (every pixel is 0 or NaN)", path=depth_path)
    if (depth[finite] < 0).any():
        raise BadCapture("depth contains negative values", path=depth_path)
    z_max = float(depth[finite].max())
    if z_max > MAX_PLAUSIBLE_DEPTH_M:
        raise BadCapture(
            f"depth up to {z_max:.1f} m is implausible; check depth_scale in camera.json (units per metre)",
            path=depth_path,
        )
    X_base_tool = X_tool_camera = None
    if (root / POSE_FILE).is_file():
        X_base_tool, X_tool_camera = _read_pose(root / POSE_FILE)
    prompts = None
    if (root / PROMPTS_FILE).is_file():
        prompts = _read_prompts(root / PROMPTS_FILE)
        try:
            _check_prompts(prompts, intr, None)
        except BadCapture as err:
            raise BadCapture(str(err), path=root / PROMPTS_FILE) from err
    gt = read_ground_truth(root / GROUND_TRUTH_FILE) if (root / GROUND_TRUTH_FILE).is_file() else None
    try:
        return Capture(
            color_rgb=color,
            depth_m=depth,
            intrinsics=intr,
            depth_scale=depth_scale if depth_scale is not None else 1000.0,
            X_base_tool=X_base_tool,
            X_tool_camera=X_tool_camera,
            prompts_px=prompts,
            ground_truth=gt,
            source=str(root),
        )
    except BadCapture as err:
        if err.path:
            raise
        raise BadCapture(str(err), path=depth_path) from err


# --------------------------------------------------------------------------------------------------
# Writing


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a capture is meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: Path, obj: Any) -> None:
    """Write JSON atomically (a reader never sees half a file)."""
    _atomic_write_bytes(Path(path), (json.dumps(obj, indent=1, allow_nan=False) + "\n").encode("utf-8"))


def _encode_png(img: NDArray[Any]) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise BadCapture("PNG encoding failed")
    return bytes(buf.tobytes())


def depth_to_png_counts(depth_m: NDArray[np.floating[Any]], depth_scale: float) -> NDArray[np.uint16]:
    """Quantise metres to 16-bit counts (``round(z * depth_scale)``); invalid and out-of-range -> 0."""
    z = np.asarray(depth_m, dtype=np.float64)
    counts = np.rint(np.where(np.isfinite(z), z, 0.0) * depth_scale)
    counts[(counts < 0) | (counts > 65535)] = 0
    return counts.astype(np.uint16)


def save_capture(
    capture: Capture,
    folder: str | os.PathLike[str],
    *,
    depth_format: Literal["png", "npy"] = "png",
    ground_truth: Sequence[GroundTruthSeam] | None = None,
) -> Path:
    """Write ``capture`` as a capture folder (created if needed) and return its path.

    Files are written atomically one by one; an existing folder's other files are left alone, but a
    stale depth file of the other format is removed so the folder stays unambiguous.
    """
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    _atomic_write_bytes(root / COLOR_FILE, _encode_png(np.ascontiguousarray(capture.color_rgb[:, :, ::-1])))
    if depth_format == "png":
        too_far = np.nanmax(capture.depth_m) * capture.depth_scale > 65535
        if too_far:
            raise BadCapture(
                f"depth up to {float(np.nanmax(capture.depth_m)):.3f} m does not fit 16 bits at "
                f"depth_scale={capture.depth_scale}; use a smaller depth_scale or depth_format='npy'"
            )
        _atomic_write_bytes(
            root / DEPTH_PNG_FILE, _encode_png(depth_to_png_counts(capture.depth_m, capture.depth_scale))
        )
        (root / DEPTH_NPY_FILE).unlink(missing_ok=True)
    else:
        import io

        buf = io.BytesIO()
        np.save(buf, np.where(np.isfinite(capture.depth_m), capture.depth_m, 0).astype(np.float32))
        _atomic_write_bytes(root / DEPTH_NPY_FILE, buf.getvalue())
        (root / DEPTH_PNG_FILE).unlink(missing_ok=True)
    write_json(root / CAMERA_FILE, capture.intrinsics.to_json(depth_scale=capture.depth_scale))
    if capture.X_base_tool is not None and capture.X_tool_camera is not None:
        write_json(
            root / POSE_FILE,
            {"X_base_tool": capture.X_base_tool.tolist(), "X_tool_camera": capture.X_tool_camera.tolist()},
        )
    if capture.prompts_px is not None:
        write_json(root / PROMPTS_FILE, {"points": np.asarray(capture.prompts_px).tolist()})
    gt = ground_truth if ground_truth is not None else capture.ground_truth
    if gt is not None:
        write_json(
            root / GROUND_TRUTH_FILE,
            {
                "frame": "camera",
                "seams": [
                    {"kind": s.kind, "points": s.points_camera.tolist(), **({"joint": s.joint} if s.joint else {})}
                    for s in gt
                ],
            },
        )
    return root


# --------------------------------------------------------------------------------------------------
# Unorganized point clouds (fine stage only)


@dataclass(frozen=True)
class PointCloud:
    """An unorganized cloud: (N, 3) float64 points in metres in ``frame``; optional (N, 3) colours in [0, 1]
    and (N, 3) unit normals as the file gave them (their sign says which side the sensor saw)."""

    points: FloatArray
    colors: FloatArray | None = None
    frame: str = "camera"
    source: str = ""
    normals: FloatArray | None = None

    def subset(self, keep: NDArray[np.bool_]) -> PointCloud:
        """This cloud with only the points ``keep`` marks (their colours and normals with them)."""
        return replace(self, points=self.points[keep], colors=None if self.colors is None else self.colors[keep],
                       normals=None if self.normals is None else self.normals[keep])  # fmt: skip


def read_point_cloud(path: str | os.PathLike[str]) -> PointCloud:
    """Read a .ply, .pcd (with or without colour) or .npy (N, 3) cloud; NaN points are dropped."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".ply", ".pcd", ".npy"):
        raise BadCapture(f"unsupported point cloud format {suffix!r}; use .ply, .pcd or .npy", path=p)
    if not p.is_file():
        raise BadCapture("point cloud file does not exist", path=p)
    colors: FloatArray | None = None
    normals: FloatArray | None = None
    if suffix == ".npy":
        try:
            pts = np.load(p, allow_pickle=False)
        except (ValueError, OSError, EOFError) as err:
            raise BadCapture(f"cannot read array: {err}", path=p) from err
        if pts.ndim != 2 or pts.shape[1] < 3:
            raise BadCapture(f"expected an (N, 3) array, got {pts.shape}", path=p)
        pts = np.asarray(pts[:, :3], dtype=np.float64)
    elif suffix in (".ply", ".pcd"):
        import open3d as o3d

        pcd = o3d.io.read_point_cloud(p, remove_nan_points=False, remove_infinite_points=False)
        pts = np.asarray(pcd.points, dtype=np.float64)
        if pts.size == 0:
            raise BadCapture("no points could be read (empty, corrupt, or a mesh without vertices)", path=p)
        if pcd.has_colors():
            colors = np.asarray(pcd.colors, dtype=np.float64)
        if pcd.has_normals():
            normals = np.asarray(pcd.normals, dtype=np.float64)
    else:
        raise BadCapture(f"unsupported point cloud format {suffix!r}; use .ply, .pcd or .npy", path=p)
    keep = np.all(np.isfinite(pts), axis=1)
    if not keep.any():
        raise BadCapture("every point is NaN or inf", path=p)
    pts = pts[keep]
    if colors is not None:
        colors = colors[keep]
        if not colors.any():
            colors = None  # all-black colour channels carry no information (common in LiDAR PCDs)
    if normals is not None:
        normals = normals[keep]
        length = np.linalg.norm(normals, axis=1)
        if not (np.all(np.isfinite(normals)) and np.all(np.abs(length - 1.0) < 0.01)):
            normals = None  # zero, unnormalised or NaN normals: ignore them rather than trust them
    return PointCloud(points=pts, colors=colors, frame="unknown", source=str(p), normals=normals)
