"""A randomized zoo of weldments: procedural families, random views and sensors, exact ground truth.

Each capture is drawn from a family (T-joint, ribs, bars, inside corner, open box, pipe, two pipes, lap,
step, V-groove, butt, gusset) with random dimensions, turned to a random yaw on the table, seen by a camera
at a random azimuth, 35 to 80 degrees elevation and 0.3 to 0.9 m, through one of three sensors (OAK-D-like
stereo, the same at high noise, structured light). Some captures carry clutter (boxes on the table that are
not part of the workpiece), and some carry no prompts. Seams come from the solids themselves
(:mod:`sim_fakes.contacts`) or, for butt gaps and groove roots, from the family; the renderer clips them to
what the camera sees (:data:`ZOO_RULES`).

Splits: the ``dev`` split is seeds 0 to 999,999 (tune on it), the ``test`` split seeds 1,000,000 and up (only
ever measured). Capture ``k`` of a split of families ``F`` is family ``F[k % len(F)]`` with seed
``base + k // len(F)``; a capture's random stream is seeded by (family code, seed), so it does not depend on
which other families are drawn.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from perception.transforms import look_at_X, make_X
from sim_fakes.contacts import dedupe_seams, fold_seams
from sim_fakes.hull import box_corners, prism
from sim_fakes.render import GroundTruthRules, RenderResult, StereoSensor, render, visible_ground_truth
from sim_fakes.scenes import CameraSetup, Part, Scene, SeamDef

FloatArray = NDArray[np.float64]
Split = Literal["dev", "test"]

SPLIT_BASE: dict[str, int] = {"dev": 0, "test": 1_000_000}
ZOO_RULES = GroundTruthRules(max_incidence_deg=75.0, min_run_m=0.020, face_offset_m=0.003)
SENSORS: dict[str, StereoSensor | None] = {
    "oakd": StereoSensor(),
    "oakd_high": StereoSensor(sigma_px=0.16, sigma_corr_px=0.08),
    "structured": None,  # the renderer's structured-light model
    # not drawn (SENSOR_SHARE): the OAK-D with its 5x5 median post-filter, for `weldcell bench zoo --sensor`
    "oakd_median": StereoSensor(median_px=5),
}
SENSOR_SHARE = {"oakd": 0.60, "structured": 0.25, "oakd_high": 0.15}
NO_PROMPT_SHARE = 0.15
CLUTTER_SHARE = 0.30
SMALL_SURFACE_PX = 3000
SMALL_SURFACE_SKIP = 0.3
MAX_VIEW_TRIES = 30

STEEL = ((0.55, 0.56, 0.58), (0.42, 0.43, 0.46), (0.60, 0.55, 0.50), (0.50, 0.52, 0.55))
TABLE_RGB = (0.22, 0.24, 0.20)


@dataclass(frozen=True)
class Weldment:
    """Parts (world frame, after the yaw on the table) and the seams the family states itself."""

    parts: tuple[Part, ...]
    extra_seams: tuple[SeamDef, ...] = ()
    joint_of: Callable[[int, int, FloatArray, FloatArray], str] | None = None


@dataclass(frozen=True)
class ZooCapture:
    """One drawn capture: the render with its truth, and how it was drawn."""

    family: str
    split: str
    seed: int
    sensor: str
    prompted: bool
    clutter: int
    camera_distance_m: float
    elevation_rad: float
    result: RenderResult

    @property
    def name(self) -> str:
        return f"{self.family}-{self.seed}"


# --------------------------------------------------------------------------------------------------
# Building blocks (weldment frame: the part's own, z up, bottom on z = 0; placed by X_world_weldment)


class _Builder:
    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        yaw = rng.uniform(0.0, 2 * np.pi)
        self.X_world_weldment = make_X(_rz(yaw), [rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), 0.0])
        self.parts: list[Part] = []

    def steel(self) -> tuple[float, float, float]:
        return STEEL[int(self.rng.integers(len(STEEL)))]

    def add(self, name: str, corners: FloatArray, *, x: float = 0.0, y: float = 0.0, z: float = 0.0,
            yaw: float = 0.0) -> int:  # fmt: skip
        X = self.X_world_weldment @ make_X(_rz(yaw), [x, y, z])
        self.parts.append(Part(name, "hull", (0.0, 0.0, 0.0), X, self.steel(), corners_part=corners))
        return len(self.parts) - 1

    def add_cylinder(self, name: str, r: float, h: float, *, x: float, y: float, z: float) -> int:
        X = self.X_world_weldment @ make_X(np.eye(3), [x, y, z])
        self.parts.append(Part(name, "cylinder", (r, r, h), X, self.steel()))
        return len(self.parts) - 1

    def local_to_world(self, p: ArrayLike) -> FloatArray:
        q = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        return np.asarray(q @ self.X_world_weldment[:3, :3].T + self.X_world_weldment[:3, 3])

    def dir_to_world(self, v: ArrayLike) -> FloatArray:
        return np.asarray(np.asarray(v, dtype=np.float64).reshape(-1, 3) @ self.X_world_weldment[:3, :3].T)


def _rz(yaw: float) -> FloatArray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _footprint(sx: float, sy: float, x: float, y: float, yaw: float, *, step: float = 0.002) -> FloatArray:
    """(N, 2) points along the boundary of a rotated rectangle (weldment frame)."""
    t = np.arange(0.0, 1.0, step / max(sx, sy, step))
    edges = [np.column_stack([-sx / 2 + sx * t, np.full_like(t, -sy / 2)]),
             np.column_stack([-sx / 2 + sx * t, np.full_like(t, sy / 2)]),
             np.column_stack([np.full_like(t, -sx / 2), -sy / 2 + sy * t]),
             np.column_stack([np.full_like(t, sx / 2), -sy / 2 + sy * t])]  # fmt: skip
    p = np.vstack(edges)
    return np.asarray(p @ _rz(yaw)[:2, :2].T + [x, y])


def _inside_rect(p: FloatArray, sx: float, sy: float, margin: float) -> bool:
    return bool(np.all(np.abs(p[:, 0]) <= sx / 2 - margin) and np.all(np.abs(p[:, 1]) <= sy / 2 - margin))


def _min_dist(a: FloatArray, b: FloatArray) -> float:
    from scipy.spatial import cKDTree

    return float(cKDTree(b).query(a)[0].min())


# --------------------------------------------------------------------------------------------------
# Families


def _tee(b: _Builder) -> Weldment:
    r = b.rng
    sx, sy, t = r.uniform(0.16, 0.34), r.uniform(0.12, 0.28), r.uniform(0.006, 0.015)
    b.add("base", box_corners(sx, sy, t))
    tw, h = r.uniform(0.003, 0.015), r.uniform(0.04, 0.12)
    yaw = r.uniform(0.0, np.pi)
    x, y = r.uniform(-0.2, 0.2) * sx, r.uniform(-0.2, 0.2) * sy
    length = r.uniform(0.6, 1.0) * max(sx, sy)
    while not _inside_rect(_footprint(length, tw, x, y, yaw), sx, sy, 0.005):
        length *= 0.92
    b.add("web", box_corners(length, tw, h), x=x, y=y, z=t, yaw=yaw)
    return Weldment(tuple(b.parts))


def _plates_on_base(b: _Builder, n: int, thick: tuple[float, float], tall: tuple[float, float],
                    long: tuple[float, float], gap_m: float) -> None:  # fmt: skip
    r = b.rng
    sx, sy, t = r.uniform(0.25, 0.45), r.uniform(0.20, 0.35), r.uniform(0.008, 0.020)
    b.add("base", box_corners(sx, sy, t))
    placed: list[FloatArray] = []
    for k in range(n):
        for _ in range(60):
            w, h, L = r.uniform(*thick), r.uniform(*tall), r.uniform(*long)
            yaw = r.uniform(0.0, np.pi)
            x, y = r.uniform(-0.5, 0.5) * sx, r.uniform(-0.5, 0.5) * sy
            fp = _footprint(L, w, x, y, yaw)
            if not _inside_rect(fp, sx, sy, 0.010):
                continue
            if any(_min_dist(fp, q) < gap_m for q in placed):
                continue
            placed.append(fp)
            b.add(f"rib{k}", box_corners(L, w, h), x=x, y=y, z=t, yaw=yaw)
            break


def _ribs(b: _Builder) -> Weldment:
    _plates_on_base(b, int(b.rng.integers(3, 11)), (0.004, 0.010), (0.03, 0.08), (0.06, 0.20), 0.030)
    return Weldment(tuple(b.parts))


def _bars(b: _Builder) -> Weldment:
    _plates_on_base(b, int(b.rng.integers(2, 6)), (0.020, 0.050), (0.020, 0.060), (0.05, 0.15), 0.050)
    return Weldment(tuple(b.parts))


def _inside_corner(b: _Builder) -> Weldment:
    r = b.rng
    sx, sy, t = r.uniform(0.18, 0.32), r.uniform(0.18, 0.32), r.uniform(0.006, 0.015)
    tw = r.uniform(0.006, 0.015)
    hx, hy = r.uniform(0.08, 0.20), r.uniform(0.08, 0.20)
    b.add("floor", box_corners(sx, sy, t))
    b.add("wall_x", box_corners(tw, sy, hx), x=sx / 2 - tw / 2, z=t)
    b.add("wall_y", box_corners(sx - tw, tw, hy), x=-tw / 2, y=sy / 2 - tw / 2, z=t)
    return Weldment(tuple(b.parts), joint_of=_corner_joint)


def _corner_joint(_ia: int, _ib: int, into_a: FloatArray, into_b: FloatArray) -> str:
    """A fold between two walls (neither face horizontal) is an inside corner; one with a floor a fillet."""
    vertical = abs(float(into_a[2])) < 0.5 and abs(float(into_b[2])) < 0.5
    return "inside_corner" if vertical else "fillet"


def _open_box(b: _Builder) -> Weldment:
    r = b.rng
    L, W, H = r.uniform(0.15, 0.30), r.uniform(0.12, 0.25), r.uniform(0.04, 0.12)
    tw, tf = r.uniform(0.004, 0.012), r.uniform(0.006, 0.015)
    mx0, mx1, my0, my1 = (r.uniform(0.015, 0.05) for _ in range(4))
    fx, fy = L + mx0 + mx1, W + my0 + my1
    b.add("floor", box_corners(fx, fy, tf), x=(mx1 - mx0) / 2, y=(my1 - my0) / 2)
    b.add("back", box_corners(L, tw, H), y=W / 2 - tw / 2, z=tf)
    b.add("front", box_corners(L, tw, H), y=-W / 2 + tw / 2, z=tf)
    b.add("left", box_corners(tw, W - 2 * tw, H), x=-L / 2 + tw / 2, z=tf)
    b.add("right", box_corners(tw, W - 2 * tw, H), x=L / 2 - tw / 2, z=tf)
    return Weldment(tuple(b.parts), joint_of=_corner_joint)


def _pipe(b: _Builder) -> Weldment:
    r = b.rng
    rad, h = r.uniform(0.015, 0.080), r.uniform(0.04, 0.15)
    sx, sy, t = 2 * rad + r.uniform(0.04, 0.16), 2 * rad + r.uniform(0.04, 0.16), r.uniform(0.006, 0.015)
    b.add("base", box_corners(sx, sy, t))
    x = r.uniform(-1, 1) * (sx / 2 - rad - 0.012)
    y = r.uniform(-1, 1) * (sy / 2 - rad - 0.012)
    b.add_cylinder("pipe", rad, h, x=x, y=y, z=t)
    return Weldment(tuple(b.parts))


def _two_pipes(b: _Builder) -> Weldment:
    r = b.rng
    r1, r2 = r.uniform(0.015, 0.05), r.uniform(0.015, 0.05)
    gap = r.uniform(0.03, 0.08)
    sx = 2 * r1 + 2 * r2 + gap + r.uniform(0.04, 0.10)
    sy = 2 * max(r1, r2) + r.uniform(0.04, 0.12)
    t = r.uniform(0.006, 0.015)
    b.add("base", box_corners(sx, sy, t))
    xc = -(r1 + r2 + gap) / 2
    b.add_cylinder("pipe0", r1, r.uniform(0.04, 0.15), x=xc + 0.0 * r1, y=0.0, z=t)
    b.add_cylinder("pipe1", r2, r.uniform(0.04, 0.15), x=xc + r1 + gap + r2, y=0.0, z=t)
    return Weldment(tuple(b.parts))


def _lap(b: _Builder) -> Weldment:
    r = b.rng
    sx, sy, t = r.uniform(0.15, 0.30), r.uniform(0.10, 0.20), r.uniform(0.004, 0.012)
    tu, su, overlap = r.uniform(0.003, 0.012), r.uniform(0.08, 0.18), r.uniform(0.03, 0.08)
    b.add("lower", box_corners(sx, sy, t))
    b.add("upper", box_corners(sx, su, tu), y=sy / 2 - overlap + su / 2, z=t)
    return Weldment(tuple(b.parts), joint_of=lambda *_: "lap")


def _step(b: _Builder) -> Weldment:
    """A thick pad plate lying on a larger plate: fillets all round its edge faces."""
    r = b.rng
    sx, sy, t = r.uniform(0.18, 0.32), r.uniform(0.15, 0.28), r.uniform(0.006, 0.015)
    b.add("lower", box_corners(sx, sy, t))
    px, py = r.uniform(0.3, 0.7) * sx, r.uniform(0.3, 0.7) * sy
    x, y = r.uniform(-0.5, 0.5) * (sx - px - 0.02), r.uniform(-0.5, 0.5) * (sy - py - 0.02)
    b.add("pad", box_corners(px, py, r.uniform(0.010, 0.025)), x=x, y=y, z=t)
    return Weldment(tuple(b.parts))


def _gusset(b: _Builder) -> Weldment:
    r = b.rng
    sx, sy, t = r.uniform(0.18, 0.32), r.uniform(0.15, 0.28), r.uniform(0.008, 0.015)
    tw, h = r.uniform(0.008, 0.015), r.uniform(0.08, 0.16)
    b.add("floor", box_corners(sx, sy, t))
    xw = r.uniform(0.1, 0.3) * sx
    b.add("wall", box_corners(tw, sy * r.uniform(0.7, 1.0), h), x=xw, z=t)
    n = int(r.integers(1, 4))
    ys = np.linspace(-0.3, 0.3, n) * sy if n > 1 else np.array([r.uniform(-0.2, 0.2) * sy])
    for k, y in enumerate(ys):
        a = min(r.uniform(0.03, 0.08), xw + sx / 2 - tw / 2 - 0.01)
        hb = min(r.uniform(0.03, 0.08), h - 0.01)
        tg = r.uniform(0.005, 0.010)
        tri = np.array([[0.0, 0.0], [-a, 0.0], [0.0, hb]])  # legs along the floor (-x) and up the wall
        corners = prism(tri, tg)
        # prism's extrusion is along y: the gusset plate stands in the x-z plane
        b.add(f"gusset{k}", corners, x=xw - tw / 2, y=float(y), z=t)
    return Weldment(tuple(b.parts))


def _butt(b: _Builder) -> Weldment:
    r = b.rng
    g, t = r.uniform(0.0005, 0.003), r.uniform(0.004, 0.012)
    w0, w1, L = r.uniform(0.06, 0.15), r.uniform(0.06, 0.15), r.uniform(0.12, 0.30)
    left = b.add("left", box_corners(w0, L, t), x=-g / 2 - w0 / 2)
    right = b.add("right", box_corners(w1, L, t), x=g / 2 + w1 / 2)
    top_l = _face_towards(b.parts[left], b.dir_to_world([0.0, 0.0, 1.0])[0])
    top_r = _face_towards(b.parts[right], b.dir_to_world([0.0, 0.0, 1.0])[0])
    pts = b.local_to_world([[0.0, -L / 2, t], [0.0, L / 2, t]])
    into_l = np.tile(b.dir_to_world([-1.0, 0.0, 0.0]), (2, 1))
    seam = SeamDef("butt", "linear", pts, ((left, top_l), (right, top_r)), into_l, -into_l, gap_m=g, joint="butt")
    return Weldment(tuple(b.parts), extra_seams=(seam,), joint_of=lambda *_: "butt")


def _v_groove(b: _Builder) -> Weldment:
    r = b.rng
    t = r.uniform(0.008, 0.020)
    beta = np.radians(r.uniform(25.0, 35.0))
    root = r.uniform(0.0, 0.002)
    root = 0.0 if root < 2e-4 else root
    g = r.uniform(0.0, 0.002)
    g = 0.0 if g < 2e-4 else g
    w0, w1, L = r.uniform(0.06, 0.14), r.uniform(0.06, 0.14), r.uniform(0.12, 0.30)
    run = (t - root) * np.tan(beta)

    def section(w: float) -> FloatArray:
        pts = [[-w, 0.0], [-g / 2, 0.0]] + ([[-g / 2, root]] if root > 0 else []) + [[-g / 2 - run, t], [-w, t]]
        return np.array(pts)

    left = b.add("left", prism(section(w0), L))
    sec_r = section(w1) * [-1.0, 1.0]
    right = b.add("right", prism(sec_r[::-1], L))
    n_l = b.dir_to_world([np.cos(beta), 0.0, np.sin(beta)])[0]
    n_r = b.dir_to_world([-np.cos(beta), 0.0, np.sin(beta)])[0]
    bev_l = _face_towards(b.parts[left], n_l)
    bev_r = _face_towards(b.parts[right], n_r)
    pts = b.local_to_world([[0.0, -L / 2, root], [0.0, L / 2, root]])
    up_l = np.tile(b.dir_to_world([-np.sin(beta), 0.0, np.cos(beta)]), (2, 1))
    up_r = np.tile(b.dir_to_world([np.sin(beta), 0.0, np.cos(beta)]), (2, 1))
    bevel_m = (t - root) / np.cos(beta)
    across = b.dir_to_world([1.0, 0.0, 0.0])[0]
    seam = SeamDef("v_groove", "linear", pts, ((left, bev_l), (right, bev_r)), up_l, up_r, gap_m=g,
                   joint="v_groove", reach_a_m=bevel_m, reach_b_m=bevel_m,
                   across_a=-across, across_b=across)  # fmt: skip
    return Weldment(tuple(b.parts), extra_seams=(seam,), joint_of=lambda *_: "v_groove")


def _face_towards(part: Part, direction: FloatArray) -> int:
    assert part.hull_world is not None
    return int(np.argmax([f.normal @ direction for f in part.hull_world.faces]))


FAMILIES: dict[str, Callable[[_Builder], Weldment]] = {
    "tee": _tee,
    "ribs": _ribs,
    "bars": _bars,
    "inside_corner": _inside_corner,
    "open_box": _open_box,
    "pipe": _pipe,
    "two_pipes": _two_pipes,
    "lap": _lap,
    "step": _step,
    "v_groove": _v_groove,
    "butt": _butt,
    "gusset": _gusset,
}


# Held-out families: weldments of other shapes that the detector was never tuned on (drawn only when named, so
# that the default splits stay as they were): a box section standing on a plate, a cruciform of a rib crossing
# another, and a web leaning up to 40 degrees off the vertical (one fold acute, the other obtuse)


def _box_section(b: _Builder) -> Weldment:
    r = b.rng
    sx, sy, t = r.uniform(0.20, 0.34), r.uniform(0.18, 0.30), r.uniform(0.008, 0.015)
    b.add("base", box_corners(sx, sy, t))
    w, d, h, tw = r.uniform(0.05, 0.12), r.uniform(0.04, 0.10), r.uniform(0.04, 0.12), r.uniform(0.003, 0.008)
    yaw = r.uniform(0.0, np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    walls = (((w, tw), (0.0, d / 2 - tw / 2)), ((w, tw), (0.0, -d / 2 + tw / 2)),
             ((tw, d - 2 * tw), (w / 2 - tw / 2, 0.0)), ((tw, d - 2 * tw), (-w / 2 + tw / 2, 0.0)))  # fmt: skip
    for k, ((lx, ly), (x, y)) in enumerate(walls):
        b.add(f"wall{k}", box_corners(lx, ly, h), x=c * x - s * y, y=s * x + c * y, z=t, yaw=yaw)
    return Weldment(tuple(b.parts), joint_of=_corner_joint)


def _cruciform(b: _Builder) -> Weldment:
    r = b.rng
    sx, sy, t = r.uniform(0.24, 0.36), r.uniform(0.22, 0.32), r.uniform(0.008, 0.015)
    b.add("base", box_corners(sx, sy, t))
    tw, h = r.uniform(0.005, 0.012), r.uniform(0.03, 0.08)
    length, half, off = r.uniform(0.6, 0.85) * sx, r.uniform(0.25, 0.4) * sy, r.uniform(-0.15, 0.15) * sx
    b.add("rib", box_corners(length, tw, h), z=t)
    for sign in (1.0, -1.0):
        b.add(f"cross{int(sign)}", box_corners(tw, half, h), x=off, y=sign * (tw + half) / 2, z=t)
    return Weldment(tuple(b.parts), joint_of=_corner_joint)


def _leaning_web(b: _Builder) -> Weldment:
    r = b.rng
    sx, sy, t = r.uniform(0.18, 0.32), r.uniform(0.16, 0.28), r.uniform(0.008, 0.015)
    b.add("base", box_corners(sx, sy, t))
    lean = np.radians(r.uniform(-40.0, 40.0))
    length, tw, h = r.uniform(0.6, 0.85) * sx, r.uniform(0.005, 0.012), r.uniform(0.04, 0.09)
    foot, shift = tw / np.cos(lean), h * np.tan(lean)  # its cross-section: a parallelogram on its foot
    section = ((-foot / 2, 0.0), (foot / 2, 0.0), (-foot / 2 + shift, h), (foot / 2 + shift, h))
    corners = np.array([[x, y, z] for x in (-length / 2, length / 2) for y, z in section])
    b.add("web", corners, y=r.uniform(-0.15, 0.15) * sy, z=t)
    return Weldment(tuple(b.parts))


HELD_OUT: dict[str, Callable[[_Builder], Weldment]] = {
    "box_section": _box_section,
    "cruciform": _cruciform,
    "leaning_web": _leaning_web,
}
ALL_FAMILIES = FAMILIES | HELD_OUT


# --------------------------------------------------------------------------------------------------
# Scenes, views, captures


def _clutter(b: _Builder, weld_parts: list[Part]) -> list[Part]:
    """1 to 3 boxes on the table, clear of the weldment's footprint by 20 to 80 mm."""
    r = b.rng
    corners = np.vstack([_part_points(p) for p in weld_parts])
    lo, hi = corners[:, :2].min(axis=0), corners[:, :2].max(axis=0)
    out: list[Part] = []
    for k in range(int(r.integers(1, 4))):
        sx, sy, sz = r.uniform(0.03, 0.10), r.uniform(0.03, 0.10), r.uniform(0.02, 0.08)
        side = int(r.integers(4))
        clear = r.uniform(0.02, 0.08)
        if side < 2:
            x = lo[0] - clear - sx / 2 if side == 0 else hi[0] + clear + sx / 2
            y = r.uniform(lo[1], hi[1])
        else:
            y = lo[1] - clear - sy / 2 if side == 2 else hi[1] + clear + sy / 2
            x = r.uniform(lo[0], hi[0])
        X = make_X(_rz(r.uniform(0, np.pi)), [x, y, 0.0])
        grey = r.uniform(0.15, 0.5)
        out.append(Part(f"clutter{k}", "hull", (0.0, 0.0, 0.0), X, (grey, grey * 0.9, grey * 0.8), workpiece=False,
                        corners_part=box_corners(sx, sy, sz)))  # fmt: skip
    return out


