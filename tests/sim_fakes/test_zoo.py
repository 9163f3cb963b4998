"""The weldment zoo: exact truth on noise-free renders, the clipping rules on constructed cases, the sensor
model's shadows, quantisation and noise, determinism and splits."""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np
import pytest

from perception.capture import JOINT_TYPES
from perception.evaluate import point_to_polyline_distance
from perception.transforms import invert_X, look_at_X, make_X, transform_points
from sim_fakes.hull import box_corners
from sim_fakes.render import GT_STEP_M, StereoSensor, render, second_eye, visible_ground_truth
from sim_fakes.scenes import CYL_SIDE, CameraSetup, Part, Scene
from sim_fakes.zoo import ALL_FAMILIES, FAMILIES, HELD_OUT, SPLIT_BASE, ZOO_RULES, draw_capture, draw_scene, split_plan

from .test_contacts import hull_part

TABLE = Part("table", "box", (2.0, 2.0, 0.04), make_X(np.eye(3), [0.0, 0.0, -0.02]), (0.2, 0.2, 0.2), workpiece=False)


def surface_distance(part: Part, face: int, p_world: np.ndarray) -> np.ndarray:
    """Exact distance of points to the (infinite) surface carrying ``face``."""
    if part.hull_world is not None:
        f = part.hull_world.faces[face]
        return np.abs(p_world @ f.normal + f.offset)
    q = transform_points(invert_X(part.X_world_part), p_world)
    if part.shape == "box":
        axis, sign = divmod(face, 2)
        return np.abs(q[:, axis] - (1 if sign else -1) * part.size[axis] / 2)
    r, _, h = part.size
    if face == CYL_SIDE:
        return np.abs(np.hypot(q[:, 0], q[:, 1]) - r)
    return np.abs(q[:, 2] - (0.0 if face == 1 else h))


@cache
def clean(family: str):
    return draw_capture(family, 0, width=640, height=360, noise_free=True)


@pytest.mark.parametrize("family", sorted(ALL_FAMILIES))
def test_every_seam_lies_on_both_of_its_faces(family: str) -> None:
    scene, _, _ = draw_scene(family, 0)
    assert scene.seams, f"{family}: no seam drawn"
    for s in scene.seams:
        # curved seams: their own vertices (a resampled chord would sag 1 um on a 15 mm pipe)
        pts, da, db = s.sample(0.002) if s.kind == "linear" else (s.points, s.into_a, s.into_b)
        (pa, fa), (pb, fb) = s.faces
        # a gap seam lies half the gap beside each face's edge, along the face
        edge_a, edge_b = s.edge_offsets(da, db)
        on_a = surface_distance(scene.parts[pa], fa, pts + edge_a)
        on_b = surface_distance(scene.parts[pb], fb, pts + edge_b)
        assert on_a.max() < 1e-6 and on_b.max() < 1e-6, f"{family} {s.name}: {on_a.max()}, {on_b.max()}"
        assert s.joint in JOINT_TYPES


@pytest.mark.parametrize("family", sorted(ALL_FAMILIES))
def test_noise_free_zoo_renders_are_exact_and_their_truth_lies_on_the_seams(family: str) -> None:
    z = clean(family)
    res = z.result
    assert res.ground_truth, f"{family}: the drawn view sees no seam"
    p_cam = res.capture.points_camera().reshape(-1, 3).astype(np.float64)
    ok = np.isfinite(p_cam[:, 2])
    p_world = transform_points(res.X_world_camera, p_cam[ok])
    part_idx, face_idx = res.part_index.reshape(-1)[ok], res.face_index.reshape(-1)[ok]
    for k, part in enumerate(res.scene.parts):
        for f in np.unique(face_idx[part_idx == k]):
            sel = (part_idx == k) & (face_idx == f)
            # float32 depth at up to ~1 m: 0.06 um per count of the mantissa
            assert surface_distance(part, int(f), p_world[sel]).max() < 1e-6, (family, part.name, f)
    for g in res.ground_truth:
        seam = res.scene.seams[g.seam_index]
        assert point_to_polyline_distance(g.points_world, seam.points).max() < 1e-9
        np.testing.assert_allclose(g.points_camera, transform_points(invert_X(res.X_world_camera), g.points_world),
                                   atol=1e-12)  # fmt: skip
        assert g.joint == seam.joint
        length = float(np.linalg.norm(np.diff(g.points_world, axis=0), axis=1).sum())
        assert length >= ZOO_RULES.min_run_m - 1e-9


