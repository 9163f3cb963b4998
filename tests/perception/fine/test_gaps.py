"""Butt gaps: the centre line of a narrow gap between two plates, at their top surface, with its width."""

from __future__ import annotations

import numpy as np
import pytest

from perception.evaluate import point_to_polyline_distance
from perception.fine.adjacency import adjacent_pairs
from perception.fine.gaps import dark_line, dark_response, gap_seams, inner_gap_seams
from perception.fine.support import find_support

from .scenes import rendered, work


def _gaps(name: str, noise: str, seed: int = 0) -> tuple:
    """The render and the butt seams of both gap steps, as the pipeline runs them (the gap splits the plates
    into two surfaces at the work resolution, or not)."""
    res = rendered(name, noise, seed)
    p, _, nm, surf = work(name, noise, seed)
    sup = find_support(p, surf, nm)
    seams = gap_seams(p, surf, adjacent_pairs(surf, nm), nm, support=sup)
    seams += inner_gap_seams(res.capture.points_camera(), res.capture.intrinsics, surf, nm, support=sup)
    return res, seams


@pytest.mark.parametrize("noise", ["none", "stereo"])
def test_a_2_mm_butt_gap_is_found_on_its_centre_line(noise: str) -> None:
    res, seams = _gaps("butt", noise)
    (gt,) = res.ground_truth
    near = [s for s in seams if np.median(point_to_polyline_distance(s.points, gt.points_camera)) < 0.003]
    assert len(near) == 1 and len(seams) == 1
    s = near[0]
    samples = s.points[0] + np.linspace(0, 1, 50)[:, None] * (s.points[1] - s.points[0])
    err = point_to_polyline_distance(samples, gt.points_camera)
    assert np.median(err) < 2e-4
    # the ends where both plates' facing points are, not where the 2 mm bins round them out to (0.3 and 0.9 mm
    # past the plates' ends before)
    assert err.max() < (1.5e-4 if noise == "none" else 3e-4)
    assert s.gap_m == pytest.approx(0.002, abs=0.001)
    assert s.joint == "butt"


@pytest.mark.parametrize("seed", [0, 1])
def test_a_gap_seen_obliquely_is_centred_between_the_plates_edges_not_on_the_face_it_shows(seed: int) -> None:
    """Seen 41 degrees across the gap, the far plate's edge face shows in it; the rays that meet the face
    near the top pass for the plate and the deeper ones cross the top's plane short of the edge, so both
    counts put that edge inside the gap (by about 2 sigma tan 41 degrees). The face's own points place it."""
    res, seams = _gaps("butt_oblique", "stereo", seed)
    (gt,) = res.ground_truth
    (s,) = seams
    samples = s.points[0] + np.linspace(0, 1, 50)[:, None] * (s.points[1] - s.points[0])
    assert np.median(point_to_polyline_distance(samples, gt.points_camera)) < 1e-4
    assert s.gap_m == pytest.approx(0.0015, abs=3e-4)


def test_a_gap_narrower_than_a_pixel_is_found_in_the_rows_that_see_it() -> None:
    """0.6 mm between the plates, seen from 0.42 m where the pixels lie 0.9 mm apart: a row of pixels sees into
    the gap where its centre falls in it, the plates fill the rest of the strip. The plates beside it hold
    (almost) no holes, so the line of holes is the gap."""
    assert work("butt_fine", "stereo")[2].spacing_m(0.42) > 0.0006 / 0.7  # the gap is narrower than a pixel
    res, seams = _gaps("butt_fine", "stereo")
    (gt,) = res.ground_truth
    (s,) = seams
    samples = s.points[0] + np.linspace(0, 1, 50)[:, None] * (s.points[1] - s.points[0])
    assert np.median(point_to_polyline_distance(samples, gt.points_camera)) < 2e-4
    assert point_to_polyline_distance(s.points, gt.points_camera).max() < 5e-4


