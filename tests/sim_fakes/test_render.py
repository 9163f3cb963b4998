"""The simulator's ground truth is exact: rendered points lie on the true surfaces, seams on both faces,
and visibility clipping removes exactly what the camera cannot see."""

from __future__ import annotations

from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from perception.capture import load_capture, save_capture
from perception.evaluate import point_to_polyline_distance
from perception.transforms import invert_X, make_X, transform_points
from sim_fakes.render import RenderResult, face_normal_at, render
from sim_fakes.scenes import CYL_SIDE, SCENES, Part, Scene, get_scene, t_joint, with_resolution

REQUIRED = {"t_joint", "ribs", "lap_joint", "inside_corner", "open_box", "pipe_on_plate", "butt_joint"}


@cache
def clean(name: str) -> RenderResult:
    """The scene noise-free at 640x360: the exactness checks below (points on their surfaces to 1 um, seams on both
    faces, visibility clipping) hold at any resolution, and a quarter of the pixels renders four times faster."""
    return render(with_resolution(get_scene(name), 640, 360), noise="none", seed=0)


@cache
def clean_full(name: str) -> RenderResult:
    """The scene noise-free at its own 1280x720, for what depends on the pixel size (footprints, prompt areas)."""
    return render(get_scene(name), noise="none", seed=0)


def surface_distance(part: Part, face: int, p_world: np.ndarray) -> np.ndarray:
    """Exact distance of points to the (infinite) surface carrying ``face``."""
    q = transform_points(invert_X(part.X_world_part), p_world)
    if part.shape == "cylinder":
        r, _, h = part.size
        if face == CYL_SIDE:
            return np.abs(np.hypot(q[:, 0], q[:, 1]) - r)
        return np.abs(q[:, 2] - (0.0 if face == 1 else h))
    axis, sign = divmod(face, 2)
    half = part.size[axis] / 2
    return np.abs(q[:, axis] - (half if sign else -half))


def test_scene_list_has_the_required_scenes() -> None:
    assert set(SCENES) >= REQUIRED
    assert get_scene("pipe_on_plate").seams[0].kind == "curved"


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_noise_free_backprojection_lies_on_true_surfaces(name: str, tmp_path: Path) -> None:
    res = clean(name)
    # through the file format too: depth.npy (float32) read back by load_capture
    cap = load_capture(save_capture(res.capture, tmp_path / name, depth_format="npy"))
    p_cam = cap.points_camera().reshape(-1, 3).astype(np.float64)
    p_world = transform_points(res.X_world_camera, p_cam)
    part_idx = res.part_index.reshape(-1)
    face_idx = res.face_index.reshape(-1)
    worst = 0.0
    for k, part in enumerate(res.scene.parts):
        for f in np.unique(face_idx[part_idx == k]):
            sel = (part_idx == k) & (face_idx == f) & np.isfinite(p_cam[:, 2])
            d = surface_distance(part, int(f), p_world[sel])
            worst = max(worst, float(d.max()))
    assert worst < 1e-6, f"{name}: a rendered point is {worst * 1e6:.3f} um off its surface"


def test_pixel_centre_convention() -> None:
    """A seam end projected with OpenCV intrinsics lands on the pixel whose ray hits it (at the full 1280x720)."""
    res = clean_full("t_joint")
    cap = res.capture
    g = res.ground_truth[0]
    mid = g.points_camera.mean(axis=0)
    uv = cap.intrinsics.project(mid[None])[0]
    u, v = round(uv[0]), round(uv[1])
    p = cap.points_camera()[v, u].astype(float)
    # the pixel nearest the projection sees a point within one pixel footprint (~0.6 mm) of the seam
    assert np.linalg.norm(p - mid) < 0.0012


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_ground_truth_lies_on_both_faces(name: str) -> None:
    res = clean(name)
    assert res.ground_truth, f"{name} has no visible seam"
    for g in res.ground_truth:
        (pa, fa), (pb, fb) = g.faces
        seam = next(s for s in res.scene.seams if g.name.split("#")[0] == s.name)
        half_gap = seam.gap_m / 2
        # a fillet lies on both surfaces; a butt seam lies half a gap from each plate's edge, on their top
        da = surface_distance(res.scene.parts[pa], fa, g.points_world)
        db = surface_distance(res.scene.parts[pb], fb, g.points_world)
        assert da.max() < 1e-8 and db.max() < 1e-8, (name, g.name, da.max(), db.max())
        if half_gap:
            assert g.points_world[:, 0] == pytest.approx(0.0, abs=1e-12)
        # the saved camera-frame points are the world points seen from the camera
        assert np.allclose(transform_points(res.X_world_camera, g.points_camera), g.points_world, atol=1e-12)


def test_t_joint_far_fillet_is_clipped_away() -> None:
    res = clean("t_joint")
    names = [g.name for g in res.ground_truth]
    assert names == ["web-x"]  # the +x fillet is behind the web
    assert res.ground_truth[0].points_world[:, 1].tolist() == pytest.approx([-0.10, 0.10], abs=1e-12)


def test_ribs_shows_ten_linear_seams() -> None:
    res = clean("ribs")
    assert len(res.ground_truth) == 10
    assert {g.kind for g in res.ground_truth} == {"linear"}