def tee_scene(web_length: float, eye, target=(0.0, 0.0, 0.0)) -> Scene:
    base = hull_part("base", box_corners(0.3, 0.3, 0.01))
    web = hull_part("web", box_corners(0.006, web_length, 0.08), z=0.01)
    from sim_fakes.contacts import fold_seams

    parts = (TABLE, base, web)
    seams = tuple(replace(s, faces=((s.faces[0][0] + 1, s.faces[0][1]), (s.faces[1][0] + 1, s.faces[1][1])))
                  for s in fold_seams(parts[1:]))  # fmt: skip
    return Scene("tee", "", parts, seams, CameraSetup(eye=eye, target=target, width=640, height=360, fx=460, fy=460))


def test_the_far_fillet_is_hidden_and_short_end_fillets_are_dropped() -> None:
    scene = tee_scene(0.2, eye=(-0.35, -0.05, 0.30))
    gts = visible_ground_truth(scene, scene.camera.X_world_camera, rules=ZOO_RULES)
    # the -x fillet, whole; the +x one is behind the web; the 6 mm end fillets are under 20 mm
    assert len(gts) == 1
    np.testing.assert_allclose(sorted(gts[0].points_world[:, 1]), [-0.1, 0.1], atol=GT_STEP_M + 1e-9)
    np.testing.assert_allclose(gts[0].points_world[:, 0], -0.003, atol=1e-12)


@pytest.mark.parametrize(("length", "seen"), [(0.018, False), (0.022, True)])
def test_a_run_shorter_than_20_mm_is_not_a_seam(length: float, seen: bool) -> None:
    scene = tee_scene(length, eye=(-0.35, -0.02, 0.30))
    gts = visible_ground_truth(scene, scene.camera.X_world_camera, rules=ZOO_RULES)
    assert (len(gts) == 1) is seen


def test_samples_seen_at_more_than_75_degrees_are_clipped_where_the_geometry_says() -> None:
    # a low camera far off the web's end: the base's top is seen ever more obliquely along the fillet
    eye = np.array([-0.25, -0.45, 0.14])
    scene = tee_scene(0.28, eye=tuple(eye), target=(0.0, 0.05, 0.0))
    (gt,) = visible_ground_truth(scene, scene.camera.X_world_camera, rules=ZOO_RULES)
    y = np.linspace(-0.14, 0.14, 28001)
    p = np.column_stack([np.full_like(y, -0.003), y, np.full_like(y, 0.01)])
    v = (eye - p) / np.linalg.norm(eye - p, axis=1, keepdims=True)
    cos75 = np.cos(np.radians(75.0))
    ok = (v[:, 2] > cos75) & (-v[:, 0] > cos75)  # base top (+z) and web face (-x)
    assert ok.any() and not ok.all()
    expected = y[ok]
    np.testing.assert_allclose(sorted(gt.points_world[:, 1]), [expected.min(), expected.max()], atol=GT_STEP_M + 1e-6)


def test_a_fillet_in_the_second_cameras_shadow_is_not_truth() -> None:
    # the camera sees the web's -x fillet whole; with a 0.2 m baseline its second camera stands beyond the
    # web's plane (x > 0.003) and the web hides the fillet from it: there is no depth there
    scene = tee_scene(0.2, eye=(-0.15, -0.35, 0.30))
    X_wc = scene.camera.X_world_camera
    whole = [[-0.003, 0.1, 0.01], [-0.003, -0.1, 0.01]]
    for sensor in (None, StereoSensor()):
        (gt,) = visible_ground_truth(scene, X_wc, rules=ZOO_RULES, sensor=sensor)
        np.testing.assert_allclose(gt.points_world, whole, atol=1e-12)
    wide = StereoSensor(baseline_m=0.2)
    assert second_eye(X_wc, wide)[0] > 0.003
    assert visible_ground_truth(scene, X_wc, rules=ZOO_RULES, sensor=wide) == ()