def test_a_line_of_holes_in_a_band_of_dropouts_is_not_a_gap() -> None:
    """A band 12 mm wide across the plate with 35% of its pixels dropped, 80% along a line in its middle: the
    line stands out from the band by a little over twice, from a gap's plates by a hundred times."""
    res = rendered("butt_fine", "stereo")
    p, _, nm, surf = work("butt_fine", "stereo")
    full = res.capture.points_camera().copy()
    (gt,) = res.ground_truth
    a, b = gt.points_camera[0], gt.points_camera[-1]
    u = (b - a) / np.linalg.norm(b - a)
    n = surf.surfaces[0].normal
    across = np.cross(n, u)
    # the band 20 mm to the side of the gap, on the right plate
    off = (full - (a + 0.02 * across)) @ across
    rng = np.random.default_rng(3)
    drop = (np.abs(off) < 0.006) & (rng.random(off.shape) < 0.35)
    drop |= (np.abs(off) < 0.0005) & (rng.random(off.shape) < 0.8)
    full[drop] = np.nan
    seams = inner_gap_seams(full, res.capture.intrinsics, surf, nm, support=find_support(p, surf, nm))
    assert all(np.median(point_to_polyline_distance(s.points, gt.points_camera)) < 0.003 for s in seams)


@pytest.mark.parametrize(("length_m", "found"), [(0.036, False), (0.10, True)])
def test_a_line_of_holes_in_one_plate_is_a_gap_narrower_than_a_pixel_only_when_it_is_long(
    length_m: float, found: bool
) -> None:
    """30% of the pixels dropped along a line 60 mm into the butt's left plate, the plate whole on both sides:
    over 100 mm that is a gap a pixel's centre falls into in some rows; over 36 mm (a scanner's seam, a
    scratch) its few holes are not taken for one."""
    from perception.transforms import invert_X, transform_points

    res = rendered("butt", "stereo")
    p, _, nm, surf = work("butt", "stereo")
    full = res.capture.points_camera().copy()
    world = transform_points(res.X_world_camera, full.reshape(-1, 3)).reshape(full.shape)
    line = (np.abs(world[..., 2] - 0.008) < 0.001) & (np.abs(world[..., 0] + 0.06) < 0.0006)
    line &= np.abs(world[..., 1]) < length_m / 2
    full[line & (np.random.default_rng(1).random(line.shape) < 0.3)] = np.nan
    seams = inner_gap_seams(full, res.capture.intrinsics, surf, nm, support=find_support(p, surf, nm))
    ends = transform_points(invert_X(res.X_world_camera), np.array([[-0.06, -length_m / 2, 0.008],
                                                                    [-0.06, length_m / 2, 0.008]]))  # fmt: skip
    if not found:
        assert seams == []
        return
    (s,) = seams
    assert np.median(point_to_polyline_distance(s.points, ends)) < 5e-4


def test_a_wall_standing_between_two_stretches_of_one_floor_is_not_a_butt_gap() -> None:
    """From above, the floor on both sides of a 2-4 mm wall is one plane in two pieces, a few millimetres apart:
    the strip between them holds the wall's top, 40 mm in front of the floor. A gap is empty. (Exact depth: the
    stereo shadow beside the wall parts the two pieces further than a gap's width.)"""
    p, _, nm, surf = work("wall", "none")
    assert sum(abs(s.offset - 0.438) < 0.002 for s in surf.surfaces) == 2  # the floor in two pieces
    sup = find_support(p, surf, nm)
    assert gap_seams(p, surf, adjacent_pairs(surf, nm), nm, support=sup) == []


def test_a_plate_without_a_gap_gives_none() -> None:
    res = rendered("tee", "stereo")
    p, _, nm, surf = work("tee", "stereo")
    assert inner_gap_seams(res.capture.points_camera(), res.capture.intrinsics, surf, nm,
                           support=find_support(p, surf, nm)) == []  # fmt: skip


