"""Value types passed between the fine-stage steps (camera frame, metres, radians)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
SurfaceKind = Literal["plane", "cylinder"]
Joint = Literal["fillet", "inside_corner", "lap", "v_groove", "butt"]


@dataclass(frozen=True)
class NoiseModel:
    """The capture's depth noise and sample spacing, measured from the capture itself.

    sigma(z) = max(sigma_1m_m * z^2, floor_m): one-sigma depth noise at range z (normal incidence);
    pixel_angle_rad: the angle between neighbouring rays at the work resolution (spacing = z * angle);
    structure_1m_m: the error at 1 m that planes a few times wider see and the noise model's do not
    (:func:`perception.fine.noise.structured_error`; 0 when not measured).
    """

    sigma_1m_m: float
    floor_m: float
    pixel_angle_rad: float
    structure_1m_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("sigma_1m_m", "floor_m", "pixel_angle_rad"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"NoiseModel.{name} must be a positive number, got {v}")
        if not (np.isfinite(self.structure_1m_m) and self.structure_1m_m >= 0):
            raise ValueError(f"NoiseModel.structure_1m_m must be a number >= 0, got {self.structure_1m_m}")

    def sigma_m(self, z: FloatArray | float) -> FloatArray:
        return np.maximum(self.sigma_1m_m * np.square(z), self.floor_m)

    def spacing_m(self, z: FloatArray | float) -> FloatArray:
        return np.asarray(z) * self.pixel_angle_rad


@dataclass(frozen=True)
class Surface:
    """A fitted surface patch.

    plane: ``normal . p + offset = 0``, normal towards the camera. cylinder: ``axis`` (unit), ``centre`` (a
    point on the axis), ``radius``; normal/offset unused (zeros). rms_m: fit residual; n_points: support
    at the work resolution; centroid: (3,) of the support; z_m: median range.
    """

    label: int
    kind: SurfaceKind
    normal: FloatArray
    offset: float
    rms_m: float
    n_points: int
    centroid: FloatArray
    z_m: float
    axis: FloatArray = field(default_factory=lambda: np.zeros(3))
    centre: FloatArray = field(default_factory=lambda: np.zeros(3))
    radius: float = 0.0

    def residual(self, p: FloatArray) -> FloatArray:
        """(N,) signed distance of (N, 3) points from the surface (plane: along the normal; cylinder:
        radial distance minus the radius)."""
        q = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        if self.kind == "plane":
            return np.asarray(q @ self.normal + self.offset)
        d = q - self.centre
        radial = d - np.outer(d @ self.axis, self.axis)
        return np.asarray(np.linalg.norm(radial, axis=1) - self.radius)


@dataclass(frozen=True)
class SurfaceSet:
    """The surfaces of one capture: (h, w) int32 labels at the work resolution (-1: none), the work
    resolution's subsampling factor, and the fitted surfaces indexed by label."""

    labels: NDArray[np.int32]
    factor: int
    surfaces: tuple[Surface, ...]


@dataclass(frozen=True)
class Pair:
    """Two surfaces that come within ``reach`` of each other; ``contact_px`` (K, 2) work-resolution pixel
    (row, col) where their neighbourhoods overlap."""

    a: int
    b: int
    contact_px: NDArray[np.int64]


@dataclass(frozen=True)
class SeamCurve:
    """A seam before path sampling: (N, 3) centre line, (N, 3) outward unit normals of its two surfaces,
    its kind and joint, the surfaces it was built from, and how well it is supported. ``from_boundary``: a lap
    or step whose edge face this shot does not see, placed by the upper plate's boundary (``surfaces`` is
    (lower, upper)): it is seen where both plates' tops are."""

    kind: Literal["linear", "curved"]
    joint: Joint
    points: FloatArray
    normals_a: FloatArray
    normals_b: FloatArray
    surfaces: tuple[int, int]
    support: int
    rms_m: float
    gap_m: float = 0.0
    from_boundary: bool = False