def block_scene(sensor_eye_height: float = 0.5) -> tuple[Scene, np.ndarray]:
    block = hull_part("block", box_corners(0.1, 0.1, 0.1))
    cam = CameraSetup(eye=(0.0, 0.0, sensor_eye_height), target=(0, 0, 0), width=640, height=360, fx=460, fy=460,
                      up=(0, 1, 0))  # fmt: skip
    scene = Scene("block", "", (TABLE, block), (), cam)
    return scene, look_at_X(scene.camera.eye, scene.camera.target, (0, 1, 0))


QUIET = StereoSensor(p_fly=0.0, p_speckle=0.0, grazing_deg=90.0, specular_exponent=1e9)


def test_stereo_shadows_fall_exactly_where_the_second_camera_cannot_see() -> None:
    scene, X_wc = block_scene()
    assert np.allclose(X_wc[:3, 0], [1, 0, 0])  # the second camera sits at +x
    res = render(scene, noise="stereo", seed=1, sensor=QUIET)
    z, zt = res.capture.depth_m, res.depth_true_m
    p = transform_points(X_wc, _true_points(res))
    floor = (res.part_index.reshape(-1) == 0) & np.isfinite(zt.reshape(-1))
    holes = floor & ~np.isfinite(z.reshape(-1))
    B, H, h, x0 = QUIET.baseline_m, 0.5, 0.1, -0.05
    x_shadow = (x0 - B * h / H) / (1 - h / H)  # where the ray from the second camera clears the block's edge
    px = 0.5 / 460 * 1.5  # a pixel and a half on the floor
    assert holes.sum() > 500
    xs, ys = p[holes, 0], p[holes, 1]
    assert xs.min() >= x_shadow - px and xs.max() <= x0 + px and np.abs(ys).max() <= 0.05 * H / (H - h) + px
    band = floor & (p[:, 0] > x_shadow + px) & (p[:, 0] < x0 / (1 - h / H) - px) & (np.abs(p[:, 1]) < 0.04)
    assert band.sum() > 200 and holes[band].all()
    # nothing else lost: the block's top and the rest of the floor have depth
    assert np.isfinite(z.reshape(-1)[(res.part_index.reshape(-1) == 1)]).all()


def _true_points(res) -> np.ndarray:
    from perception.capture import backproject

    return backproject(res.depth_true_m.astype(np.float32), res.capture.intrinsics).reshape(-1, 3).astype(np.float64)


def test_stereo_depth_is_quantised_in_disparity_with_the_modelled_noise() -> None:
    scene, _ = block_scene()
    res = render(scene, noise="stereo", seed=2, sensor=QUIET)
    z, zt = res.capture.depth_m.astype(np.float64), res.depth_true_m
    top = (res.part_index == 1) & np.isfinite(z)
    fb = 460.0 * QUIET.baseline_m
    steps = fb / z[top] * QUIET.subpixel
    assert np.abs(steps - np.round(steps)).max() < 2e-3
    # the block's top at 0.4 m, seen head-on: sigma_z = z^2 / (f B) * sqrt(white^2 + correlated^2 + step^2 / 12)
    sigma_px = np.sqrt(QUIET.sigma_px**2 + QUIET.sigma_corr_px**2 + (1 / QUIET.subpixel) ** 2 / 12)
    expected = 0.4**2 / fb * sigma_px
    measured = float(np.std(z[top] - zt[top]))
    assert measured == pytest.approx(expected, rel=0.15)
    assert abs(float(np.mean(z[top] - zt[top]))) < 0.2 * expected


def test_a_draw_is_deterministic_and_the_splits_do_not_overlap() -> None:
    a = draw_capture("tee", 3, width=320, height=180)
    b = draw_capture("tee", 3, width=320, height=180)
    c = draw_capture("tee", 4, width=320, height=180)
    np.testing.assert_array_equal(a.result.capture.depth_m, b.result.capture.depth_m)
    assert not np.array_equal(np.isfinite(a.result.capture.depth_m), np.isfinite(c.result.capture.depth_m))
    dev, test = split_plan("dev", 200), split_plan("test", 200)
    assert not {s for _, s in dev} & {s for _, s in test}
    assert min(s for _, s in test) == SPLIT_BASE["test"] and max(s for _, s in dev) < SPLIT_BASE["test"]
    counts = {f: sum(1 for g, _ in test if g == f) for f in FAMILIES}
    assert max(counts.values()) - min(counts.values()) <= 1
    first = split_plan("test", 24, ["pipe", "butt"])[:3]
    assert first == [("pipe", 1_000_000), ("butt", 1_000_000), ("pipe", 1_000_001)]
    # the held-out families are drawn only when named: the default splits are the twelve tuned on
    assert not {f for f, _ in dev + test} & set(HELD_OUT)
    assert split_plan("test", 3, list(HELD_OUT)) == [(f, 1_000_000) for f in HELD_OUT]