def test_rows_of_dropouts_on_the_bars_end_faces_seen_from_above_are_not_butt_gaps() -> None:
    """The sim FANUC cell's camera at home looks straight down on the ribs scene: the bars' end faces stand at
    73-74 degrees to its rays, and on stereo frame 7 a row of dropouts runs along each. Found as "gaps" 1.1 mm
    wide, where the samples across the face lie 1.4-1.7 mm apart, they were butt seams with the torch 90
    degrees from straight down (the planner refused the job). A gap narrower than the spacing across it is not
    measured; the four fillets stay, the torch within the planner's limit on each."""
    from scipy.spatial.transform import Rotation

    from perception.detect import DetectParams
    from perception.detect_surfaces import detect_surfaces
    from perception.transforms import make_X
    from sim_fakes.fake_camera import FakeCamera

    X_base_tool = make_X(Rotation.from_euler("xyz", [180.0, 0.0, 0.0], degrees=True).as_matrix(), [0.5, 0.0, 0.4])
    X_base_world = np.array([[0.0, -1.0, 0.0, 0.62], [1.0, 0.0, 0.0, 0.04], [0.0, 0.0, 1.0, 0.015], [0, 0, 0, 1.0]])
    cam = FakeCamera("ribs", robot_pose=lambda: X_base_tool, resolution=(640, 360), noise="stereo", seed=7,
                     X_base_world=X_base_world)  # fmt: skip
    cam.connect()
    cap = cam.capture()
    result = detect_surfaces(cap, DetectParams(method="surfaces"))
    assert [s.joint for s in result.seams] == ["fillet"] * 4
    # and the planner's torch limit (60 degrees from straight down in the robot's base frame) holds for each
    R_base_camera = (X_base_world @ cam.X_world_camera())[:3, :3]
    for seam in result.seams:
        torch_z_base = seam.poses[:, :3, 2] @ R_base_camera.T
        assert np.degrees(np.arccos(-torch_z_base[:, 2])).max() < 60.0


def test_a_butt_over_a_v_grooves_root_is_its_opening_and_one_beside_it_is_not() -> None:
    from perception.fine.gaps import over_groove
    from perception.fine.types import SeamCurve

    up = np.tile([0.0, 0.0, -1.0], (2, 1))  # the plates' normal, towards the camera
    bevel_a, bevel_b = np.tile([0.7, 0.0, -0.7], (2, 1)), np.tile([-0.7, 0.0, -0.7], (2, 1))
    root = SeamCurve("linear", "v_groove", np.array([[-0.1, 0.0, 0.508], [0.1, 0.0, 0.508]]), bevel_a, bevel_b,
                     (1, 2), 100, 1e-4)  # fmt: skip

    def butt(y0: float, y1: float, x0: float = -0.08, x1: float = 0.08) -> SeamCurve:
        pts = np.array([[x0, y0, 0.5], [x1, y1, 0.5]])  # on the tops, 8 mm above the root
        return SeamCurve("linear", "butt", pts, up, up, (3, 4), 100, 1e-4, gap_m=0.004)

    assert over_groove(butt(0.001, 0.001), [root])  # across: 1 mm from the root's line, seen along the normal
    assert over_groove(butt(0.0049, 0.0049), [root])  # 4.9 mm: within half the 4 mm gap plus 3 mm
    assert not over_groove(butt(0.0051, 0.0051), [root])
    assert not over_groove(butt(0.0, 0.0, 0.12, 0.3), [root])  # past the groove's end
    assert not over_groove(butt(-0.08, 0.08, 0.0, 0.0), [root])  # across the groove
    assert not over_groove(butt(0.001, 0.001), [])


def test_a_gap_the_depth_does_not_resolve_is_found_by_its_line_of_shadow_in_the_image() -> None:
    """0.8 mm between the plates seen from 0.67 m, where the pixels lie 1.5 mm apart and the stereo noise
    fills the gap's few deeper pixels: the depth alone holds no line of holes. The colour image shows the gap
    as a line of shadow, darker than the plate on both sides of it."""
    res = rendered("butt_far", "stereo")
    p, _, nm, surf = work("butt_far", "stereo")
    sup = find_support(p, surf, nm)
    full, intr = res.capture.points_camera(), res.capture.intrinsics
    assert inner_gap_seams(full, intr, surf, nm, support=sup) == []
    (s,) = inner_gap_seams(full, intr, surf, nm, support=sup, color_rgb=res.capture.color_rgb)
    (gt,) = res.ground_truth
    samples = s.points[0] + np.linspace(0, 1, 50)[:, None] * (s.points[1] - s.points[0])
    assert np.median(point_to_polyline_distance(samples, gt.points_camera)) < 2e-4
    assert point_to_polyline_distance(s.points, gt.points_camera).max() < 5e-4
    assert s.gap_m == pytest.approx(0.0008, abs=4e-4)


