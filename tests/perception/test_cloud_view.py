"""A cloud's range image (perception.cloud_view), and the surfaces-first stage run on it."""

from __future__ import annotations

import numpy as np
import pytest

from perception.capture import PointCloud
from perception.cloud_view import sensor_side, view_cloud
from perception.detect import DetectParams, detect_cloud
from perception.errors import PerceptionError
from perception.evaluate import point_to_polyline_distance
from perception.transforms import make_X, transform_points

from .fine.scenes import rendered, tee


def _grid_cloud(step: float = 0.002) -> np.ndarray:
    x, y = np.meshgrid(np.arange(-0.05, 0.05 + 1e-9, step), np.arange(-0.04, 0.04 + 1e-9, step))
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def test_each_pixel_keeps_the_nearest_point_where_it_was_measured() -> None:
    flat = _grid_cloud()
    inner = (np.abs(flat[:, 0]) < 0.025) & (np.abs(flat[:, 1]) < 0.02)
    behind = flat[inner] + [0.0, 0.0, -0.05]  # a smaller layer 50 mm further, hidden behind it
    view = view_cloud(np.vstack([behind, flat]), np.array([0.0, 0.0, 0.5]))
    pts = view.organized.reshape(-1, 3)
    pts = pts[np.isfinite(pts[:, 2])]
    back = transform_points(view.X_cloud_camera, pts)
    # every kept point is one of the near layer's, unmoved (not snapped onto a pixel centre)
    d = np.min(np.linalg.norm(back[:, None, :] - flat[None, :, :], axis=2), axis=1)
    assert d.max() < 1e-6
    # a pixel 1.25 spacings wide holds at most one sample of the 2 mm grid (empty ones between take a
    # neighbour's), and most samples are kept
    assert 0.5 * len(flat) < len(np.unique(pts, axis=0)) <= len(flat)
    assert view.X_cloud_camera[:3, 3] == pytest.approx([0.0, 0.0, 0.5])


def test_a_layer_seen_through_the_gaps_of_a_randomly_sampled_plate_is_not_kept() -> None:
    """A lap sampled like a merged scan: the lower plate sampled under the upper one too, both at random
    (a mesh sampled by area, so some pixels of the upper plate hold none of its points), 6 mm apart, seen
    from above a cloud in a z-up frame. Inside the upper plate every pixel holds an upper plate's point;
    beside its edge, the lower plate's pixels keep the lower plate's points (the edge is not moved)."""
    rng = np.random.default_rng(3)

    def plate(x0: float, x1: float, z: float, n: int) -> np.ndarray:
        xy = rng.uniform([x0, -0.05], [x1, 0.05], (n, 2))
        return np.column_stack([xy, np.full(n, z) + rng.normal(0.0, 2e-4, n)])

    lower = plate(-0.06, 0.06, 0.0, 16000)
    upper = plate(-0.06, 0.02, 0.006, 10700)  # about the same density: its edge at x = 20 mm
    view = view_cloud(rng.permutation(np.vstack([lower, upper])), np.array([0.0, 0.0, 0.5]))
    kept = view.organized.reshape(-1, 3)
    pts = transform_points(view.X_cloud_camera, kept[np.isfinite(kept[:, 2])])
    inside = (pts[:, 0] < 0.018) & (pts[:, 0] > -0.055) & (np.abs(pts[:, 1]) < 0.045)
    beside = (pts[:, 0] > 0.022) & (pts[:, 0] < 0.055) & (np.abs(pts[:, 1]) < 0.045)
    assert inside.sum() > 1000 and beside.sum() > 400
    assert np.all(pts[inside, 2] > 0.004)  # every one an upper plate's point (a fifth without the filters)
    assert np.all(pts[beside, 2] < 0.002)
    # the lower plate's points reach the edge: within two pixels of it along its whole length
    near_edge = pts[(pts[:, 2] < 0.002) & (pts[:, 0] > 0.02)]
    bins = np.digitize(near_edge[:, 1], np.linspace(-0.045, 0.045, 10))
    assert max(float(near_edge[bins == b, 0].min()) for b in range(1, 10)) < 0.02 + 2 * 0.5 / view.intrinsics.fx