def test_partial_occlusion_splits_the_seam() -> None:
    """A post standing between the camera and the middle of the T-joint's fillet hides that part only."""
    base = t_joint()
    eye = np.array(base.camera.eye)
    mid = np.array([-0.005, 0.0, 0.010])
    post_at = eye + 0.45 * (mid - eye)
    post = Part(
        "post",
        "box",
        (0.02, 0.02, 2 * post_at[2]),
        make_X(np.eye(3), [post_at[0], post_at[1], 0.0]),
        (0.5, 0.5, 0.5),
        workpiece=False,
    )
    scene = Scene("occluded", "", (*base.parts, post), base.seams, base.camera)
    res = render(scene, noise="none")
    visible = [g for g in res.ground_truth if g.name.startswith("web-x")]
    assert len(visible) == 2
    # the middle of the seam is no longer on any visible piece
    for g in visible:
        assert point_to_polyline_distance(mid[None], g.points_world)[0] > 0.005
    # every remaining sample is really seen: a ray to it hits nothing closer
    total = sum(np.linalg.norm(np.diff(g.points_world, axis=0), axis=1).sum() for g in visible)
    assert 0.05 < total < 0.19


def test_prompts_sit_on_their_surfaces() -> None:
    res = clean_full("ribs")  # a face needs PROMPT_MIN_PIXELS to be prompted: at 640x360 a bar's end face has not
    labels = res.surface_labels
    for k, (u, v) in enumerate(res.capture.prompts_px):
        assert labels[int(v), int(u)] == k
    # every face named by a visible seam is prompted
    needed = {f for g in res.ground_truth for f in g.faces}
    assert needed <= set(res.surfaces)


def test_render_is_deterministic_per_seed() -> None:
    s = with_resolution(get_scene("lap_joint"), 640, 360)  # determinism does not depend on the image size
    a = render(s, noise="stereo", seed=3).capture
    b = render(s, noise="stereo", seed=3).capture
    c = render(s, noise="stereo", seed=4).capture
    assert np.array_equal(a.depth_m, b.depth_m, equal_nan=True)
    assert np.array_equal(a.color_rgb, b.color_rgb)
    assert not np.array_equal(a.depth_m, c.depth_m, equal_nan=True)


def test_stereo_noise_matches_its_model() -> None:
    """On the lap joint's lower plate: sigma = 0.5 mm (z/0.5)^2 / max(cos, 0.25), checked to 10%."""
    res = render(get_scene("lap_joint"), noise="stereo", seed=1)
    z = res.capture.depth_m.astype(float)
    zt = res.depth_true_m
    sel = (res.part_index == 1) & (res.face_index == 5) & np.isfinite(z)
    n = res.normals_camera[sel]
    p = res.capture.points_camera()[sel].astype(float)
    cos = np.abs((n * p).sum(axis=1) / np.linalg.norm(p, axis=1))
    sigma = 0.0005 * (zt[sel] / 0.5) ** 2 / np.maximum(cos, 0.25)
    r = (z[sel] - zt[sel]) / sigma
    inliers = np.abs(r) < 6  # flying pixels at the plate's outline are not Gaussian noise
    assert np.std(r[inliers]) == pytest.approx(1.0, rel=0.1)
    assert abs(np.mean(r[inliers])) < 0.05


def test_structured_noise_is_smaller_than_stereo() -> None:
    s = get_scene("butt_joint")
    res_s = render(s, noise="stereo", seed=2)
    res_l = render(s, noise="structured", seed=2)
    sel = res_s.part_index == 1
    err_s = np.nanstd((res_s.capture.depth_m - res_s.depth_true_m)[sel])
    err_l = np.nanstd((res_l.capture.depth_m - res_l.depth_true_m)[sel])
    assert err_l < err_s / 3


def test_dropouts_at_grazing_angles() -> None:
    """Stereo dropouts: probability (incidence - 70 deg) / 15 deg, plus 0.2 % speckle."""
    res = render(get_scene("ribs"), noise="stereo", seed=0)
    cam = res.scene.camera
    u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    ok = np.isfinite(res.depth_true_m)
    inc = np.degrees(np.arccos(np.clip(np.abs((np.nan_to_num(res.normals_camera) * rays).sum(-1)), 0, 1)))
    dropped = ~np.isfinite(res.capture.depth_m) & ok
    grazing = ok & (inc >= 80) & (inc < 84)
    frontal = ok & (inc < 45)
    assert grazing.sum() > 1000 and frontal.sum() > 100_000
    expected = np.mean(np.clip((inc[grazing] - 70) / 15, 0, 1)) + 0.002
    assert dropped[grazing].mean() == pytest.approx(expected, abs=0.03)
    assert dropped[frontal].mean() == pytest.approx(0.002, abs=0.001)


def test_face_normals_are_outward() -> None:
    s = get_scene("pipe_on_plate")
    pipe = s.parts[2]
    n = face_normal_at(pipe, CYL_SIDE, np.array([[0.04, 0.0, 0.05], [0.0, -0.04, 0.05]]))
    assert np.allclose(n, [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], atol=1e-12)


def test_resolution_override_keeps_geometry() -> None:
    s = get_scene("t_joint")
    small = replace(s, camera=replace(s.camera, width=640, height=360, fx=460.0, fy=460.0))
    res = render(small, noise="none")
    assert res.capture.shape == (360, 640)
    assert len(res.ground_truth) == 1