def test_a_dark_line_is_darker_than_both_sides_and_a_colour_edge_is_not_one() -> None:
    """A plate with noise of 2 grey levels, one half darker by 40 (another plate's colour), and a line one pixel
    wide 30 levels darker than its side of the plate: the line is taken, the edge between the halves is not."""
    rng = np.random.default_rng(0)
    img = 150.0 + rng.normal(0.0, 2.0, (60, 80))
    img[:, 40:] -= 40.0  # the colour edge at column 40
    img[30, 5:35] -= 30.0  # the line along row 30, in the brighter half
    rgb = np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    mask = np.ones((60, 80), dtype=bool)
    found = dark_line(dark_response(rgb), mask)
    assert found[30, 7:33].all()
    assert found.sum() - found[30].sum() <= 3  # off the line: a pixel or two of noise at most
    assert not found[:, 38:42].any()
    assert not dark_line(dark_response(rgb), np.zeros((60, 80), dtype=bool)).any()


@pytest.mark.parametrize("seed", [35, 66])
def test_the_far_plates_rim_pixels_pulled_deep_are_not_taken_for_the_face_seen_in_the_gap(seed: int) -> None:
    """Zoo dev butt 35 and 66: a 0.7 mm gap seen 18 and 31 degrees across it from 0.5-0.8 m. The far plate's
    rim pixels, their depth mixed with what the gap shows, stand 3-4 sigma behind the top along their own
    rays, 1 mm on the near side of the gap; they were taken for the near plate's edge face, and the seam moved
    0.47 and 0.41 mm off the gap's centre. Their rays cross the top on the far plate, not in the gap: the
    plates' own edges place the seam. Since the far edge is fitted to the rays' ranges
    (perception.fine.gap_profile) these two are 0.08 and 0.09 mm off across, 0.20 and 0.13 mm at most (with
    the face's deepest points 0.05 and 0.01 mm, but those put it 0.3-0.6 mm inside the far plate elsewhere)."""
    from perception.detect import DetectParams
    from perception.detect_surfaces import detect_surfaces
    from sim_fakes.zoo import draw_capture

    zc = draw_capture("butt", seed)
    (truth,) = [t.points_camera for t in zc.result.ground_truth]
    (seam,) = detect_surfaces(zc.result.capture, DetectParams(method="surfaces")).seams
    samples = seam.points[0] + np.linspace(0, 1, 50)[:, None] * (seam.points[1] - seam.points[0])
    err = point_to_polyline_distance(samples, truth)
    assert seam.joint == "butt" and float(err.max()) < 0.25e-3


