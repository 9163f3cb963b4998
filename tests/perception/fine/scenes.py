"""Small constructed weldments rendered for the fine-stage tests (exact geometry known)."""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np

from perception.fine.noise import LocalPlanes, estimate_noise, local_planes
from perception.fine.surfaces import segment_surfaces
from perception.fine.types import NoiseModel, SurfaceSet
from perception.transforms import make_X
from sim_fakes.contacts import fold_seams
from sim_fakes.hull import box_corners, prism
from sim_fakes.render import RenderResult, StereoSensor, render
from sim_fakes.scenes import CameraSetup, Part, Scene, SeamDef

TABLE = Part("table", "box", (2.0, 2.0, 0.04), make_X(np.eye(3), [0.0, 0.0, -0.02]), (0.2, 0.2, 0.2), workpiece=False)
WHITE_ONLY = StereoSensor(sigma_corr_px=0.0, p_fly=0.0, p_speckle=0.0, specular_exponent=1e9)


def hull(name: str, corners: np.ndarray, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Part:
    return Part(name, "hull", (0, 0, 0), make_X(np.eye(3), [x, y, z]), (0.5, 0.5, 0.5), corners_part=corners)


def scene_of(parts: tuple[Part, ...], eye: tuple[float, float, float], target=(0.0, 0.0, 0.02)) -> Scene:
    found = fold_seams(parts)
    seams = tuple(replace(s, faces=((s.faces[0][0] + 1, s.faces[0][1]), (s.faces[1][0] + 1, s.faces[1][1])))
                  for s in found)  # fmt: skip
    cam = CameraSetup(eye=eye, target=target, width=640, height=360, fx=460.0, fy=460.0)
    return Scene("test", "", (TABLE, *parts), seams, cam)


def tee() -> Scene:
    """A 10 mm web, 80 mm tall and 160 mm long, on a 12 mm plate; seen from the -x side."""
    base = hull("base", box_corners(0.30, 0.24, 0.012))
    web = hull("web", box_corners(0.010, 0.16, 0.08), z=0.012)
    return scene_of((base, web), eye=(-0.32, -0.10, 0.30))


def pipe(radius: float = 0.04, *, view_scale: float = 1.0) -> Scene:
    """A pipe standing on a 10 mm plate, seen from 0.48 m (times ``view_scale``)."""
    base = hull("base", box_corners(0.26, 0.26, 0.010))
    cyl = Part("pipe", "cylinder", (radius, radius, 0.10), make_X(np.eye(3), [0.0, 0.0, 0.010]), (0.5, 0.5, 0.5))
    return scene_of((base, cyl), eye=(-0.05 * view_scale, -0.34 * view_scale, 0.34 * view_scale))


def butt(gap: float = 0.002, eye: tuple[float, float, float] = (-0.10, -0.25, 0.32)) -> Scene:
    """Two 8 mm plates 120 x 200 mm with a ``gap`` between them along y, at x = 0; seen from ``eye`` (the
    default: 17 degrees across the gap from its plates' normal)."""
    left = hull("left", box_corners(0.12, 0.20, 0.008), x=-0.06 - gap / 2)
    right = hull("right", box_corners(0.12, 0.20, 0.008), x=0.06 + gap / 2)
    sc = scene_of((left, right), eye=eye, target=(0.0, 0.0, 0.0))
    top = [int(np.argmax([f.normal[2] for f in part.hull_world.faces])) for part in (left, right)]  # type: ignore[union-attr]
    x = np.tile([-1.0, 0.0, 0.0], (2, 1))
    seam = SeamDef("butt", "linear", np.array([[0.0, -0.1, 0.008], [0.0, 0.1, 0.008]]), ((1, top[0]), (2, top[1])),
                   x, -x, gap_m=gap, joint="butt")  # fmt: skip
    return replace(sc, seams=(*sc.seams, seam))


def wall() -> Scene:
    """A wall 40 mm tall standing across a 12 mm floor plate end to end, 2 mm thick at its foot and 4 mm at its
    top (its sides face away from a camera above it), seen from above: the floor on both sides of it and
    its top between them."""
    base = hull("base", box_corners(0.30, 0.24, 0.012))
    wall = hull("wall", prism(np.array([[-0.001, 0.0], [0.001, 0.0], [0.002, 0.04], [-0.002, 0.04]]), 0.24), z=0.012)
    return scene_of((base, wall), eye=(0.0, -0.04, 0.45))


def lap(*, behind: bool = False) -> Scene:
    """A 5 mm plate overlapping a 10 mm one by 60 mm; seen towards its edge face, or from behind it."""
    lower = hull("lower", box_corners(0.22, 0.16, 0.010))
    upper = hull("upper", box_corners(0.22, 0.14, 0.005), y=0.08 - 0.06 + 0.07, z=0.010)
    eye = (-0.05, 0.45, 0.30) if behind else (-0.05, -0.32, 0.30)
    return scene_of((lower, upper), eye=eye, target=(0.0, 0.02, 0.0))


def lip() -> Scene:
    """A 10 mm plate whose -y edge rises in a lip 6 mm high and 2 mm deep (its inner face 72 degrees from the
    plate, its outer face flush with the plate's end, no top face), seen from the plate's side of it."""
    base = hull("base", box_corners(0.22, 0.16, 0.010))
    section = np.array([[0.0, 0.0], [0.002, 0.0], [0.002, 0.006]])  # extruded along y: turned onto x below
    along_x = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    rim = Part("lip", "hull", (0, 0, 0), make_X(along_x, [0.0, -0.078, 0.010]), (0.5, 0.5, 0.5),
               corners_part=prism(section, 0.22))  # fmt: skip
    return scene_of((base, rim), eye=(-0.05, 0.30, 0.30), target=(0.0, -0.02, 0.0))


def v_groove(*, gap: float = 0.0, root: float = 0.0, near: bool = False) -> Scene:
    """Two 12 mm plates with 30-degree bevels (from the vertical) meeting at a V, its root ``root`` above
    the plates' bottom, with a ``gap`` between their root faces; seen from 0.6 m, so that each bevel is a
    strip about five pixels wide (``near``: from 0.35 m, so that the gap is two pixels wide)."""
    t, beta, w, length = 0.012, np.radians(30.0), 0.10, 0.20
    run = (t - root) * np.tan(beta)

    def section(sign: float) -> np.ndarray:
        pts = [[-w, 0.0], [-gap / 2, 0.0]] + ([[-gap / 2, root]] if root > 0 else []) + [[-gap / 2 - run, t], [-w, t]]
        sec = np.array(pts) * [sign, 1.0]
        return sec if sign > 0 else sec[::-1]

    left = hull("left", prism(section(1.0), length))
    right = hull("right", prism(section(-1.0), length))
    eye = (0.05, -0.15, 0.31) if near else (0.12, -0.30, 0.52)
    cam = CameraSetup(eye=eye, target=(0.0, 0.0, 0.0), width=640, height=360, fx=460.0, fy=460.0)
    faces = []
    for part, nx in ((left, np.cos(beta)), (right, -np.cos(beta))):
        n = np.array([nx, 0.0, np.sin(beta)])
        faces.append(int(np.argmax([f.normal @ n for f in part.hull_world.faces])))  # type: ignore[union-attr]
    up_l = np.tile([-np.sin(beta), 0.0, np.cos(beta)], (2, 1))
    up_r = up_l * [-1.0, 1.0, 1.0]
    bevel = (t - root) / np.cos(beta)
    x = np.array([1.0, 0.0, 0.0])
    seam = SeamDef("v_groove", "linear", np.array([[0.0, -length / 2, root], [0.0, length / 2, root]]),
                   ((1, faces[0]), (2, faces[1])), up_l, up_r, gap_m=gap, joint="v_groove", reach_a_m=bevel,
                   reach_b_m=bevel, across_a=-x, across_b=x)  # fmt: skip
    return Scene("test", "", (TABLE, left, right), (seam,), cam)


def gusset(*, at_end: bool = False) -> Scene:
    """A triangular 8 mm gusset (60 mm along the floor, 50 mm up) in the middle of a 100 mm wall standing on a
    12 mm floor, the wall going on 80 mm each side of it (``at_end``: 12 mm past it on one side): a T, its
    vertical seam a fillet. Seen from the gusset's -y side, in front of the wall."""
    floor = hull("floor", box_corners(0.30, 0.26, 0.012))
    wall = hull("wall", box_corners(0.010, 0.18, 0.10), x=0.05, z=0.012)
    y = 0.09 - 0.016 if at_end else 0.0
    tri = np.array([[0.0, 0.0], [-0.06, 0.0], [0.0, 0.05]])  # legs along the floor (-x) and up the wall
    g = hull("gusset", prism(tri, 0.008), x=0.045, y=y, z=0.012)
    return scene_of((floor, wall, g), eye=(-0.25, -0.30, 0.32), target=(0.02, y, 0.04))


def corner() -> Scene:
    """Two 10 mm walls, 100 and 60 mm tall, butted at a corner on a 12 mm floor (the taller one's face shows
    past the lower one's plane above it): a corner, its vertical seam an inside corner."""
    floor = hull("floor", box_corners(0.26, 0.26, 0.012))
    wx = hull("wall_x", box_corners(0.010, 0.20, 0.10), x=0.08, z=0.012)
    wy = hull("wall_y", box_corners(0.17, 0.010, 0.06), x=-0.01, y=0.095, z=0.012)
    return scene_of((floor, wx, wy), eye=(-0.25, -0.30, 0.32), target=(0.03, 0.03, 0.04))


@cache
def rendered(name: str, noise: str = "none", seed: int = 0) -> RenderResult:
    sc = {"tee": tee, "pipe": pipe, "thin_pipe_far": lambda: pipe(0.015, view_scale=1.8), "butt": butt,
          "butt_oblique": lambda: butt(0.0015, eye=(-0.26, -0.12, 0.30)), "butt_fine": lambda: butt(0.0006),
          "butt_far": lambda: butt(0.0008, eye=(-0.16, -0.40, 0.51)),
          "wall": wall,
          "lap": lap, "lip": lip, "lap_behind": lambda: lap(behind=True), "v_groove": v_groove,
          "v_groove_open": lambda: v_groove(gap=0.0016, root=0.001, near=True), "branch": branch,
          "gusset": gusset, "gusset_end": lambda: gusset(at_end=True), "corner": corner}[name]()  # fmt: skip
    if noise == "stereo":
        return render(sc, noise="stereo", seed=seed, sensor=WHITE_ONLY)
    return render(sc, noise="none", seed=seed)


@cache
def work(name: str, noise: str = "none", seed: int = 0) -> tuple[np.ndarray, LocalPlanes, NoiseModel, SurfaceSet]:
    """The work image (every pixel: these renders are already 640 wide), its local planes, noise, surfaces."""
    res = rendered(name, noise, seed)
    p = res.capture.points_camera().astype(np.float64)
    lp = local_planes(p, window_px=7)
    nm = estimate_noise(p, lp)
    return p, lp, nm, segment_surfaces(p, lp, nm, factor=1)


def branch(main_radius: float = 0.05, branch_radius: float = 0.02) -> Scene:
    """A branch pipe standing on a main pipe that lies along x on the table (its axis at z = ``main_radius``):
    they meet in a saddle, x = r cos t, y = r sin t, z = R + sqrt(R^2 - y^2). Seen from (-0.25, -0.20, 0.35)."""
    R, r = main_radius, branch_radius
    along_x = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # the cylinder's z onto x
    main = Part("main", "cylinder", (R, R, 0.30), make_X(along_x, [-0.15, 0.0, R]), (0.5, 0.5, 0.5))
    stand = Part("branch", "cylinder", (r, r, 0.12), make_X(np.eye(3), [0.0, 0.0, R]), (0.5, 0.5, 0.5))
    cam = CameraSetup(eye=(-0.25, -0.20, 0.35), target=(0.0, 0.0, 0.08), width=640, height=360, fx=460.0, fy=460.0)
    return Scene("test", "", (TABLE, main, stand), (), cam)
