"""Parametric synthetic weldments: parts made of boxes and cylinders on a table, with exact seams.

World frame: the table top is the plane z = 0, z up, metres. Each part is a box or a (capped)
cylinder placed by ``X_world_part``. Each face of a part has an id (boxes: 0..5 = -x, +x, -y, +y, -z, +z
in the part frame; cylinders: 0 = side, 1 = bottom cap, 2 = top cap), so a pixel's ray hit names its
surface as (part, face).

A seam is where two faces of two different parts meet. It is given exactly, by construction: the
centre line points (world frame) and, per point, the unit directions pointing *into* each of the two
faces away from the seam; those directions make the visibility test and the torch bisector exact.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from perception.transforms import look_at_X, make_X
from sim_fakes.hull import Hull, convex_hull

FloatArray = NDArray[np.float64]

BOX_FACES = ("-x", "+x", "-y", "+y", "-z", "+z")
CYL_SIDE, CYL_BOTTOM, CYL_TOP = 0, 1, 2
CYLINDER_SEGMENTS = 1024  # polygon error r(1 - cos(pi/n)) < 0.2 um for r = 40 mm


@dataclass(frozen=True)
class Part:
    """A rigid solid. ``size`` is (sx, sy, sz) for a box centred on its frame origin, or
    (radius, radius, height) for a cylinder whose axis is the part z axis from z=0 to z=height.
    A ``hull`` is the convex hull of ``corners_part`` ((V, 3), part frame); its face ids index
    :attr:`hull_world`'s faces, and ``size`` is unused."""

    name: str
    shape: Literal["box", "cylinder", "hull"]
    size: tuple[float, float, float]
    X_world_part: FloatArray
    albedo_rgb: tuple[float, float, float]
    workpiece: bool = True
    corners_part: FloatArray | None = None
    hull_world: Hull | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.shape == "hull":
            if self.corners_part is None:
                raise ValueError(f"part {self.name!r}: a hull needs corners_part")
            c = np.asarray(self.corners_part, dtype=np.float64).reshape(-1, 3)
            c_world = c @ self.X_world_part[:3, :3].T + self.X_world_part[:3, 3]
            object.__setattr__(self, "hull_world", convex_hull(c_world))

    def face_normal_world(self, face: int) -> FloatArray:
        """Outward unit normal of a planar face in the world frame."""
        R = self.X_world_part[:3, :3]
        if self.hull_world is not None:
            return np.asarray(self.hull_world.faces[face].normal)
        if self.shape == "box":
            axis, sign = divmod(face, 2)
            n = np.zeros(3)
            n[axis] = 1.0 if sign else -1.0
            return R @ n
        if face == CYL_SIDE:
            raise ValueError("the cylinder side has no single normal")
        return R @ np.array([0.0, 0.0, -1.0 if face == CYL_BOTTOM else 1.0])