def test_a_butt_gap_parts_two_plates_not_a_plate_and_a_sliver_of_it() -> None:
    # a plate on x < 48 mm and a gap to x = 50 mm, on a 1 mm grid; beyond it either a second plate 50 mm wide
    # or a sliver 1 mm wide on the same plane (valid pixels left inside a blob of specular holes, as on zoo
    # dev v_groove 170): the sliver does not reach far_m beyond its edge, the plate does
    from perception.fine.gaps import GapParams, _plates_reach

    x, y = np.meshgrid(np.arange(100) * 0.001, np.arange(60) * 0.001)
    p = np.stack([x, y, np.full_like(x, 0.5)], axis=-1)
    c, u, across = np.array([0.049, 0.03, 0.5]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    edges, span = (-0.001, 0.001), (-0.025, 0.025)
    lab = np.full(x.shape, -1, np.int32)
    lab[x < 0.0475] = 0
    plate = lab.copy()
    plate[x > 0.0505] = 1
    sliver = lab.copy()
    sliver[(x > 0.0505) & (x < 0.0515)] = 1
    assert _plates_reach(p, plate, (0, 1), c, u, across, edges, span, GapParams())
    assert not _plates_reach(p, sliver, (0, 1), c, u, across, edges, span, GapParams())


def test_no_butt_gap_between_a_plate_and_a_sliver_in_its_specular_holes() -> None:
    # zoo dev v_groove 170: the groove, and no 16 mm "butt" beside it between the plate and a 51-point sliver
    from perception.detect import DetectParams
    from perception.detect_surfaces import detect_surfaces
    from sim_fakes.zoo import draw_capture

    res = detect_surfaces(draw_capture("v_groove", 170).result.capture, DetectParams(method="surfaces"))
    assert [s.joint for s in res.seams] == ["v_groove"]


@pytest.mark.timeout(120)
def test_two_plates_segmented_apart_across_a_gap_under_a_work_sample_give_their_butt_seam() -> None:
    # zoo dev butt 80 (OAK-D-like at 0.31 m): the gap is a pixel or two wide at full resolution, under one
    # work-resolution sample; the two plates were segmented apart and the work-resolution strip between them
    # held plate points, so no seam. Looked in as one outline at full resolution, the gap is there
    from perception.detect import DetectParams
    from perception.detect_surfaces import detect_surfaces
    from sim_fakes.zoo import draw_capture

    cap = draw_capture("butt", 80).result.capture
    res = detect_surfaces(cap, DetectParams(method="surfaces"))
    (truth,) = cap.ground_truth
    (seam,) = res.seams
    assert seam.joint == "butt"
    # off the truth's line (its visible run ends before the plates do): under 0.1 mm. No base pose: camera frame
    a, b = truth.points_camera[0], truth.points_camera[-1]
    u = (b - a) / np.linalg.norm(b - a)
    rel = np.asarray(seam.points) - a
    off = np.linalg.norm(rel - np.outer(rel @ u, u), axis=1)
    assert float(off.max()) < 0.0001


def test_a_gap_parts_two_surfaces_when_one_lies_on_each_side_of_it() -> None:
    from perception.capture import CameraIntrinsics
    from perception.fine.gaps import _parts
    from perception.fine.types import SeamCurve, SurfaceSet

    intr = CameraIntrinsics(fx=500.0, fy=500.0, cx=100.0, cy=50.0, width=200, height=100)
    labels = np.full((50, 100), -1, np.int32)
    labels[:, :50] = 0  # at factor 2: image columns below 100 are surface 0's, beyond it surface 1's
    labels[:, 50:] = 1
    surf = SurfaceSet(labels, 2, ())

    def seam_at(u_px: float) -> SeamCurve:
        z = 0.5
        x = (u_px - intr.cx) * z / intr.fx
        pts = np.array([[x, (10 - intr.cy) * z / intr.fy, z], [x, (90 - intr.cy) * z / intr.fy, z]])
        n = np.tile([0.0, 0.0, -1.0], (2, 1))
        return SeamCurve("linear", "butt", pts, n, n, (0, 0), 10, 0.0)

    assert _parts(seam_at(100.0), surf, 0, 1, intr)  # between the two
    assert not _parts(seam_at(40.0), surf, 0, 1, intr)  # inside surface 0
    assert not _parts(seam_at(100.0), surf, 0, 2, intr)  # between 0 and another


def test_only_pieces_large_enough_to_flank_a_gap_are_looked_in_as_one_outline() -> None:
    # three pieces of one plane at 0.5 m seen square, 1 mm work samples: a plate of 40 x 40 samples, another
    # beside it, and a speckle of 64 samples (64 mm^2, under the 12 mm x 8 mm a plate covers that reaches 8 mm
    # beyond the shortest gap along 60% of it): only the two plates are a pair to look in
    from perception.fine.gaps import InnerGapParams, _coplanar_pairs
    from perception.fine.types import NoiseModel, Pair, Surface, SurfaceSet

    nm = NoiseModel(sigma_1m_m=1e-3, floor_m=5e-5, pixel_angle_rad=0.001)  # full resolution: 0.5 mm at 0.5 m
    down = np.array([0.0, 0.0, -1.0])

    def plate(label: int, n: int) -> Surface:
        return Surface(label, "plane", down, 0.5, 1e-4, n, np.array([0.0, 0.0, 0.5]), 0.5)

    surf = SurfaceSet(np.zeros((1, 1), np.int32), 2, (plate(0, 1600), plate(1, 1600), plate(2, 64)))
    touch = np.zeros((1, 2), np.int64)
    pairs = (Pair(0, 1, touch), Pair(0, 2, touch), Pair(1, 2, touch))
    assert _coplanar_pairs(surf, pairs, frozenset(), (), nm, InnerGapParams()) == [(0, 1)]
    # 100 samples of 1 mm: as large as the rule asks, it is looked in
    surf = SurfaceSet(surf.labels, 2, (plate(0, 1600), plate(1, 1600), plate(2, 100)))
    assert _coplanar_pairs(surf, pairs, frozenset(), (), nm, InnerGapParams()) == [(0, 1), (0, 2), (1, 2)]
    # 64 samples of a plane seen at 60 degrees cover twice the area of 64 seen square: 128 mm^2
    from perception.fine.gaps import _area_m2

    tilted = Surface(2, "plane", np.array([0.0, np.sin(np.radians(60.0)), -0.5]), 0.25, 1e-4, 64,
                     np.array([0.0, 0.0, 0.5]), 0.5)  # fmt: skip
    assert _area_m2(tilted, nm, 2) == pytest.approx(128e-6)
    assert _area_m2(plate(2, 64), nm, 2) == pytest.approx(64e-6)


def test_a_line_of_holes_among_many_scattered_ones_is_found_from_a_sample_of_them() -> None:
    # 20 000 dropouts scattered over a 200 mm plate and a 150 mm gap line of 1 500 hole points across it: the
    # trials are scored on 4 000 of the holes; the line found is the gap's (the best trial's points within 1 mm,
    # over most of its length)
    from perception.fine.gaps import SCORE_POINTS, InnerGapParams, _gap_lines

    rng = np.random.default_rng(3)
    scattered = np.column_stack([rng.uniform(-0.1, 0.1, (20000, 2)), np.full(20000, 0.5)])
    t = rng.uniform(-0.075, 0.075, 1500)
    line = np.column_stack([0.02 + 0.3 * t, t, np.full(1500, 0.5)])
    g = np.vstack([scattered, line])
    assert len(g) > SCORE_POINTS
    lines = _gap_lines(g, np.array([0.0, 0.0, -1.0]), InnerGapParams(), rng=np.random.default_rng(0))
    pts, u = lines[0]
    along = np.array([0.3, 1.0, 0.0]) / np.hypot(0.3, 1.0)
    assert abs(float(u @ along)) > np.cos(np.radians(1.0))
    on_line = np.abs((pts[:, :2] - [0.02, 0.0]) @ np.array([1.0, -0.3]) / np.hypot(1.0, 0.3)) <= 0.001
    assert on_line.mean() > 0.85  # the gap's points, and the few scattered holes within 1 mm of it
    assert float(np.ptp(pts @ along)) > 0.1


def test_an_outlines_pixels_sort_into_holes_and_points_on_the_plate() -> None:
    """The compiled pass over an outline's pixels (gaps.outline_pixels): on a plate z = 0.5 m, a pixel with no
    depth and one 5 mm behind see through it (where they lie inside the outline), one 5 mm in front of it and
    those two are not on it; the rest, in raster order, are."""
    from perception.fine.gaps import outline_pixels

    h, w = 10, 12
    y, x = np.mgrid[:h, :w] * 0.001
    full = np.stack([x, y, np.full((h, w), 0.5)], axis=-1).astype(np.float32)
    full[4, 5] = np.nan  # no depth
    full[5, 6, 2] = 0.505  # behind the plate: through a gap
    full[6, 7, 2] = 0.495  # in front of it: something standing on it
    full[2, 3] = np.nan  # no depth on the outline's edge: not inside it
    filled = np.zeros((6, 8), bool)
    filled[:, 1:] = True  # the window (rows 1-6, columns 2-9), less its first column
    inner = np.zeros_like(filled)
    inner[1:-1, 2:-1] = True
    normal = np.array([0.0, 0.0, -1.0])
    fy, fx, hole, on_plane = outline_pixels(full, 1, 2, filled, inner, normal, 0.5, 0.5, (4e-4, 5e-5), 0.0)
    assert (fy.tolist(), fx.tolist()) == tuple(a.tolist() for a in np.nonzero(filled))
    assert sorted(zip(fy[hole] + 1, fx[hole] + 2, strict=True)) == [(4, 5), (5, 6)]
    off = {(4, 5), (5, 6), (6, 7), (2, 3)}
    want = [full[r, c] for r, c in zip(fy + 1, fx + 2, strict=True) if (r, c) not in off]
    assert np.array_equal(on_plane, np.array(want, dtype=np.float64))
