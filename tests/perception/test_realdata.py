"""The detector on the real scans in ../shared/realdata: it must run without errors (a clear
NoSeamFound is an answer, a traceback is not). Skipped when the folder is absent."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from perception.capture import read_point_cloud
from perception.detect import DetectParams, detect, detect_cloud
from perception.errors import NoSeamFound

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is not present"),
]


def test_structured_light_frame_converts_with_its_documented_numbers() -> None:
    from cell.real_bench import xiaoyu_capture

    cap = xiaoyu_capture(REALDATA)
    # SOURCES.md: 2048 x 1536, fx = fy = 1991.94, cx 713.5, cy 761.3, median depth 676 mm, 85% valid
    assert cap.shape == (1536, 2048)
    assert cap.intrinsics.fx == pytest.approx(1991.9388)
    assert (cap.intrinsics.cx, cap.intrinsics.cy) == pytest.approx((713.5279, 761.3322))
    z = cap.depth_m[np.isfinite(cap.depth_m)]
    assert np.median(z) == pytest.approx(0.676, abs=0.01)
    assert z.size / cap.depth_m.size == pytest.approx(0.85, abs=0.03)
    for c in (cap, replace(cap, prompts_px=None)):
        try:
            res = detect(c, DetectParams())
        except NoSeamFound as err:
            assert "no seam found" in str(err)
        else:
            assert all(np.isfinite(s.points).all() for s in res.seams)


@pytest.mark.parametrize(
    "rel",
    [
        "thillRobot_seam_detection/table_8in10in_tee_x4y24_45.pcd",
        "pengrui-rio_welding-robot/Thu_Apr_2_10_14_30_3_frame.pcd",
        "blackhorsewu_CoboWeld/barpoints.pcd",
        "abhinand4as_weld_seam_ros2/lap_joint_base_frame.pcd",
    ],
)
def test_clouds_run_without_errors(rel: str) -> None:
    path = REALDATA / rel
    if not path.exists():
        pytest.skip(f"{rel} missing")
    cloud = read_point_cloud(path)
    assert len(cloud.points) > 1000
    try:
        res = detect_cloud(cloud, DetectParams())
    except NoSeamFound as err:
        assert "no seam found" in str(err)
    else:
        for s in res.seams:
            assert np.isfinite(s.points).all()
            # a seam found in a cloud lies within the cloud's bounds
            assert (s.points >= cloud.points.min(axis=0) - 0.01).all()
            assert (s.points <= cloud.points.max(axis=0) + 0.01).all()


def test_the_cad_sampled_tee_gives_its_visible_fillet_on_the_cad_line() -> None:
    # thillRobot's tee in its part frame (SOURCES.md): a 2-in tube along x (|y|, |z| <= 25.4 mm) and a 2-in
    # tube standing on it along z (|x|, |y| <= 25.4 mm). Their fillets run along y at x = +-25.4 mm,
    # z = 25.4 mm, 50.8 mm long; the sampled view sees the +x one (the y = +-25.4 mm junctions are flush).
    path = REALDATA / "thillRobot_seam_detection/8in10in_tee_01_blndrB.pcd"
    if not path.exists():
        pytest.skip("8in10in_tee_01_blndrB.pcd missing")
    cloud = read_point_cloud(path)
    assert cloud.normals is not None  # its normals say which side the sensor saw
    res = detect_cloud(cloud, DetectParams(method="refined"))
    assert res.info["voxel_m"] > 0.004  # 3 mm sample spacing: a coarser voxel was chosen
    assert len(res.seams) == 1
    p = res.seams[0].points
    assert np.abs(p[:, 0] - 0.0254).max() < 0.0005 and np.abs(p[:, 2] - 0.0254).max() < 0.0005
    assert np.abs(p[:, 1]).max() <= 0.0254 and res.seams[0].length_m > 0.035
    # the surfaces stage (the default) on the cloud's range image: the same line, exact, but only 22 of its
    # 50.8 mm (3 mm samples: issue 12)
    (seam,) = detect_cloud(cloud).seams
    assert np.abs(seam.points[:, 0] - 0.0254).max() < 0.0005 and np.abs(seam.points[:, 2] - 0.0254).max() < 0.0005
    assert np.abs(seam.points[:, 1]).max() <= 0.0254 and seam.length_m > 0.02


def test_the_structured_light_frames_butted_plates_give_the_authors_seam() -> None:
    # two steel plates butted with a 6.4 mm gap and a 4.7 mm step fill the frame, with no table: neither plate
    # stands on the other (the gap parts them), so neither is taken for the support and the joint between them
    # is found. The authors' own path (weld_trajectory.csv, their detector's output, 483 mm) is the comparison:
    # one seam over 400 mm long with its median distance to that path under 2 mm (1.4 mm measured)
    from cell.real_bench import xiaoyu_capture
    from perception.evaluate import point_to_polyline_distance

    csv = REALDATA / "XiaoyuChangeTheWorld_weld-seam-tracker-3d" / "weld_trajectory.csv"
    if not csv.is_file():
        pytest.skip("weld_trajectory.csv missing")
    authors = np.loadtxt(csv, delimiter=",", skiprows=1)[:, :3]
    authors = authors / 1000.0 if np.abs(authors).max() > 10 else authors
    res = detect(xiaoyu_capture(REALDATA), DetectParams())
    (seam,) = res.seams
    assert seam.length_m > 0.4
    assert float(np.median(point_to_polyline_distance(seam.points, authors))) < 0.002


def _turn_across_deg(points: np.ndarray, seam: np.ndarray) -> float | None:
    """How far the cloud ``points`` turns across straight ``seam`` (degrees): the angle between planes
    fitted to its points 2 to 18 mm either side of the seam's middle half-length stretch; None where a
    side holds under 20 points."""
    a, b = seam[0], seam[-1]
    u = (b - a) / np.linalg.norm(b - a)
    m, half = 0.5 * (a + b), 0.5 * float(np.linalg.norm(b - a))
    near = points[np.linalg.norm(points - m, axis=1) < max(half, 0.02)]
    n = np.linalg.eigh(np.cov((near - near.mean(axis=0)).T))[1][:, 0]
    across = np.cross(n, u) / np.linalg.norm(np.cross(n, u))
    d = points - m
    t, s, h = d @ u, d @ across, d @ n
    normals = []
    for sign in (-1.0, 1.0):
        k = (np.abs(t) <= half) & (np.abs(h) < 0.03) & (sign * s > 0.002) & (sign * s < 0.018)
        if k.sum() < 20:
            return None
        q = points[k]
        normals.append(np.linalg.eigh(np.cov((q - q.mean(axis=0)).T))[1][:, 0])
    return float(np.degrees(np.arccos(min(1.0, abs(float(normals[0] @ normals[1]))))))


def test_a_bent_panels_facets_give_no_seam_where_it_does_not_fold() -> None:
    # pengrui-rio frame 6: a bent steel panel, cut by the plane fits into facets whose best planes turn 22 to 30
    # degrees from their neighbours; at most of the lines where they meet the panel turns 8 to 19 degrees
    # within 12 pixels, under a fold's 20. Four such "seams" (18 to 65 mm) were reported before 4cb1e4d; none
    # is. Its stray points (16, 300 mm off) made its view coarser and it gave no seam at all; without them one
    # line turns 21 degrees at 12 pixels and is reported (60 mm): the cloud itself turns 25 degrees across it.
    # So: no straight seam where the cloud turns under a fold's 20 degrees, and at most two seams
    path = REALDATA / "pengrui-rio_welding-robot/Thu_Apr_2_10_14_30_6_frame.pcd"
    if not path.exists():
        pytest.skip("Thu_Apr_2_10_14_30_6_frame.pcd missing")
    cloud = read_point_cloud(path)
    try:
        seams = detect_cloud(cloud, DetectParams()).seams
    except NoSeamFound:
        return
    assert len(seams) <= 2
    for seam in seams:
        if seam.kind == "linear":
            turn = _turn_across_deg(cloud.points, np.asarray(seam.points))
            assert turn is not None and turn > 20.0, (seam.length_m, turn)


def test_the_y_tube_joint_gives_the_saddle_at_the_bottom_of_its_v() -> None:
    # CoboWeld's y-tube joint: two tubes of about 72 mm radius meet in a V (2.6 mm samples). Both are fitted
    # as cylinders, and their saddle is traced round the narrower one: one curved seam of 114 mm, on the
    # cloud (within 2.6 mm of a point everywhere) and along the V's bottom (a median 2.9 mm from the deepest
    # point, seen from the sensor's side, of each 5 mm slice across it). Before cylinder pairs were
    # intersected, nothing was found
    from scipy.spatial import cKDTree

    from perception.cloud_view import sensor_side

    path = REALDATA / "blackhorsewu_CoboWeld/y-tube-joint.pcd"
    if not path.exists():
        pytest.skip("y-tube-joint.pcd missing")
    cloud = read_point_cloud(path)
    (seam,) = detect_cloud(cloud, DetectParams()).seams
    assert seam.kind == "curved" and seam.length_m > 0.1
    p = np.asarray(seam.points)
    assert cKDTree(cloud.points).query(p)[0].max() < 0.003
    eye = sensor_side(cloud.points, cloud.normals)
    c = p.mean(axis=0)
    u = np.linalg.svd(p - c)[2][0]
    view = (c - eye) / np.linalg.norm(c - eye)
    t = (cloud.points - c) @ u
    deepest = []
    for t0 in np.arange(float(((p - c) @ u).min()), float(((p - c) @ u).max()), 0.005):
        q = cloud.points[(t >= t0) & (t < t0 + 0.005)]
        if len(q) >= 10:
            deepest.append(q[np.argmax((q - eye) @ view)])
    assert float(np.median(cKDTree(np.array(deepest)).query(p)[0])) < 0.004


def test_the_lidar_tee_on_its_table_gives_its_fillet() -> None:
    # thillRobot's tee on a table (a LiDAR scan, 1.9 mm between samples along a line, its lines 5-8 mm apart
    # on the tube): the tube's fillet on the cross-tube top, a median 0.6 mm from the reference's line
    # (independent plane fits, 44 mm), covering all of it within the reference's 10 mm, and no seam
    # elsewhere. The table's piece of the cloud is found by joining each point to its nearest: at three
    # in-line spacings the tube was a piece per scan line, clear of the table, and the fillet was dropped.
    # With 2% of the points dropped, the refinement alone held a piece of the fillet or none (no seam in
    # draws 4 and 7 of `weldcell bench real --draws 8`, 15 mm in draw 5): the wide planes' fold along the
    # fold the view proposed (fine.wide_folds, the structured error 0.85 sigma) confirms it and gives its
    # extent; and draw 2's "lap" 491 mm away, between two strips of the table fitted at a 31-33 degree tilt
    # 5 mm apart, is gone with the strips taken for the table (fine.support.on_table)
    import json

    from perception.evaluate import point_to_polyline_distance, resample_polyline

    rel = "thillRobot_seam_detection/table_8in10in_tee_x4y24_45.pcd"
    ref_file = REALDATA / "references" / "thillRobot_seam_detection_table_8in10in_tee_x4y24_45.json"
    if not ref_file.is_file():
        pytest.skip("the tee's reference is missing")
    reference = json.loads(ref_file.read_text(encoding="utf-8"))
    ref, tolerance = np.asarray(reference["seams"][0]["points"]), float(reference["tolerance_m"])
    cloud = read_point_cloud(REALDATA / rel)
    along = resample_polyline(ref, 0.001)
    for draw in (None, 2, 4, 7):
        pc = cloud if draw is None else cloud.subset(np.random.default_rng(draw).random(len(cloud.points)) >= 0.02)
        (seam,) = detect_cloud(pc, DetectParams()).seams
        assert seam.joint == "fillet", draw
        assert float(np.median(point_to_polyline_distance(np.asarray(seam.points), ref))) < 0.0025, draw
        assert float(np.mean(point_to_polyline_distance(along, np.asarray(seam.points)) <= tolerance)) >= 0.95, draw


def test_a_lidar_tube_on_a_plate_gives_its_fillet_and_no_groove_on_the_table() -> None:
    # thillRobot's tube on a plate on a table (1plate_1tube partA): the LiDAR draws the table in layers of scan
    # lines 3 mm apart and bends it by as much across the scene, and its border curls up 10 mm over its last
    # 20 mm. With the table taken to be flat to 1 mm it was no support, and the curl made a 59 mm "V-groove"
    # 326 mm from the reference fillet. The table flat as its sensor shows it (noise.structured_error) is
    # the support; the tube's front face and the base plate, found again as wide planes (fine.wide_folds:
    # the structure is 2.1 times the noise), give the fillet: 105 mm, a median 4.0 mm from the reference
    # (corner rounded over 20-40 mm, tolerance 10 mm), covering all of it, and nothing else
    import json

    from perception.evaluate import point_to_polyline_distance, resample_polyline

    rel = "thillRobot_seam_detection/1plate_1tube_partA_fig1_cropped.pcd"
    ref_file = REALDATA / "references" / "thillRobot_seam_detection_1plate_1tube_partA_fig1_cropped.json"
    if not ref_file.is_file() or not (REALDATA / rel).is_file():
        pytest.skip("the scan or its reference is missing")
    reference = json.loads(ref_file.read_text(encoding="utf-8"))
    ref, tolerance = np.asarray(reference["seams"][0]["points"]), float(reference["tolerance_m"])
    (seam,) = detect_cloud(read_point_cloud(REALDATA / rel), DetectParams()).seams
    assert seam.joint == "fillet"
    assert float(np.median(point_to_polyline_distance(np.asarray(seam.points), ref))) < 0.5 * tolerance
    along = resample_polyline(ref, 0.001)
    assert float(np.mean(point_to_polyline_distance(along, np.asarray(seam.points)) <= tolerance)) >= 0.9