def test_the_held_out_families_are_what_they_say() -> None:
    # a box section: four walls standing on the base, each touching two others
    scene, _, _ = draw_scene("box_section", 0)
    walls = [p for p in scene.parts if p.name.startswith("wall")]
    assert len(walls) == 4
    # where two walls meet, an inside corner; where a wall meets the base, a fillet (as in an open box)
    for s in scene.seams:
        names = {scene.parts[s.faces[0][0]].name, scene.parts[s.faces[1][0]].name}
        assert s.joint == ("fillet" if "base" in names else "inside_corner"), (s.name, s.joint)
    # a cruciform: a rib and the two halves of the rib crossing it, all on the base, each half butted to the rib
    scene, _, _ = draw_scene("cruciform", 0)
    assert [p.name for p in scene.parts if p.workpiece] == ["base", "rib", "cross1", "cross-1"]
    assert {s.joint for s in scene.seams if "base" not in s.name} == {"inside_corner"}
    # a leaning web: its two folds with the base are acute and obtuse, summing to 180 degrees
    for seed in range(4):
        scene, _, _ = draw_scene("leaning_web", seed)
        feet = [s for s in scene.seams if {scene.parts[s.faces[0][0]].name, scene.parts[s.faces[1][0]].name}
                == {"base", "web"}]  # fmt: skip
        assert len(feet) == 4  # its two sides' and its two ends'
        feet = sorted(feet, key=lambda s: -float(np.linalg.norm(s.points[-1] - s.points[0])))[:2]  # the sides'
        angles = sorted(float(np.degrees(np.arccos(-s.into_a[0] @ s.into_b[0]))) for s in feet)
        assert angles[0] + angles[1] == pytest.approx(180.0, abs=1e-6)
        assert 50.0 - 1e-6 <= angles[0] <= 90.0 + 1e-6


def test_the_median_post_filter_takes_the_median_of_the_valid_pixels_around_each_valid_one() -> None:
    from sim_fakes.render import _valid_median

    # a disparity valley (a concave corner, farther than its faces) along column 10: |x - 10|; each side of it
    # a plane, which a median leaves as it is; an invalid pixel stays invalid and is left out of its
    # neighbours' windows
    x = np.arange(21, dtype=np.float64)
    img = np.tile(np.abs(x - 10.0), (7, 1))
    img[3, 4] = np.nan
    out = _valid_median(img, 3)
    assert np.isnan(out[3, 4]) and np.isfinite(out[np.isfinite(img)]).all()
    # the valley's bottom rises: the 3x3 window holds three 0s and six 1s
    np.testing.assert_allclose(out[1:6, 10], 1.0, atol=1e-6)
    np.testing.assert_allclose(out[1:6, 12:20], img[1:6, 12:20], atol=1e-5)
    # the pixel beside the invalid one: the median of its 8 valid neighbours' values and its own
    win = img[2:5, 4:7].ravel()
    assert out[3, 5] == pytest.approx(float(np.median(win[np.isfinite(win)])), abs=1e-5)


def test_a_sensor_override_renders_the_same_weldment_and_view_with_that_sensor() -> None:
    a = draw_capture("tee", 3, width=320, height=180)
    b = draw_capture("tee", 3, width=320, height=180, sensor="oakd_median")
    assert b.sensor == "oakd_median" and a.sensor != b.sensor
    np.testing.assert_array_equal(a.result.X_world_camera, b.result.X_world_camera)
    assert [g.name for g in a.result.ground_truth] == [g.name for g in b.result.ground_truth]
    for ga, gb in zip(a.result.ground_truth, b.result.ground_truth, strict=True):
        np.testing.assert_array_equal(ga.points_camera, gb.points_camera)
    assert not np.array_equal(a.result.capture.depth_m, b.result.capture.depth_m, equal_nan=True)
    with pytest.raises(KeyError, match="unknown zoo sensor"):
        draw_capture("tee", 3, width=320, height=180, sensor="kinect")