@dataclass(frozen=True)
class SeamDef:
    """One seam of a scene (world frame, metres).

    points: (N, 3) centre line ordered along the seam (2 points for a linear seam).
    faces: ((part_index, face_id), (part_index, face_id)) of the two surfaces that meet.
    into_a, into_b: (N, 3) unit directions lying in face a / face b, pointing away from the seam.
    gap_m: width of the gap for butt joints (0 for fillets).
    joint: fillet, inside_corner, lap, v_groove or butt (the capture format's names).
    reach_a_m, reach_b_m: how far face a / face b extend from the seam along ``into_a`` / ``into_b``
        (a 3 mm lap edge face reaches 3 mm); the visibility probe stays within half of it.
    across_a, across_b: (3,) unit directions from the seam's centre line to face a's / face b's edge across
        the gap (default: ``into_a`` / ``into_b``; a V-groove's bevels rise at an angle to the gap).
    """

    name: str
    kind: Literal["linear", "curved"]
    points: FloatArray
    faces: tuple[tuple[int, int], tuple[int, int]]
    into_a: FloatArray
    into_b: FloatArray
    gap_m: float = 0.0
    joint: str = "fillet"
    reach_a_m: float = float("inf")
    reach_b_m: float = float("inf")
    across_a: FloatArray | None = None
    across_b: FloatArray | None = None

    def edge_offsets(self, into_a: FloatArray, into_b: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(N, 3) offsets from seam points to the edges of face a and face b (zero without a gap)."""
        da = into_a if self.across_a is None else np.broadcast_to(self.across_a, into_a.shape)
        db = into_b if self.across_b is None else np.broadcast_to(self.across_b, into_b.shape)
        return da * (self.gap_m / 2), db * (self.gap_m / 2)

    def sample(self, step_m: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Resample points and in-face directions every ``step_m`` along the seam."""
        pts = self.points
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        n = max(2, int(np.ceil(s[-1] / step_m)) + 1)
        s_new = np.linspace(0.0, s[-1], n)
        out = []
        for arr in (pts, self.into_a, self.into_b):
            out.append(np.column_stack([np.interp(s_new, s, arr[:, k]) for k in range(3)]))
        for k in (1, 2):
            out[k] /= np.linalg.norm(out[k], axis=1, keepdims=True)
        return out[0], out[1], out[2]


@dataclass(frozen=True)
class CameraSetup:
    """Pinhole camera placed by look-at (world frame)."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    width: int = 1280
    height: int = 720
    fx: float = 920.0
    fy: float = 920.0
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    @property
    def X_world_camera(self) -> FloatArray:
        return look_at_X(self.eye, self.target, self.up)


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    parts: tuple[Part, ...]
    seams: tuple[SeamDef, ...]
    camera: CameraSetup
    prompt_faces: tuple[tuple[int, int], ...] = field(default=())

    def surfaces(self) -> tuple[tuple[int, int], ...]:
        """Workpiece surfaces to prompt: the faces named by seams (in first-seen order) unless given."""
        if self.prompt_faces:
            return self.prompt_faces
        seen: list[tuple[int, int]] = []
        for s in self.seams:
            for f in s.faces:
                if f not in seen:
                    seen.append(f)
        return tuple(seen)


# --------------------------------------------------------------------------------------------------
# Building blocks

STEEL = (0.55, 0.56, 0.58)
STEEL_DARK = (0.42, 0.43, 0.46)
STEEL_WARM = (0.60, 0.55, 0.50)
TABLE = (0.22, 0.24, 0.20)


def _table() -> Part:
    return Part("table", "box", (1.6, 1.2, 0.04), make_X(np.eye(3), [0.0, 0.0, -0.02]), TABLE, workpiece=False)


def _plate(name: str, sx: float, sy: float, sz: float, x: float, y: float, z0: float, albedo=STEEL) -> Part:
    """An axis-aligned box whose bottom is at z0."""
    return Part(name, "box", (sx, sy, sz), make_X(np.eye(3), [x, y, z0 + sz / 2]), albedo)


def _top(p: Part) -> float:
    return float(p.X_world_part[2, 3] + p.size[2] / 2)


def _linear(name: str, a: FloatArray, b: FloatArray, faces, into_a, into_b, gap_m: float = 0.0) -> SeamDef:
    pts = np.array([a, b], dtype=float)
    da = np.tile(np.asarray(into_a, float), (2, 1))
    db = np.tile(np.asarray(into_b, float), (2, 1))
    return SeamDef(name, "linear", pts, faces, da, db, gap_m)


def _fillet_x_face(base_i: int, base: Part, rib_i: int, rib: Part, side: int) -> SeamDef:
    """Fillet between the base plate's top and a rib face normal to x (side -1: the -x face)."""
    cx, cy = rib.X_world_part[0, 3], rib.X_world_part[1, 3]
    sx, sy = rib.size[0], rib.size[1]
    x = cx + side * sx / 2
    z = _top(base)
    face = 0 if side < 0 else 1
    return _linear(
        f"{rib.name}{'-x' if side < 0 else '+x'}",
        np.array([x, cy - sy / 2, z]),
        np.array([x, cy + sy / 2, z]),
        ((base_i, 5), (rib_i, face)),
        [side, 0.0, 0.0],
        [0.0, 0.0, 1.0],
    )


def _fillet_y_face(base_i: int, base: Part, rib_i: int, rib: Part, side: int) -> SeamDef:
    """Fillet between the base plate's top and a rib face normal to y (side -1: the -y face)."""
    cx, cy = rib.X_world_part[0, 3], rib.X_world_part[1, 3]
    sx, sy = rib.size[0], rib.size[1]
    y = cy + side * sy / 2
    z = _top(base)
    face = 2 if side < 0 else 3
    return _linear(
        f"{rib.name}{'-y' if side < 0 else '+y'}",
        np.array([cx - sx / 2, y, z]),
        np.array([cx + sx / 2, y, z]),
        ((base_i, 5), (rib_i, face)),
        [0.0, side, 0.0],
        [0.0, 0.0, 1.0],
    )


# --------------------------------------------------------------------------------------------------
# Scenes


def t_joint() -> Scene:
    base = _plate("base", 0.30, 0.22, 0.010, 0.0, 0.0, 0.0)
    web = _plate("web", 0.010, 0.20, 0.10, 0.0, 0.0, _top(base), STEEL_WARM)
    parts = (_table(), base, web)
    seams = (_fillet_x_face(1, base, 2, web, -1), _fillet_x_face(1, base, 2, web, +1))
    cam = CameraSetup(eye=(-0.36, -0.12, 0.36), target=(0.0, 0.0, 0.02))
    return Scene(
        "t_joint", "T-joint: a web plate standing on a base plate (the far fillet is hidden)", parts, seams, cam
    )


def ribs() -> Scene:
    """A base plate with five stiffener bars; from the diagonal view each shows two fillets: 10 seams."""
    base = _plate("base", 0.46, 0.34, 0.012, 0.0, 0.0, 0.0)
    parts: list[Part] = [_table(), base]
    seams: list[SeamDef] = []
    # (x, y, length along y, width along x); staggered so that no bar hides another's near fillets
    bars = [
        (-0.15, 0.07, 0.12, 0.04),
        (-0.05, -0.07, 0.12, 0.04),
        (0.05, 0.07, 0.12, 0.04),
        (0.15, -0.07, 0.12, 0.04),
        (-0.15, -0.10, 0.07, 0.04),
    ]
    for k, (x, y, ly, wx) in enumerate(bars):
        bar = _plate(f"bar{k}", wx, ly, 0.03, x, y, _top(base), STEEL_WARM if k % 2 else STEEL_DARK)
        parts.append(bar)
        i = len(parts) - 1
        seams.append(_fillet_x_face(1, base, i, bar, -1))
        seams.append(_fillet_y_face(1, base, i, bar, -1))
    cam = CameraSetup(eye=(-0.30, -0.28, 0.36), target=(0.0, 0.0, 0.0))
    return Scene(
        "ribs", "plate with five stiffener bars: 10 linear fillet seams in one shot", tuple(parts), tuple(seams), cam
    )


def lap_joint() -> Scene:
    lower = _plate("lower", 0.26, 0.18, 0.008, 0.0, -0.03, 0.0)
    upper = _plate("upper", 0.26, 0.14, 0.008, 0.0, 0.06, _top(lower), STEEL_WARM)
    parts = (_table(), lower, upper)
    seam = replace(_fillet_y_face(1, lower, 2, upper, -1), joint="lap")
    cam = CameraSetup(eye=(0.05, -0.40, 0.34), target=(0.0, 0.0, 0.0))
    return Scene("lap_joint", "lap joint: an upper plate overlapping a lower one", parts, (seam,), cam)


def inside_corner() -> Scene:
    floor = _plate("floor", 0.24, 0.24, 0.010, 0.0, 0.0, 0.0)
    t = 0.010
    wall_x = _plate("wall_x", t, 0.24, 0.16, 0.12 - t / 2, 0.0, _top(floor), STEEL_WARM)
    wall_y = _plate("wall_y", 0.24 - t, t, 0.16, -t / 2, 0.12 - t / 2, _top(floor), STEEL_DARK)
    parts = (_table(), floor, wall_x, wall_y)
    z = _top(floor)
    xw = 0.12 - t  # inner face of wall_x
    yw = 0.12 - t  # inner face of wall_y
    s1 = _linear(
        "floor-wall_x", np.array([xw, -0.12, z]), np.array([xw, yw, z]), ((1, 5), (2, 0)), [-1, 0, 0], [0, 0, 1]
    )
    s2 = _linear(
        "floor-wall_y", np.array([-0.12, yw, z]), np.array([xw, yw, z]), ((1, 5), (3, 2)), [0, -1, 0], [0, 0, 1]
    )
    s3 = _linear(
        "wall_x-wall_y", np.array([xw, yw, z]), np.array([xw, yw, z + 0.16]), ((2, 0), (3, 2)), [0, -1, 0], [-1, 0, 0]
    )
    s3 = replace(s3, joint="inside_corner")
    cam = CameraSetup(eye=(-0.30, -0.30, 0.40), target=(0.02, 0.02, 0.04))
    return Scene(
        "inside_corner",
        "inside corner of three plates: two fillets and a vertical corner seam",
        parts,
        (s1, s2, s3),
        cam,
    )


def open_box() -> Scene:
    t = 0.008
    L, W, H = 0.24, 0.20, 0.08
    floor = _plate("floor", L, W, t, 0.0, 0.0, 0.0)
    z = _top(floor)
    back = _plate("back", L, t, H, 0.0, W / 2 - t / 2, z, STEEL_WARM)
    front = _plate("front", L, t, H, 0.0, -W / 2 + t / 2, z, STEEL_WARM)
    left = _plate("left", t, W - 2 * t, H, -L / 2 + t / 2, 0.0, z, STEEL_DARK)
    right = _plate("right", t, W - 2 * t, H, L / 2 - t / 2, 0.0, z, STEEL_DARK)
    parts = (_table(), floor, back, front, left, right)
    yb, yf = W / 2 - t, -W / 2 + t
    xl, xr = -L / 2 + t, L / 2 - t
    seams = (
        _linear("floor-back", np.array([xl, yb, z]), np.array([xr, yb, z]), ((1, 5), (2, 2)), [0, -1, 0], [0, 0, 1]),
        _linear("floor-front", np.array([xl, yf, z]), np.array([xr, yf, z]), ((1, 5), (3, 3)), [0, 1, 0], [0, 0, 1]),
        _linear("floor-left", np.array([xl, yf, z]), np.array([xl, yb, z]), ((1, 5), (4, 1)), [1, 0, 0], [0, 0, 1]),
        _linear("floor-right", np.array([xr, yf, z]), np.array([xr, yb, z]), ((1, 5), (5, 0)), [-1, 0, 0], [0, 0, 1]),
        _linear("back-left", np.array([xl, yb, z]), np.array([xl, yb, z + H]), ((2, 2), (4, 1)), [1, 0, 0], [0, -1, 0]),
        _linear(
            "back-right", np.array([xr, yb, z]), np.array([xr, yb, z + H]), ((2, 2), (5, 0)), [-1, 0, 0], [0, -1, 0]
        ),
        _linear("front-left", np.array([xl, yf, z]), np.array([xl, yf, z + H]), ((3, 3), (4, 1)), [1, 0, 0], [0, 1, 0]),
        _linear(
            "front-right", np.array([xr, yf, z]), np.array([xr, yf, z + H]), ((3, 3), (5, 0)), [-1, 0, 0], [0, 1, 0]
        ),
    )
    tagged = tuple(replace(s, joint="inside_corner") if not s.name.startswith("floor") else s for s in seams)
    cam = CameraSetup(eye=(-0.20, -0.30, 0.40), target=(0.02, 0.03, 0.02))
    return Scene("open_box", "open box: floor and four walls, inside fillets and corners", parts, tagged, cam)


def pipe_on_plate() -> Scene:
    base = _plate("base", 0.26, 0.26, 0.010, 0.0, 0.0, 0.0)
    r, h = 0.04, 0.12
    z = _top(base)
    pipe = Part("pipe", "cylinder", (r, r, h), make_X(np.eye(3), [0.0, 0.0, z]), STEEL_WARM)
    parts = (_table(), base, pipe)
    n = 8001  # chord sag r(1 - cos(pi/8000)) = 3e-9 m
    ang = np.linspace(0.0, 2 * np.pi, n)
    ring = np.column_stack([r * np.cos(ang), r * np.sin(ang), np.full(n, z)])
    radial = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n)])
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    seam = SeamDef("pipe-base", "curved", ring, ((1, 5), (2, CYL_SIDE)), radial, up)
    cam = CameraSetup(eye=(-0.05, -0.36, 0.38), target=(0.0, 0.0, 0.02))
    return Scene("pipe_on_plate", "a pipe standing on a plate: one curved fillet seam", parts, (seam,), cam)