def _part_points(p: Part) -> FloatArray:
    if p.hull_world is not None:
        return np.asarray(p.hull_world.vertices)
    r, _, h = p.size
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros(16)])
    pts = np.vstack([ring, ring + np.array([0.0, 0.0, h])])
    return np.asarray(pts @ p.X_world_part[:3, :3].T + p.X_world_part[:3, 3])


def family_code(family: str) -> int:
    return zlib.crc32(family.encode())


def split_of(seed: int) -> str:
    return "test" if seed >= SPLIT_BASE["test"] else "dev"


def draw_scene(family: str, seed: int) -> tuple[Scene, np.random.Generator, int]:
    """The weldment of ``family`` drawn with ``seed`` on a table (camera not yet placed), the stream to go on
    drawing from, and the number of clutter boxes."""
    if family not in ALL_FAMILIES:
        raise KeyError(f"unknown zoo family {family!r}; choose from {', '.join(ALL_FAMILIES)}")
    rng = np.random.default_rng([family_code(family), seed])
    b = _Builder(rng)
    weld = ALL_FAMILIES[family](b)
    parts = list(weld.parts)
    n_clutter = 0
    if rng.random() < CLUTTER_SHARE:
        clutter = _clutter(b, parts)
        n_clutter = len(clutter)
        parts += clutter
    table = Part("table", "box", (2.0, 2.0, 0.04), make_X(np.eye(3), [0.0, 0.0, -0.02]), TABLE_RGB, workpiece=False)
    parts.insert(0, table)
    found = dedupe_seams([*weld.extra_seams, *fold_seams(parts[1:], joint_rule=weld.joint_of)])
    seams = [_shift_seam(s, 1) for s in found]
    scene = Scene(f"zoo:{family}:{seed}", f"zoo family {family}, seed {seed}", tuple(parts), tuple(seams),
                  CameraSetup(eye=(0.0, -0.5, 0.5), target=(0.0, 0.0, 0.0)))  # fmt: skip
    return scene, rng, n_clutter


