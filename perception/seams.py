"""Detected seams: the value types and the seams.json format (spec: capture-format.md).

A torch pose ``X_frame_torch`` has its z axis along the torch pointing into the joint and its x axis
along the travel direction. In seams.json each pose is ``[x, y, z, qx, qy, qz, qw]`` (metres,
scalar-last); two extra keys per seam give the same poses as FANUC XYZWPR (mm, deg) and UR pose vectors
(m, rotation vector), as the robots take them.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from perception.capture import write_json
from perception.errors import BadCapture
from perception.seams_schema import FORMAT_VERSION, UNITS
from perception.transforms import (
    X_from_xyzquat,
    invert_X,
    transform_points,
    ur_pose_from_X,
    xyzquat_from_X,
    xyzwpr_mm_deg_from_X,
)

FloatArray = NDArray[np.float64]
Frame = Literal["camera", "base"]


def check_seam_path(
    points: ArrayLike,
    poses: ArrayLike,
    *,
    what: str,
    points_name: str = "points",
    poses_name: str = "poses",
) -> tuple[FloatArray, FloatArray]:
    """A seam's path as float64 arrays after checking it: ``points`` (N >= 2, 3) metres and ``poses`` (N, 4, 4)
    torch poses, all finite. The one home of this rule for every seam type (:class:`Seam` here, the planner's
    world-frame seams); ValueError naming ``what`` and the field otherwise."""
    pts = np.asarray(points, dtype=np.float64)
    X = np.asarray(poses, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
        raise ValueError(f"{what} {points_name} must be (N>=2, 3), got {pts.shape}")
    if X.shape != (len(pts), 4, 4):
        raise ValueError(f"{what} {poses_name} must be ({len(pts)}, 4, 4), got {X.shape}")
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(X))):
        raise ValueError(f"{what} {points_name} or {poses_name} contain NaN or inf")
    return pts, X


@dataclass(frozen=True)
class Seam:
    """One detected seam in ``frame``.

    points: (N, 3) welding path in metres, ordered along the seam.
    poses: (N, 4, 4) torch poses ``X_frame_torch`` at the path points.
    surfaces: the two surface labels (prompt indices) that meet here.
    """

    id: int
    kind: Literal["linear", "curved"]
    points: FloatArray
    poses: FloatArray
    length_m: float
    confidence: float
    surfaces: tuple[int, int] = (-1, -1)
    frame: Frame = "camera"
    joint: str = "fillet"  # fillet, inside_corner, lap, v_groove, butt

    def __post_init__(self) -> None:
        pts, poses = check_seam_path(self.points, self.poses, what="seam")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "poses", poses)

    def transformed(self, X_new_old: FloatArray, frame: Frame) -> Seam:
        """The same seam expressed in another frame (``X_new_old`` maps this seam's frame to ``frame``)."""
        return Seam(
            id=self.id,
            kind=self.kind,
            points=transform_points(X_new_old, self.points),
            poses=np.einsum("ij,njk->nik", X_new_old, self.poses),
            length_m=self.length_m,
            confidence=self.confidence,
            surfaces=self.surfaces,
            frame=frame,
            joint=self.joint,
        )


@dataclass(frozen=True)
class DetectionResult:
    """Everything ``detect`` returns: seams, point counts per stage and timings per stage (seconds)."""

    frame: Frame
    seams: tuple[Seam, ...]
    point_counts: dict[str, int] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    artifacts: dict[str, Any] = field(default_factory=dict, repr=False)  # masks, ROI: for overlays, not JSON


def seams_to_json(result: DetectionResult) -> dict[str, Any]:
    """The seams.json document of ``result`` (schema: ``weldcell schema seams``, :mod:`perception.seams_schema`)."""
    seams = []
    for s in result.seams:
        seams.append(
            {
                "id": s.id,
                "kind": s.kind,
                "joint": s.joint,
                "points": np.round(s.points, 7).tolist(),
                "poses": [np.round(xyzquat_from_X(X), 7).tolist() for X in s.poses],
                "length_m": round(float(s.length_m), 6),
                "confidence": round(float(s.confidence), 4),
                "surfaces": list(s.surfaces),
                "fanuc_xyzwpr_mm_deg": [np.round(xyzwpr_mm_deg_from_X(X), 4).tolist() for X in s.poses],
                "ur_pose": [np.round(ur_pose_from_X(X), 7).tolist() for X in s.poses],
            }
        )
    return {
        "format_version": FORMAT_VERSION,
        "units": UNITS,
        "frame": result.frame,
        "seams": seams,
        "points": dict(result.point_counts),
        "timing_s": {k: round(float(v), 5) for k, v in result.timing_s.items()},
        **({"info": result.info} if result.info else {}),
    }


def write_seams_json(result: DetectionResult, path: str | os.PathLike[str]) -> Path:
    out = Path(path)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    write_json(out, seams_to_json(result))
    return out


@dataclass(frozen=True)
class SeamsFile:
    """What a reader of seams.json needs: the frame and each seam's kind, path points and poses."""

    frame: Frame
    kinds: tuple[str, ...]
    points: tuple[FloatArray, ...]
    poses: tuple[FloatArray, ...]
    raw: dict[str, Any]

    def points_in_camera(self, X_base_camera: FloatArray | None) -> list[FloatArray]:
        if self.frame == "camera":
            return list(self.points)
        if X_base_camera is None:
            raise BadCapture("seams.json is in the base frame but the capture has no pose.json to relate them")
        X_camera_base = invert_X(X_base_camera)
        return [transform_points(X_camera_base, p) for p in self.points]


def read_seams_json(path: str | os.PathLike[str]) -> SeamsFile:
    p = Path(path)
    try:
        obj = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise BadCapture("seams file does not exist", path=p) from err
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise BadCapture(f"cannot read seams JSON: {err}", path=p) from err
    if not isinstance(obj, dict) or not isinstance(obj.get("seams"), list):
        raise BadCapture("expected an object with a 'seams' list", path=p)
    version = str(obj.get("format_version", "1.0"))  # files from before the field are 1.0, the same layout
    if version.split(".")[0] != FORMAT_VERSION.split(".")[0]:
        raise BadCapture(f"format_version {version!r} is not 1.x; this weldcell reads seams.json 1.x", path=p)
    if obj.get("units", UNITS) != UNITS:
        raise BadCapture(f"units {obj.get('units')!r}: seams.json lengths are in metres ('m')", path=p)
    frame = obj.get("frame", "camera")
    if frame not in ("camera", "base"):
        raise BadCapture(f"'frame' must be 'camera' or 'base', got {frame!r}", path=p)
    kinds, pts, poses = [], [], []
    for i, s in enumerate(obj["seams"]):
        try:
            arr = np.asarray(s["points"], dtype=np.float64).reshape(-1, 3)
            pose_rows = np.asarray(s.get("poses", []), dtype=np.float64).reshape(-1, 7)
        except (KeyError, TypeError, ValueError) as err:
            raise BadCapture(f"seam {i}: malformed points or poses ({err})", path=p) from err
        if not np.all(np.isfinite(arr)):
            raise BadCapture(f"seam {i}: points contain NaN or inf", path=p)
        kinds.append(str(s.get("kind", "linear")))
        pts.append(arr)
        poses.append(np.array([X_from_xyzquat(r) for r in pose_rows]).reshape(-1, 4, 4))
    return SeamsFile(frame, tuple(kinds), tuple(pts), tuple(poses), obj)
