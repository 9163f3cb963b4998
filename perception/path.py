"""Welding path: points sampled along a seam and a 6-DOF torch pose at each.

Torch frame: z along the torch, pointing from the torch into the joint (the bisector of the two
surfaces' outward normals, reversed); x along the travel direction; y = z x x. Work angle rotates the
torch about the travel axis away from the bisector; travel angle tilts it along the travel direction
(positive = push: the torch leans forward, pointing ahead of the arc).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from perception.evaluate import resample_polyline

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TorchParams:
    """How the path is sampled and the torch held: ``step_m`` (metres) at most between path points;
    ``work_angle_rad`` about the travel axis (torch x) and ``travel_angle_rad`` about the new torch y (positive =
    push), radians (``weldcell detect`` takes degrees and converts them)."""

    step_m: float = 0.005
    work_angle_rad: float = 0.0
    travel_angle_rad: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.step_m) and self.step_m > 0):
            raise ValueError(f"torch params: step_m must be finite and > 0, got {self.step_m}")
        for name in ("work_angle_rad", "travel_angle_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and abs(value) < math.pi / 2):
                raise ValueError(f"torch params: {name} must be within (-pi/2, pi/2), got {value}")


def sample_uniform(line: FloatArray, step_m: float) -> tuple[FloatArray, FloatArray]:
    """Points spaced at most ``step_m`` apart, evenly, ends included; and the arc length of each."""
    dense = resample_polyline(line, min(step_m, 0.001))
    seg = np.linalg.norm(np.diff(dense, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(2, int(np.ceil(s[-1] / step_m - 1e-9)) + 1)
    s_new = np.linspace(0.0, s[-1], n)
    pts = np.column_stack([np.interp(s_new, s, dense[:, k]) for k in range(3)])
    return pts, s_new


def interpolate_rows(s_src: FloatArray, rows: FloatArray, s_new: FloatArray, *, unit: bool) -> FloatArray:
    out = np.column_stack([np.interp(s_new, s_src, rows[:, k]) for k in range(rows.shape[1])])
    if unit:
        out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
    return out


def torch_poses(
    points: FloatArray, normals_a: FloatArray, normals_b: FloatArray, *, params: TorchParams | None = None
) -> FloatArray:
    """(N, 4, 4) torch poses at (N, 3) path points, given both surfaces' outward unit normals there."""
    p = params or TorchParams()
    n = len(points)
    tangent = np.gradient(points, axis=0) if n > 2 else np.tile(points[-1] - points[0], (n, 1))
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    bis = normals_a + normals_b
    bis /= np.maximum(np.linalg.norm(bis, axis=1, keepdims=True), 1e-12)
    z = -bis
    x = tangent - (tangent * z).sum(axis=1, keepdims=True) * z
    x /= np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=2)  # columns are the torch axes
    if p.work_angle_rad or p.travel_angle_rad:
        from scipy.spatial.transform import Rotation

        # intrinsic rotations: first about the travel axis x (work), then about the new y (travel)
        local = Rotation.from_euler("XY", [p.work_angle_rad, p.travel_angle_rad]).as_matrix()
        R = R @ local
    X = np.tile(np.eye(4), (n, 1, 1))
    X[:, :3, :3] = R
    X[:, :3, 3] = points
    return X
