"""Render a :class:`~sim_fakes.scenes.Scene` to an RGB-D capture with exact, visibility-clipped ground truth.

Rays are built here in the OpenCV convention, pixel (u, v) through ``((u - cx)/fx, (v - cy)/fy, 1)``,
and cast with Open3D's ``RaycastingScene`` (CPU, headless). Building the rays ourselves instead of
``create_rays_pinhole`` avoids its half-pixel offset (the "pixel-centre trap" of the capture spec).
Because each ray's camera-z component is 1, the hit distance ``t_hit`` *is* the depth z.

Noise models (depth along z, metres):
- ``none``: exact depth.
- ``stereo``: sigma = 0.5 mm * (z / 0.5 m)^2 / max(cos(incidence), 0.25), dropouts rising from 70 to
  85 degrees incidence, flying pixels at depth edges, sparse speckle dropouts.
- ``structured``: sigma = 0.1 mm * (z / 0.5 m)^2 / max(cos, 0.5), dropouts beyond 78 degrees, fewer
  flying pixels.
Colour: per-part albedo, two-light Lambertian shading, a brushed-metal texture and sensor noise.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics, Capture, GroundTruthSeam
from perception.transforms import invert_X, make_X, transform_points
from sim_fakes.scenes import CYL_SIDE, CYLINDER_SEGMENTS, Part, Scene

FloatArray = NDArray[np.float64]
NoiseModel = Literal["none", "stereo", "structured"]
NOISE_MODELS: tuple[str, ...] = ("none", "stereo", "structured")

SIM_DEPTH_SCALE = 10000.0  # 0.1 mm per count in depth.png
GT_STEP_M = 0.0005
GT_FACE_OFFSET_M = 0.003  # a seam is seen when its centre and 3 mm into both faces are seen
GT_MIN_RUN_M = 0.015
MAX_INCIDENCE_DEG = 78.0
STRUCTURED_DROPOUT_DEG = 78.0
PROMPT_MIN_PIXELS = 400

# Robot base placement used by --with-pose: the scene's world frame expressed in the robot base frame,
# and a fixed hand-eye result. Both are arbitrary but non-trivial so that frame mistakes show.
X_BASE_WORLD = make_X(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [0.62, 0.04, 0.015])
X_TOOL_CAMERA = make_X(
    np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.0, 1.0, 1.0]), [0.032, -0.061, 0.045]
)


# --------------------------------------------------------------------------------------------------
# Meshes with per-triangle face ids


def _box_mesh(part: Part) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.int32]]:
    sx, sy, sz = (s / 2 for s in part.size)
    v = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    # vertex index = 4*ix + 2*iy + iz; quads listed with outward (counter-clockwise) winding
    quads = {
        0: (0, 1, 3, 2),  # -x
        1: (4, 6, 7, 5),  # +x
        2: (0, 4, 5, 1),  # -y
        3: (2, 3, 7, 6),  # +y
        4: (0, 2, 6, 4),  # -z
        5: (1, 5, 7, 3),  # +z
    }
    tris, faces = [], []
    for f, (a, b, c, d) in quads.items():
        tris += [(a, b, c), (a, c, d)]
        faces += [f, f]
    return transform_points(part.X_world_part, v), np.array(tris, np.int32), np.array(faces, np.int32)


def _cylinder_mesh(part: Part) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.int32]]:
    r, _, h = part.size
    n = CYLINDER_SEGMENTS
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    bottom = np.column_stack([ring, np.zeros(n)])
    top = np.column_stack([ring, np.full(n, h)])
    v = np.vstack([bottom, top, [[0.0, 0.0, 0.0], [0.0, 0.0, h]]])
    i = np.arange(n)
    j = (i + 1) % n
    side = np.vstack([np.column_stack([i, j, n + j]), np.column_stack([i, n + j, n + i])])
    cap_b = np.column_stack([np.full(n, 2 * n), j, i])
    cap_t = np.column_stack([np.full(n, 2 * n + 1), n + i, n + j])
    tris = np.vstack([side, cap_b, cap_t]).astype(np.int32)
    faces = np.concatenate([np.full(2 * n, CYL_SIDE), np.full(n, 1), np.full(n, 2)]).astype(np.int32)
    return transform_points(part.X_world_part, v), tris, faces


def part_mesh(part: Part) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.int32]]:
    """(V, 3) world vertices, (T, 3) triangles, (T,) face id per triangle."""
    if part.hull_world is not None:
        h = part.hull_world
        return h.vertices, h.triangles, h.triangle_face
    return _box_mesh(part) if part.shape == "box" else _cylinder_mesh(part)


def face_normal_at(part: Part, face: int, p_world: FloatArray) -> FloatArray:
    """(N, 3) exact outward normals of ``face`` at (N, 3) points on it."""
    p = np.asarray(p_world, dtype=np.float64).reshape(-1, 3)
    if part.hull_world is not None:
        return np.tile(part.hull_world.faces[face].normal, (len(p), 1))
    if part.shape == "cylinder" and face == CYL_SIDE:
        X_part_world = invert_X(part.X_world_part)
        q = transform_points(X_part_world, p)
        radial = np.column_stack([q[:, 0], q[:, 1], np.zeros(len(q))])
        radial /= np.linalg.norm(radial, axis=1, keepdims=True)
        return radial @ part.X_world_part[:3, :3].T
    return np.tile(part.face_normal_world(face), (len(p), 1))


# --------------------------------------------------------------------------------------------------
# Rendering


@dataclass(frozen=True)
class GroundTruthDetail:
    """A visible seam with what the evaluation and tests need beyond the file format."""

    name: str
    kind: Literal["linear", "curved"]
    points_world: FloatArray
    points_camera: FloatArray
    normal_a_camera: FloatArray  # (N, 3) outward normals of the two faces at the points
    normal_b_camera: FloatArray
    faces: tuple[tuple[int, int], tuple[int, int]]
    joint: str = "fillet"
    seam_index: int = -1  # into the scene's seams


@dataclass(frozen=True)
class RenderResult:
    """A rendered capture plus the exact per-pixel truth behind it.

    depth_true_m: (H, W) noise-free depth, NaN where no geometry.
    part_index, face_index: (H, W) int32 of the surface hit (-1 = nothing).
    surface_labels: (H, W) int32 index into ``surfaces`` for prompted workpiece faces, -1 elsewhere.
    normals_camera: (H, W, 3) exact outward normals in the camera frame (NaN where nothing was hit).
    """

    scene: Scene
    capture: Capture
    depth_true_m: NDArray[np.float64]
    part_index: NDArray[np.int32]
    face_index: NDArray[np.int32]
    surface_labels: NDArray[np.int32]
    surfaces: tuple[tuple[int, int], ...]
    normals_camera: NDArray[np.float64]
    X_world_camera: FloatArray
    ground_truth: tuple[GroundTruthDetail, ...]


class _Raycaster:
    def __init__(self, scene: Scene) -> None:
        import open3d as o3d

        self._o3d = o3d
        self.rc = o3d.t.geometry.RaycastingScene()
        self.face_of_triangle: list[NDArray[np.int32]] = []
        for part in scene.parts:
            v, t, f = part_mesh(part)
            mesh = o3d.t.geometry.TriangleMesh()
            mesh.vertex.positions = o3d.core.Tensor.from_numpy(np.ascontiguousarray(v, dtype=np.float32))
            mesh.triangle.indices = o3d.core.Tensor.from_numpy(np.ascontiguousarray(t))
            self.rc.add_triangles(mesh)
            self.face_of_triangle.append(f)

    def cast(self, origins: FloatArray, dirs: FloatArray) -> dict[str, NDArray]:
        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        ans = self.rc.cast_rays(self._o3d.core.Tensor.from_numpy(rays))
        return {k: v.numpy() for k, v in ans.items()}


def _rays(scene: Scene, X_world_camera: FloatArray) -> tuple[FloatArray, FloatArray]:
    cam = scene.camera
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    d_cam = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1).reshape(-1, 3)
    d_world = d_cam @ X_world_camera[:3, :3].T
    origins = np.broadcast_to(X_world_camera[:3, 3], d_world.shape)
    return np.ascontiguousarray(origins), d_world


def _exact_depth(
    scene: Scene, caster: _Raycaster, X_world_camera: FloatArray
) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.int32], FloatArray]:
    """Noise-free depth (float64 refined from the float32 hit) and hit ids, each (H, W)."""
    cam = scene.camera
    origins, dirs = _rays(scene, X_world_camera)
    ans = caster.cast(origins, dirs)
    t = ans["t_hit"].astype(np.float64)
    gid = ans["geometry_ids"].astype(np.int64)
    pid = ans["primitive_ids"].astype(np.int64)
    hit = np.isfinite(t) & (gid < len(scene.parts))
    part_idx = np.where(hit, gid, -1).astype(np.int32)
    face_idx = np.full(t.shape, -1, np.int32)
    normals = np.full((t.size, 3), np.nan)
    depth = np.full(t.shape, np.nan)
    # Open3D intersects in float32; recompute t exactly (float64) against the analytic surface so that
    # noise-free depth is exact to well below a micrometre.
    for k, part in enumerate(scene.parts):
        sel = np.flatnonzero(part_idx == k)
        if sel.size == 0:
            continue
        faces = caster.face_of_triangle[k][pid[sel]]
        face_idx[sel] = faces
        o, d = origins[sel], dirs[sel]
        t0 = t[sel]
        approx = o + t0[:, None] * d
        n = np.empty((sel.size, 3))
        for f in np.unique(faces):
            m = faces == f
            n[m] = face_normal_at(part, int(f), approx[m])
        if part.shape == "cylinder":
            t_exact = _refine_cylinder(part, o, d, t0, faces)
        elif part.hull_world is not None:
            offs = np.array([f.offset for f in part.hull_world.faces])[faces]
            t_exact = -(np.einsum("ij,ij->i", o, n) + offs) / np.einsum("ij,ij->i", d, n)
        else:
            # plane through the face: n . (p - p_face) = 0, with p_face from the part centre
            c = part.X_world_part[:3, 3]
            half = np.abs(np.asarray(part.size) / 2)
            local_n = n @ part.X_world_part[:3, :3]
            offset = np.abs(local_n) @ half
            p0 = c + n * offset[:, None]
            t_exact = np.einsum("ij,ij->i", p0 - o, n) / np.einsum("ij,ij->i", d, n)
        depth[sel] = t_exact
        normals[sel] = n
    H, W = cam.height, cam.width
    return depth.reshape(H, W), part_idx.reshape(H, W), face_idx.reshape(H, W), normals.reshape(H, W, 3)


def _refine_cylinder(part: Part, o: FloatArray, d: FloatArray, t0: FloatArray, faces: NDArray) -> FloatArray:
    X_part_world = invert_X(part.X_world_part)
    ol = transform_points(X_part_world, o)
    dl = d @ X_part_world[:3, :3].T
    r, _, h = part.size
    t = t0.copy()
    side = faces == CYL_SIDE
    a = dl[side, 0] ** 2 + dl[side, 1] ** 2
    b = 2 * (ol[side, 0] * dl[side, 0] + ol[side, 1] * dl[side, 1])
    c = ol[side, 0] ** 2 + ol[side, 1] ** 2 - r * r
    disc = np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))
    t[side] = (-b - disc) / (2 * a)
    caps = ~side
    zc = np.where(faces[caps] == 1, 0.0, h)
    t[caps] = (zc - ol[caps, 2]) / dl[caps, 2]
    return t


def _noisy_depth(depth: FloatArray, cos_inc: FloatArray, noise: NoiseModel, rng: np.random.Generator) -> FloatArray:
    if noise == "none":
        return depth.copy()
    z = depth.copy()
    valid = np.isfinite(z)
    inc_deg = np.degrees(np.arccos(np.clip(cos_inc, 0.0, 1.0)))
    if noise == "stereo":
        sigma = 0.0005 * (z / 0.5) ** 2 / np.maximum(cos_inc, 0.25)
        p_drop = np.clip((inc_deg - 70.0) / 15.0, 0.0, 1.0) + 0.002
        p_fly = 0.6
    else:
        sigma = 0.0001 * (z / 0.5) ** 2 / np.maximum(cos_inc, 0.5)
        p_drop = (inc_deg > STRUCTURED_DROPOUT_DEG).astype(float) + 0.0005
        p_fly = 0.2
    z = z + rng.standard_normal(z.shape) * np.where(valid, sigma, 0.0)
    z = _flying_pixels(depth, z, p_fly, rng)
    drop = valid & (rng.random(z.shape) < p_drop)
    z[drop] = np.nan
    return z


@dataclass(frozen=True)
class StereoSensor:
    """An active stereo camera (OAK-D-like), modelled in the disparity domain.

    Disparity d = fx * baseline / z gets white noise ``sigma_px`` (grown as 1/sqrt(cos incidence) on
    slanted surfaces), a spatially correlated part ``sigma_corr_px`` (smooth over ``corr_px`` pixels),
    and is quantised to 1/``subpixel`` px before turning back into depth. Pixels the second camera (at
    +baseline along the camera's x axis) cannot see get no depth (stereo shadows); dropouts rise from
    ``grazing_deg`` to ``grazing_deg`` + 15 degrees incidence; depth edges get flying pixels; steel seen
    near the mirror direction of the projector gets specular holes. With ``median_px`` > 1 the disparity
    then passes a median post-filter over ``median_px`` square windows (an OAK-D's StereoDepth median: 3, 5
    or 7) of the valid pixels around each valid one; invalid pixels stay invalid. It rounds corners and
    grooves over its window and correlates the noise of neighbouring pixels.
    """

    baseline_m: float = 0.075
    sigma_px: float = 0.08
    sigma_corr_px: float = 0.04
    corr_px: float = 12.0
    subpixel: int = 8
    grazing_deg: float = 70.0
    p_fly: float = 0.5
    specular_exponent: float = 300.0
    p_speckle: float = 0.002
    median_px: int = 1


def second_eye(X_world_camera: FloatArray, sensor: StereoSensor) -> FloatArray:
    """Where a stereo sensor's second camera sits (world frame): ``baseline_m`` along the camera's x axis."""
    return np.asarray(X_world_camera[:3, 3] + sensor.baseline_m * X_world_camera[:3, 0], dtype=np.float64)


def _flying_pixels(depth: FloatArray, z: FloatArray, p_fly: float, rng: np.random.Generator) -> FloatArray:
    """A mix of foreground and background depth where the true depth jumps by more than 1 cm."""
    valid = np.isfinite(depth)
    zf = np.where(valid, depth, np.inf)
    pad = np.pad(zf, 1, mode="edge")
    neigh = np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    far = np.where(np.isfinite(neigh), neigh, np.nan)
    stack = np.concatenate([far, depth[None]])
    zmax = np.max(np.where(np.isfinite(stack), stack, -np.inf), axis=0)
    edge = valid & (zmax - depth > 0.01)
    fly = edge & (rng.random(z.shape) < p_fly)
    mix = rng.uniform(0.1, 0.9, z.shape)
    return np.where(fly, depth + mix * (zmax - depth), z)


def _smooth_field(shape: tuple[int, int], scale_px: float, rng: np.random.Generator) -> FloatArray:
    """(H, W) zero-mean, unit-variance random field correlated over about ``scale_px`` pixels."""
    import cv2

    H, W = shape
    h, w = max(2, int(np.ceil(H / scale_px)) + 1), max(2, int(np.ceil(W / scale_px)) + 1)
    coarse = rng.standard_normal((h, w)).astype(np.float32)
    field = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC).astype(np.float64)
    return (field - field.mean()) / max(float(field.std()), 1e-12)


def _stereo_depth(
    depth: FloatArray,
    cos_inc: FloatArray,
    sensor: StereoSensor,
    rng: np.random.Generator,
    *,
    fx: float,
    caster: _Raycaster,
    X_world_camera: FloatArray,
    dirs_world: FloatArray,
    steel: NDArray[np.bool_],
) -> FloatArray:
    valid = np.isfinite(depth)
    fb = fx * sensor.baseline_m
    zt = np.where(valid, depth, 1.0)
    g = 1.0 / np.sqrt(np.maximum(cos_inc, 0.25))
    disp = fb / zt
    disp = disp + sensor.sigma_px * g * rng.standard_normal(depth.shape)
    disp = disp + sensor.sigma_corr_px * _smooth_field(depth.shape, sensor.corr_px, rng)
    disp = np.round(disp * sensor.subpixel) / sensor.subpixel
    z = np.where(valid & (disp > 0), fb / np.maximum(disp, 1e-9), np.nan)
    # stereo shadow: the second camera's ray to the surface point is blocked
    eye2 = second_eye(X_world_camera, sensor)
    flat = np.flatnonzero(valid.ravel())
    p = X_world_camera[:3, 3] + depth.ravel()[flat, None] * dirs_world[flat]
    vec = p - eye2
    dist = np.linalg.norm(vec, axis=1)
    t_hit = caster.cast(np.broadcast_to(eye2, vec.shape).copy(), vec / dist[:, None])["t_hit"]
    shadow = np.zeros(depth.size, bool)
    shadow[flat] = t_hit < dist - np.maximum(0.001, 0.002 * dist)
    z = np.where(shadow.reshape(depth.shape), np.nan, z)
    z = _flying_pixels(depth, z, sensor.p_fly, rng)
    inc_deg = np.degrees(np.arccos(np.clip(cos_inc, 0.0, 1.0)))
    p_drop = np.clip((inc_deg - sensor.grazing_deg) / 15.0, 0.0, 1.0) + sensor.p_speckle
    glare = steel & (cos_inc**sensor.specular_exponent * (1.0 + 0.5 * _smooth_field(depth.shape, 6.0, rng)) > 0.6)
    z[valid & ((rng.random(z.shape) < p_drop) | glare)] = np.nan
    if sensor.median_px > 1:
        z = fb / _valid_median(fb / z, sensor.median_px)
    return z


def _valid_median(img: FloatArray, k: int) -> FloatArray:
    """Per valid (finite) pixel of ``img``, the median of the valid pixels in its ``k`` x ``k`` window (NaN
    elsewhere), a band of rows at a time (the (rows, W, k*k) stack of a whole 1280x720 image is 90 MB)."""
    r = k // 2
    pad = np.pad(img.astype(np.float32), r, mode="constant", constant_values=np.nan)
    H, W = img.shape
    out = np.full((H, W), np.nan)
    for y0 in range(0, H, 128):
        y1 = min(y0 + 128, H)
        stack = np.stack([pad[y0 + i : y1 + i, j : j + W] for i in range(k) for j in range(k)], axis=-1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a window with no valid pixel: NaN, and it is masked
            out[y0:y1] = np.nanmedian(stack, axis=-1)
    return np.where(np.isfinite(img), out, np.nan)


def _texture(p_world: FloatArray, part_index: NDArray, seed: int) -> FloatArray:
    """Brushed-metal value in about [-1, 1] from world position (streaks along each part's x)."""
    rng = np.random.default_rng(1234)
    out = np.zeros(len(p_world))
    for _ in range(4):
        k = rng.normal(size=3)
        k /= np.linalg.norm(k)
        k[0] *= 0.15  # stretched along x: streaks
        freq = rng.uniform(40.0, 400.0)
        out += np.sin(freq * (p_world @ k) + rng.uniform(0, 2 * np.pi) + 0.7 * part_index) / 4.0
    return out


def _color(
    scene: Scene,
    depth: FloatArray,
    part_idx: NDArray[np.int32],
    normals_world: FloatArray,
    dirs_world: FloatArray,
    eye: FloatArray,
    rng: np.random.Generator,
    noise: NoiseModel,
) -> NDArray[np.uint8]:
    H, W = depth.shape
    albedo = np.array([p.albedo_rgb for p in scene.parts] + [(0.08, 0.08, 0.09)])
    idx = np.where(part_idx >= 0, part_idx, len(scene.parts)).reshape(-1)
    n = np.nan_to_num(normals_world.reshape(-1, 3))
    d = dirs_world / np.linalg.norm(dirs_world, axis=1, keepdims=True)
    headlight = np.clip(-(n * d).sum(axis=1), 0.0, 1.0)
    key = np.array([0.35, -0.55, 0.76])
    key /= np.linalg.norm(key)
    keylight = np.clip(n @ key, 0.0, 1.0)
    shade = 0.18 + 0.45 * keylight + 0.40 * headlight
    p = eye + np.nan_to_num(depth.reshape(-1))[:, None] * dirs_world
    tex = 1.0 + 0.06 * _texture(p, idx, 0)
    rgb = albedo[idx] * (shade * tex)[:, None]
    rgb[idx == len(scene.parts)] = 0.06
    img = rgb.reshape(H, W, 3)
    if noise != "none":
        img = img + rng.normal(0.0, 2.0 / 255.0, img.shape)
    img = np.clip(img, 0.0, 1.0) ** (1 / 2.2)
    return (img * 255.0 + 0.5).astype(np.uint8)


@dataclass(frozen=True)
class GroundTruthRules:
    """When a seam sample counts as seen: its centre and points ``face_offset_m`` into both faces (at most
    half of each face's reach) are unoccluded and inside the image, both faces are seen at less than
    ``max_incidence_deg``, and the visible run is at least ``min_run_m`` long."""

    max_incidence_deg: float = MAX_INCIDENCE_DEG
    min_run_m: float = GT_MIN_RUN_M
    face_offset_m: float = GT_FACE_OFFSET_M


def _visible_runs(
    scene: Scene,
    caster: _Raycaster,
    X_world_camera: FloatArray,
    seam_index: int,
    rules: GroundTruthRules,
    also_from: tuple[FloatArray, ...] = (),
) -> list[tuple[FloatArray, FloatArray, FloatArray]]:
    """Sampled points of a seam that the camera sees, split into runs, with both face normals. The probes
    must also be unoccluded from each eye (world frame) in ``also_from``: a stereo sensor's second camera,
    without which there is no depth."""
    seam = scene.seams[seam_index]
    cam = scene.camera
    pts, da, db = seam.sample(GT_STEP_M)
    (pa, fa), (pb, fb) = seam.faces
    edge_a, edge_b = seam.edge_offsets(da, db)
    na = face_normal_at(scene.parts[pa], fa, pts + edge_a)
    nb = face_normal_at(scene.parts[pb], fb, pts + edge_b)
    eye = X_world_camera[:3, 3]
    X_camera_world = invert_X(X_world_camera)
    ok = np.ones(len(pts), bool)
    off_a = min(rules.face_offset_m, seam.reach_a_m / 2)
    off_b = min(rules.face_offset_m, seam.reach_b_m / 2)
    for probe in (pts, pts + edge_a + off_a * da, pts + edge_b + off_b * db):
        p_cam = transform_points(X_camera_world, probe)
        in_front = p_cam[:, 2] > 0.05
        uv = np.column_stack([cam.fx * p_cam[:, 0] / p_cam[:, 2] + cam.cx, cam.fy * p_cam[:, 1] / p_cam[:, 2] + cam.cy])
        margin = 4.0
        inside = (uv[:, 0] >= margin) & (uv[:, 0] <= cam.width - 1 - margin)
        inside &= (uv[:, 1] >= margin) & (uv[:, 1] <= cam.height - 1 - margin)
        ok &= in_front & inside
        for e in (eye, *also_from):
            vec = probe - e
            dist = np.linalg.norm(vec, axis=1)
            ok &= caster.cast(np.tile(e, (len(probe), 1)), vec / dist[:, None])["t_hit"] >= dist - 5e-4
    view = (pts - eye) / np.linalg.norm(pts - eye, axis=1, keepdims=True)
    cos_max = np.cos(np.radians(rules.max_incidence_deg))
    ok &= (-(na * view).sum(axis=1) > cos_max) & (-(nb * view).sum(axis=1) > cos_max)
    closed = seam.kind == "curved" and np.linalg.norm(seam.points[0] - seam.points[-1]) < 1e-9
    runs: list[tuple[int, int]] = []
    start = None
    for i, good in enumerate(ok):
        if good and start is None:
            start = i
        if not good and start is not None:
            runs.append((start, i))
            start = None
    if start is not None:
        runs.append((start, len(ok)))
    idx_runs = [np.arange(a, b) for a, b in runs]
    if closed and len(runs) >= 2 and runs[0][0] == 0 and runs[-1][1] == len(ok):
        idx_runs = [np.concatenate([idx_runs[-1][:-1], idx_runs[0]]), *idx_runs[1:-1]]
    out = []
    for ir in idx_runs:
        if len(ir) < 2 or (len(ir) - 1) * GT_STEP_M < rules.min_run_m - 1e-9:
            continue
        out.append((pts[ir], na[ir], nb[ir]))
    return out


def visible_ground_truth(
    scene: Scene,
    X_world_camera: FloatArray,
    *,
    rules: GroundTruthRules | None = None,
    caster: _Raycaster | None = None,
    sensor: StereoSensor | None = None,
) -> tuple[GroundTruthDetail, ...]:
    """The scene's seams clipped to what a camera at ``X_world_camera`` sees (``rules``), as visible runs. With
    a stereo ``sensor`` a seam must be seen by its second camera too: in its shadow there is no depth."""
    caster = caster or _Raycaster(scene)
    X_wc = np.asarray(X_world_camera, dtype=np.float64)
    X_cw = invert_X(X_wc)
    also = () if sensor is None else (second_eye(X_wc, sensor),)
    gts: list[GroundTruthDetail] = []
    for si, seam in enumerate(scene.seams):
        runs = _visible_runs(scene, caster, X_wc, si, rules or GroundTruthRules(), also)
        for k, (pts, na, nb) in enumerate(runs):
            if seam.kind == "linear":
                keep = np.array([0, len(pts) - 1])
            else:
                keep = np.unique(np.concatenate([np.arange(0, len(pts), 2), [len(pts) - 1]]))
            p_w = pts[keep]
            gts.append(
                GroundTruthDetail(
                    name=seam.name if len(runs) == 1 else f"{seam.name}#{k}",
                    kind=seam.kind,
                    points_world=p_w,
                    points_camera=transform_points(X_cw, p_w),
                    normal_a_camera=na[keep] @ X_cw[:3, :3].T,
                    normal_b_camera=nb[keep] @ X_cw[:3, :3].T,
                    faces=seam.faces,
                    joint=seam.joint,
                    seam_index=si,
                )
            )

    return tuple(gts)


def render(
    scene: Scene,
    *,
    noise: NoiseModel = "stereo",
    seed: int = 0,
    with_pose: bool = False,
    X_world_camera: FloatArray | None = None,
    rules: GroundTruthRules | None = None,
    sensor: StereoSensor | None = None,
) -> RenderResult:
    """Render ``scene`` from its camera (or ``X_world_camera``) with the given noise model.

    Deterministic for a given seed. The returned capture carries prompts and ground truth.
    """
    if noise not in NOISE_MODELS:
        raise ValueError(f"unknown noise model {noise!r}; choose one of {NOISE_MODELS}")
    rng = np.random.default_rng(seed)
    cam = scene.camera
    X_wc = scene.camera.X_world_camera if X_world_camera is None else np.asarray(X_world_camera, float)
    caster = _Raycaster(scene)
    depth, part_idx, face_idx, normals_w = _exact_depth(scene, caster, X_wc)
    _, dirs = _rays(scene, X_wc)
    dnorm = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    cos_inc = np.abs((np.nan_to_num(normals_w.reshape(-1, 3)) * dnorm).sum(axis=1)).reshape(depth.shape)
    if sensor is None:
        z = _noisy_depth(depth, cos_inc, noise, rng)
    else:
        steel = np.isin(part_idx, [k for k, p in enumerate(scene.parts) if p.workpiece])
        z = _stereo_depth(
            depth, cos_inc, sensor, rng, fx=cam.fx, caster=caster, X_world_camera=X_wc, dirs_world=dirs, steel=steel
        )
    color = _color(scene, depth, part_idx, normals_w, dirs, X_wc[:3, 3], rng, noise)

    # ground truth, clipped to what the camera sees
    X_cw = invert_X(X_wc)
    gts = list(visible_ground_truth(scene, X_wc, rules=rules, caster=caster, sensor=sensor))

    labels, surfaces, prompts = _face_prompts(scene, part_idx, face_idx, z)

    intr = CameraIntrinsics(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
    X_base_tool = X_tool_camera = None
    if with_pose:
        X_tool_camera = X_TOOL_CAMERA
        X_base_tool = X_BASE_WORLD @ X_wc @ invert_X(X_TOOL_CAMERA)
    capture = Capture(
        color_rgb=color,
        depth_m=z.astype(np.float32),
        intrinsics=intr,
        depth_scale=SIM_DEPTH_SCALE,
        X_base_tool=X_base_tool,
        X_tool_camera=X_tool_camera,
        prompts_px=np.array(prompts, dtype=np.float64).reshape(-1, 2),
        ground_truth=tuple(GroundTruthSeam(g.kind, g.points_camera, g.joint) for g in gts),
        source=f"sim:{scene.name}:{noise}:{seed}",
    )
    normals_cam = (normals_w.reshape(-1, 3) @ X_cw[:3, :3].T).reshape(normals_w.shape)
    return RenderResult(
        scene=scene,
        capture=capture,
        depth_true_m=depth,
        part_index=part_idx,
        face_index=face_idx,
        surface_labels=labels,
        surfaces=tuple(surfaces),
        normals_camera=normals_cam,
        X_world_camera=X_wc,
        ground_truth=tuple(gts),
    )


def _face_prompts(
    scene: Scene, part_idx: NDArray[np.int32], face_idx: NDArray[np.int32], z: FloatArray
) -> tuple[NDArray[np.int32], list[tuple[int, int]], list[tuple[float, float]]]:
    """One prompt per visible workpiece face, one pixel deep inside it (as an operator would click): the (H, W)
    surface labels (-1 elsewhere), the (part, face) of each label and the prompts' pixels (u, v)."""
    import cv2

    surfaces: list[tuple[int, int]] = []
    labels = np.full(part_idx.shape, -1, np.int32)
    prompts: list[tuple[float, float]] = []
    pairs = sorted({(int(p), int(f)) for p, f in zip(part_idx.ravel(), face_idx.ravel(), strict=True) if p >= 0})
    for p, f in pairs:
        if not scene.parts[p].workpiece:
            continue
        mask = (part_idx == p) & (face_idx == f)
        if mask.sum() < PROMPT_MIN_PIXELS:
            continue
        # the most interior pixel of the face, among those with depth: dropouts at grazing angles must not hide
        # a face whose seam is in the ground truth
        dist = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
        dist[~np.isfinite(z)] = 0.0
        if dist.max() < 2.0:
            continue
        v, u = np.unravel_index(int(np.argmax(dist)), dist.shape)
        labels[mask] = len(surfaces)
        surfaces.append((p, f))
        prompts.append((float(u), float(v)))
    return labels, surfaces, prompts