def _shift_seam(s: SeamDef, by: int) -> SeamDef:
    (pa, fa), (pb, fb) = s.faces
    return replace(s, faces=((pa + by, fa), (pb + by, fb)))


def draw_capture(
    family: str, seed: int, *, width: int = 1280, height: int = 720, noise_free: bool = False,
    sensor: str | None = None,
) -> ZooCapture:
    """Draw, place the camera and render one zoo capture (deterministic in family and seed).

    The camera is redrawn (up to 30 times) until at least one seam is visible under :data:`ZOO_RULES` (to both
    cameras of a stereo sensor).
    ``noise_free`` renders the same draw with exact depth (for tests of the truth). ``sensor`` (a key of
    :data:`SENSORS`) renders the same weldment from the same view with that sensor instead of the drawn one.
    """
    scene, rng, n_clutter = draw_scene(family, seed)
    work = np.vstack([_part_points(p) for p in scene.parts if p.workpiece])
    centre = 0.5 * (work.min(axis=0) + work.max(axis=0))
    if sensor is not None and sensor not in SENSORS:
        raise KeyError(f"unknown zoo sensor {sensor!r}; choose from {', '.join(SENSORS)}")
    drawn = str(rng.choice(list(SENSOR_SHARE), p=list(SENSOR_SHARE.values())))  # the view is drawn for it
    prompted = bool(rng.random() >= NO_PROMPT_SHARE)
    fx = rng.uniform(900.0, 940.0) * width / 1280.0
    cam = scene.camera
    dist = elev = 0.0
    for _ in range(MAX_VIEW_TRIES):
        az, elev, dist = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(35.0, 80.0)), rng.uniform(0.30, 0.90)
        target = centre + np.array([rng.normal(0, 0.02), rng.normal(0, 0.02), 0.0])
        target[2] = rng.uniform(0.0, 0.5) * centre[2]
        eye = target + dist * np.array([np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.sin(elev)])
        cam = CameraSetup(eye=tuple(eye), target=tuple(target), width=width, height=height, fx=fx, fy=fx)
        if visible_ground_truth(replace(scene, camera=cam), look_at_X(eye, target), rules=ZOO_RULES,
                                sensor=SENSORS[drawn]):  # fmt: skip
            break
    scene = replace(scene, camera=cam)
    noise_seed = int(rng.integers(2**31))
    sensor = drawn if sensor is None else sensor
    noise = "structured" if sensor == "structured" else "stereo"
    if noise_free:
        result = render(scene, noise="none", seed=noise_seed, rules=ZOO_RULES)
    else:
        result = render(scene, noise=noise, seed=noise_seed, rules=ZOO_RULES, sensor=SENSORS[sensor])  # type: ignore[arg-type]
    result = _apply_prompt_policy(result, prompted, rng)
    return ZooCapture(family, split_of(seed), seed, sensor, prompted, n_clutter, float(dist), float(elev), result)