def _pixel_of(view, p: np.ndarray) -> tuple[int, int]:
    """The (row, column) of cloud-frame point ``p`` in ``view``."""
    R, eye = view.X_cloud_camera[:3, :3], view.X_cloud_camera[:3, 3]
    c = (p - eye) @ R
    k = view.intrinsics
    return int(np.floor(k.fy * c[1] / c[2] + k.cy + 0.5)), int(np.floor(k.fx * c[0] / c[2] + k.cx + 0.5))


def test_a_scans_lines_far_apart_are_one_face_and_a_gap_between_plates_stays_open() -> None:
    """Two plates 4 mm apart scanned in lines like a LiDAR: 1 mm between samples along a line, 6 mm between
    lines, looked at from another side than the scan's. Between the lines the view is bridged: every pixel
    of a plate holds a point of it (the lines come three to five pixels apart). Along the lines the gap
    between the plates, wider than a sample but flanked by whole plates, stays open."""
    s = np.arange(-0.1, 0.1, 0.001)
    lines = np.arange(-0.06, 0.06, 0.006)
    pts = np.array([[x, y, 0.0] for y in lines for x in s if abs(x) > 0.002])
    pts[:, 2] += np.random.default_rng(0).normal(0.0, 1e-4, len(pts))
    view = view_cloud(pts, np.array([0.0, -0.35, 0.45]))
    z = view.organized[..., 2]
    inner = [_pixel_of(view, np.array([x, y, 0.0])) for x in (-0.08, -0.03, 0.03, 0.08)
             for y in np.arange(-0.05, 0.05, 0.0005)]  # fmt: skip
    assert np.mean([np.isfinite(z[r, c]) for r, c in inner]) > 0.98
    gap = [_pixel_of(view, np.array([0.0, y, 0.0])) for y in np.arange(-0.05, 0.05, 0.002)]
    assert not any(np.isfinite(z[r, c]) for r, c in gap)


def test_a_cloud_in_millimetres_is_refused_with_the_reason() -> None:
    from perception.errors import BadCapture

    cloud, _ = _tee_cloud(make_X(np.eye(3), [0.0, 0.0, 0.0]))
    with pytest.raises(BadCapture, match=r"millimetres must be scaled by 0\.001"):
        detect_cloud(PointCloud(cloud * 1000.0, source="tee_mm.ply"))


def test_a_room_scanned_whole_is_refused_with_the_reason() -> None:
    """A cell's floor and a wall scanned whole, 7 m by 5 m at 25 mm samples (a LiDAR's room scan): over 6.7
    m across, more than a cell's part, and the reason says to crop it (it was refused by the range image's
    depth check, as a camera file's depth scale)."""
    from perception.errors import BadCapture

    a, b = np.meshgrid(np.arange(0.0, 7.0, 0.025), np.arange(0.0, 5.0, 0.025))
    floor = np.column_stack([a.ravel(), b.ravel(), np.zeros(a.size)])
    wall = np.column_stack([a.ravel(), np.full(a.size, 5.0), 0.6 * b.ravel()])
    with pytest.raises(BadCapture, match=r"spans 9\.1 m across, more than a part in a welding cell: crop it"):
        detect_cloud(PointCloud(np.vstack([floor, wall]), source="room"))