def butt_joint() -> Scene:
    gap = 0.0015
    t = 0.008
    left = _plate("left", 0.14, 0.22, t, -0.07 - gap / 2, 0.0, 0.0)
    right = _plate("right", 0.14, 0.22, t, 0.07 + gap / 2, 0.0, 0.0, STEEL_DARK)
    parts = (_table(), left, right)
    seam = _linear(
        "butt", np.array([0.0, -0.11, t]), np.array([0.0, 0.11, t]), ((1, 5), (2, 5)), [-1, 0, 0], [1, 0, 0], gap_m=gap
    )
    seam = replace(seam, joint="butt")
    cam = CameraSetup(eye=(-0.20, -0.30, 0.40), target=(0.0, 0.0, 0.0))
    return Scene("butt_joint", "butt joint: two plates side by side with a 1.5 mm gap", parts, (seam,), cam)


def with_resolution(scene: Scene, width: int, height: int) -> Scene:
    """The same view at another image size: focal lengths scale with the width."""
    cam = scene.camera
    k = width / cam.width
    return replace(scene, camera=replace(cam, width=width, height=height, fx=cam.fx * k, fy=cam.fy * k))


SCENES: dict[str, Callable[[], Scene]] = {
    "t_joint": t_joint,
    "ribs": ribs,
    "lap_joint": lap_joint,
    "inside_corner": inside_corner,
    "open_box": open_box,
    "pipe_on_plate": pipe_on_plate,
    "butt_joint": butt_joint,
}


def get_scene(name: str) -> Scene:
    try:
        return SCENES[name]()
    except KeyError:
        raise KeyError(f"unknown scene {name!r}; choose one of: {', '.join(SCENES)}") from None