def _apply_prompt_policy(result: RenderResult, prompted: bool, rng: np.random.Generator) -> RenderResult:
    """Operator clicks: none at all for a share of captures; small surfaces are sometimes left out."""
    cap = result.capture
    if not prompted:
        return replace(result, capture=replace(cap, prompts_px=None))
    assert cap.prompts_px is not None
    keep = []
    for k in range(len(cap.prompts_px)):
        small = int((result.surface_labels == k).sum()) < SMALL_SURFACE_PX
        if not (small and rng.random() < SMALL_SURFACE_SKIP):
            keep.append(k)
    return replace(result, capture=replace(cap, prompts_px=cap.prompts_px[keep]))


def split_plan(split: str, n: int, families: list[str] | None = None) -> list[tuple[str, int]]:
    """(family, seed) of the first ``n`` captures of a split (``families``: by default the twelve of
    :data:`FAMILIES`; the :data:`HELD_OUT` ones only when named)."""
    if split not in SPLIT_BASE:
        raise ValueError(f"unknown split {split!r}; use dev or test")
    fams = families or list(FAMILIES)
    for f in fams:
        if f not in ALL_FAMILIES:
            raise KeyError(f"unknown zoo family {f!r}; choose from {', '.join(ALL_FAMILIES)}")
    return [(fams[k % len(fams)], SPLIT_BASE[split] + k // len(fams)) for k in range(n)]