def test_a_few_stray_returns_far_off_do_not_change_the_seam() -> None:
    """The tee's cloud in a z-up frame with three single returns 2 m aside and one 10 m off (a far wall, a
    reflection): they are dropped (the view they stretched had pixels too coarse for the part, and one
    10 m off read as a unit error) and the fillet is the same as without them."""
    X = make_X(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [0.4, -0.2, 1.0])
    cloud, truth = _tee_cloud(X)
    clean = detect_cloud(PointCloud(cloud, source="tee"))
    c = np.median(cloud, axis=0)
    strays = c + np.array([[2.0, 0.0, 0.0], [-2.0, 0.5, 0.0], [0.0, 2.0, 0.3], [0.0, 0.0, 10.0]])
    res = detect_cloud(PointCloud(np.vstack([cloud, strays]), source="tee+strays"))
    assert res.info["stray_points"] == 4 and clean.info["stray_points"] == 0
    assert len(res.seams) == len(clean.seams) >= 1
    for a, b in zip(res.seams, clean.seams, strict=True):
        assert np.array_equal(a.points, b.points)
    best = min(float(np.median(point_to_polyline_distance(np.asarray(s.points), truth))) for s in res.seams)
    assert best < 3e-4


def test_invalid_points_are_left_out_and_a_cloud_with_no_surface_says_so() -> None:
    """A cloud given in memory with NaN and inf rows (an organized cloud's invalid pixels): they are left
    out, and the tee's fillet is the same as without them. Points along one line, or all at one point, hold
    no surface: no seam, and the reason says so (it read as a wrong intrinsics file before); no finite
    point at all is refused."""
    from perception.errors import NoSeamFound

    X = make_X(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [0.4, -0.2, 1.0])
    cloud, _ = _tee_cloud(X)
    holes = cloud.copy()
    holes[::37] = np.nan
    holes[5::41] = np.inf
    clean = detect_cloud(PointCloud(cloud[np.all(np.isfinite(holes), axis=1)], source="tee"))
    res = detect_cloud(PointCloud(holes, source="tee with holes"))
    assert [s.points.tolist() for s in res.seams] == [s.points.tolist() for s in clean.seams]
    line = np.column_stack([np.linspace(0.0, 1.0, 500), np.zeros(500), np.full(500, 0.5)])
    with pytest.raises(NoSeamFound, match="along a line 1000 mm long"):
        detect_cloud(PointCloud(line, source="line"))
    with pytest.raises(NoSeamFound, match="along a line 0 mm long"):
        detect_cloud(PointCloud(np.tile([[0.1, 0.2, 0.5]], (500, 1)), source="one point"))
    with pytest.raises(PerceptionError, match="only 0 finite points"):
        detect_cloud(PointCloud(np.full((100, 3), np.nan), source="nothing"))


def test_a_bad_cloud_or_viewpoint_is_refused() -> None:
    flat = _grid_cloud()
    with pytest.raises(PerceptionError, match="N >= 5"):
        view_cloud(flat[:3], np.array([0.0, 0.0, 0.5]))
    with pytest.raises(PerceptionError, match="centre"):
        view_cloud(flat, np.median(flat, axis=0))
    with pytest.raises(PerceptionError, match=r"\(N, 3\)"):
        view_cloud(flat[:, :2], np.array([0.0, 0.0, 0.5]))


def _tee_cloud(X_frame_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rendered tee's valid points as a cloud in another frame, and its fillet's truth in that frame."""
    res = rendered("tee", "none")
    p = res.capture.points_camera().reshape(-1, 3)
    p = p[np.isfinite(p[:, 2])].astype(np.float64)
    (gt,) = res.ground_truth
    return transform_points(X_frame_camera, p), transform_points(X_frame_camera, gt.points_camera)


def _assert_fillet_found(cloud: np.ndarray, truth: np.ndarray) -> None:
    """The cloud's nearest seam to ``truth`` lies within 0.3 mm of it (median) over 80% of its length."""
    out = detect_cloud(PointCloud(cloud, source="tee"), DetectParams(method="surfaces"))
    best = min(out.seams, key=lambda s: float(np.median(point_to_polyline_distance(np.asarray(s.points), truth))))
    err = point_to_polyline_distance(np.asarray(best.points), truth)
    assert np.median(err) < 3e-4
    assert best.length_m > 0.8 * float(np.linalg.norm(np.diff(truth, axis=0), axis=1).sum())


def test_the_tee_fillet_from_its_cloud_in_a_robot_frame() -> None:
    """The rendered tee as an unorganized, shuffled cloud in a frame 1 m away and turned: the fillet comes
    back in that frame within a few tenths of a millimetre."""
    X_robot_camera = make_X(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.0, -1.0, -1.0]),
                            [0.4, -0.2, 1.0])  # fmt: skip
    cloud, truth = _tee_cloud(X_robot_camera)
    _assert_fillet_found(cloud[np.random.default_rng(0).permutation(len(cloud))], truth)


def test_a_scan_in_a_z_up_frame_is_looked_at_from_the_side_it_was_taken_from() -> None:
    """The tee scanned from its -x side 43 degrees above the table, as a cloud in the world frame (z up):
    from straight above its web's face is seen edge-on and the base plate's shadow behind the web shows.
    The viewpoint is the direction from which none of the scan's points hide behind others (within 30
    degrees of the eye's), and the fillet comes back within a few tenths of a millimetre."""
    scene = tee()
    cloud, truth = _tee_cloud(scene.camera.X_world_camera)
    centre = np.median(cloud, axis=0)
    got = sensor_side(cloud) - centre
    eye = np.asarray(scene.camera.eye) - centre
    assert np.degrees(np.arccos(got @ eye / np.linalg.norm(got) / np.linalg.norm(eye))) < 30.0
    _assert_fillet_found(cloud, truth)


def test_normals_that_are_all_nan_count_as_none_and_partly_nan_ones_by_their_finite_rows() -> None:
    """A cloud built in code (not read from a file, which drops bad normals) may carry NaN normals: all NaN,
    the viewpoint is the one without normals, and no warning is raised; some NaN, the finite ones decide."""
    import warnings

    scene = tee()
    cloud, _ = _tee_cloud(scene.camera.X_world_camera)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "Mean of empty slice" from a NaN mean was one
        got = sensor_side(cloud, np.full(cloud.shape, np.nan))
    assert np.array_equal(got, sensor_side(cloud))
    up = np.tile([0.0, 0.0, 1.0], (len(cloud), 1))
    up[::3] = np.nan
    centre = np.median(cloud, axis=0)
    size = float(np.linalg.norm(np.ptp(cloud, axis=0)))
    np.testing.assert_allclose(sensor_side(cloud, up), centre + np.array([0.0, 0.0, 2.0 * size]), atol=1e-12)


def test_a_piece_floating_clear_of_the_table_holds_no_seam(monkeypatch) -> None:
    """The tee's cloud (its table found as the support) with a bracket floating 200 mm over the table: two 60 mm
    plates meeting at a right angle, open upwards. Its fold is a v_groove 57 mm long when every surface counts;
    but it is joined to nothing standing on the table, so only the tee's fillet is given."""
    scene = tee()
    cloud, truth = _tee_cloud(scene.camera.X_world_camera)
    s, y = (g.ravel() for g in np.meshgrid(np.arange(0.0005, 0.06, 0.0012), np.arange(-0.03, 0.03, 0.0012)))
    r = np.sqrt(0.5)
    left, right = (np.column_stack([0.2 + side * s * r, y, 0.2 + s * r]) for side in (-1.0, 1.0))
    both = PointCloud(np.vstack([cloud, left, right]), source="tee")
    out = detect_cloud(both, DetectParams())
    assert out.info["support"]
    (seam,) = out.seams
    assert seam.joint == "fillet" and np.median(point_to_polyline_distance(np.asarray(seam.points), truth)) < 3e-4
    # every seam kept: the bracket's fold is found too, on its line (x = z = 0.2 m)
    import perception.detect as detect_module

    monkeypatch.setattr(detect_module, "_on_the_table", lambda res, points: res)
    (fold,) = [s for s in detect_cloud(both, DetectParams()).seams if s.joint != "fillet"]
    assert fold.length_m > 0.05 and np.abs(np.asarray(fold.points)[:, [0, 2]] - 0.2).max() < 1e-3
