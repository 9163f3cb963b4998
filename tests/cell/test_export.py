"""weldcell export: the demo's seams.json in all five formats, each read back and checked against the file."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from cell.cli import main
from cell.export import X_GLTF_ROBOT, load_seams, plan_for_export, route_poses
from cell.planning import WeldParams
from perception.transforms import X_from_xyzquat

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "samples" / "ribs"


@pytest.fixture(scope="module")
def demo_seams(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out)]) == 0
    return out / "seams.json"


def _doc(path: Path) -> dict:
    return json.loads(path.read_text())


def test_all_five_formats_are_written(demo_seams, tmp_path, capsys):
    outs = {"urscript": "w.script", "ls": "w.ls", "rosbag2": "bag", "gltf": "w.glb", "html": "w.html"}
    for fmt, name in outs.items():
        assert main(["export", str(demo_seams), "--to", fmt, "--out", str(tmp_path / name), "--json"]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["files"] == [str(tmp_path / name)]
        assert (tmp_path / name).exists()


def test_the_bag_reads_back_one_pose_array_per_seam_and_the_route(demo_seams, tmp_path):
    from rosbags.highlevel import AnyReader

    doc = _doc(demo_seams)
    for storage in ("mcap", "sqlite3"):
        bag = tmp_path / storage
        assert main(["export", str(demo_seams), "--to", "rosbag2", "--out", str(bag), "--storage", storage]) == 0
        arrays, paths = [], []
        with AnyReader([bag]) as reader:
            assert {c.topic: c.msgtype for c in reader.connections} == {
                "/weldcell/seams": "geometry_msgs/msg/PoseArray",
                "/weldcell/route": "nav_msgs/msg/Path",
            }
            for conn, _t, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                assert msg.header.frame_id == "base_link"
                (arrays if conn.topic == "/weldcell/seams" else paths).append(msg)
        assert len(arrays) == len(doc["seams"]) and len(paths) == 1
        for msg, seam in zip(arrays, doc["seams"], strict=True):
            assert len(msg.poses) == len(seam["points"])
            got = np.array([[p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                             p.orientation.z, p.orientation.w] for p in msg.poses])  # fmt: skip
            np.testing.assert_allclose(got, np.array(seam["poses"]), atol=1e-12)
        # the route is the planned TCP path: as many poses as the planner's waypoints, in order
        weld_path = plan_for_export(load_seams(demo_seams), params=WeldParams())
        expected = route_poses(load_seams(demo_seams), weld_path)
        route = paths[0].poses
        assert len(route) == sum(len(p.waypoints) for p in weld_path.passes) == len(expected)
        first = route[0].pose
        np.testing.assert_allclose(
            [first.position.x, first.position.y, first.position.z], expected[0][:3, 3], atol=1e-12
        )


def test_camera_frame_seams_go_to_the_bag_in_a_camera_frame_and_programs_refuse_them(demo_seams, tmp_path, capsys):
    doc = _doc(demo_seams)
    doc["frame"] = "camera"
    cam = tmp_path / "camera-seams.json"
    cam.write_text(json.dumps(doc))
    assert main(["export", str(cam), "--to", "rosbag2", "--out", str(tmp_path / "b"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frame_id"] == "camera"
    assert summary["route_poses"] == sum(len(s["points"]) for s in doc["seams"])
    assert main(["export", str(cam), "--to", "urscript", "--out", str(tmp_path / "w.script")]) == 2
    assert "camera frame" in capsys.readouterr().err


def test_a_bag_folder_named_like_a_ros1_bag_or_existing_is_refused(demo_seams, tmp_path, capsys):
    assert main(["export", str(demo_seams), "--to", "rosbag2", "--out", str(tmp_path / "x.bag")]) == 2
    assert "ROS 1 suffix" in capsys.readouterr().err
    assert main(["export", str(demo_seams), "--to", "rosbag2", "--out", str(tmp_path)]) == 2
    assert "exists" in capsys.readouterr().err


def test_the_gltf_loads_with_trimesh_with_every_seam_its_torch_axes_and_the_crop(demo_seams, tmp_path):
    import trimesh

    out = tmp_path / "w.glb"
    assert main(["export", str(demo_seams), "--to", "gltf", "--out", str(out), "--capture", str(SAMPLE)]) == 0
    scene = trimesh.load(out)
    doc = _doc(demo_seams)
    for seam in doc["seams"]:
        pts = np.array(seam["points"])
        lines = scene.geometry[f"seam_{seam['id']}"].vertices.reshape(-1, 2, 3)  # GL_LINES: one pair per segment
        np.testing.assert_allclose(lines[:, 0], pts[:-1], atol=1e-7)  # float32 in the file
        np.testing.assert_allclose(lines[:, 1], pts[1:], atol=1e-7)
        X = np.array([X_from_xyzquat(p) for p in seam["poses"]])
        z_axis = scene.geometry[f"seam_{seam['id']}_torch_z"].vertices.reshape(-1, 2, 3)
        np.testing.assert_allclose(z_axis[:, 1] - z_axis[:, 0], 0.015 * X[:, :3, 2], atol=1e-7)
        np.testing.assert_allclose(scene.graph[f"seam_{seam['id']}"][0], X_GLTF_ROBOT)
    crop = scene.geometry["cloud_crop"]
    assert isinstance(crop, trimesh.PointCloud)
    # the crop: every point within 25 mm of a seam point, and there are many
    seam_pts = np.concatenate([np.array(s["points"]) for s in doc["seams"]])
    from scipy.spatial import cKDTree

    d, _ = cKDTree(seam_pts).query(np.asarray(crop.vertices))
    assert len(crop.vertices) > 5000 and d.max() <= 0.025 + 1e-6


def test_the_programs_carry_the_jobs_speeds_and_the_cells_arc_output(demo_seams, tmp_path):
    # the sample's base frame is not the simulated cell's, so the cell's workspace refuses it: use the cell's welding
    # and IO without its [safety] table
    config = tmp_path / "cell.toml"
    text = (REPO / "examples" / "sim-cell.toml").read_text()
    text = (
        text.split("[safety]")[0] + "[welding]" + text.split("[welding]")[1].replace("arc_output = 0", "arc_output = 3")
    )
    config.write_text(text)
    job = tmp_path / "job.toml"
    job.write_text((REPO / "examples" / "jobs" / "ribs.toml").read_text().replace("arc_output = 0\n", ""))
    script, ls = tmp_path / "w.script", tmp_path / "w.ls"
    common = ["--config", str(config), "--job", str(job)]
    assert main(["export", str(demo_seams), "--to", "urscript", "--out", str(script), *common]) == 0
    assert main(["export", str(demo_seams), "--to", "ls", "--out", str(ls), *common, "--uframe", "2"]) == 0
    ur, fanuc = script.read_text(), ls.read_text()
    n = len(_doc(demo_seams)["seams"])
    assert ur.startswith("def RIBS():") and f"{n} passes" in ur
    assert ur.count("set_standard_digital_out(3, True)") == n  # the cell's arc output, once per pass
    assert "v=0.02500" in ur  # the job's travel speed, 25 mm/s
    assert fanuc.startswith("/PROG  RIBS") and fanuc.count("DO[4]=ON") == n  # FANUC numbers outputs from 1
    assert "150cm/min" in fanuc and "UFRAME_NUM=2 ;" in fanuc  # 25 mm/s = 150 cm/min


def test_the_cells_safety_limits_refuse_a_program_outside_its_workspace(demo_seams, tmp_path, capsys):
    args = ["--config", str(REPO / "examples" / "sim-cell.toml")]
    assert main(["export", str(demo_seams), "--to", "urscript", "--out", str(tmp_path / "w.script"), *args]) == 1
    assert "workspace" in capsys.readouterr().err
    assert not (tmp_path / "w.script").exists()


def test_the_html_view_is_self_contained_and_draws_every_segment(demo_seams, tmp_path):
    out = tmp_path / "w.html"
    assert main(["export", str(demo_seams), "--to", "html", "--out", str(out), "--capture", str(SAMPLE)]) == 0
    page = out.read_text()
    assert "<script src" not in page and "<link" not in page and "http://" not in page.replace("http://www.w3", "")
    assert "https://" not in page
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: the page's script is not run")
    script = page.split("<script>")[1].split("</script>")[0]
    harness = tmp_path / "run.js"
    harness.write_text(
        "let strokes = 0, dots = 0;\n"
        "const ctx0 = new Proxy({}, {get: (t, k) => k === 'stroke' ? () => strokes++ : k === 'fillRect' ? "
        "() => dots++ : (k in t ? t[k] : () => {}), set: (t, k, v) => { t[k] = v; return true; }});\n"
        "const el = {getContext: () => ctx0, addEventListener() {}, clientWidth: 800, clientHeight: 600, "
        "textContent: ''};\n"
        "globalThis.document = {getElementById: () => el}; globalThis.devicePixelRatio = 1;\n"
        "globalThis.addEventListener = () => {};\n" + script + "\nconsole.log(JSON.stringify({strokes, dots}));\n"
    )
    counts = json.loads(subprocess.run([node, str(harness)], check=True, capture_output=True, text=True).stdout)
    doc = _doc(demo_seams)
    n_points = sum(len(s["points"]) for s in doc["seams"])
    n_segments = sum(len(s["points"]) - 1 for s in doc["seams"])
    assert counts["strokes"] == n_segments + 3 * n_points  # seam segments and three torch axes per path point
    assert counts["dots"] > 5000 + 1  # the crop's points and the background


def _seam_along_x(seam_id: int, y: float) -> dict:
    xs = np.linspace(0.30, 0.40, 21)
    pts = np.column_stack([xs, np.full_like(xs, y), np.zeros_like(xs)])
    quat = [1.0, 0.0, 0.0, 0.0]  # 180 deg about x: torch z points down into the joint, x along +x (travel)
    poses = [[*p, *quat] for p in pts.tolist()]
    return {"id": seam_id, "kind": "linear", "points": pts.tolist(), "poses": poses, "length_m": 0.1, "confidence": 1}


def test_a_path_across_track_positions_gives_one_program_per_position_and_one_rigid_route(tmp_path):
    from cell.export import write_programs
    from cell.planning import CellGeometry, Reach, TrackAxis

    doc = {
        "format_version": "1.1",
        "units": "m",
        "frame": "base",
        "seams": [_seam_along_x(0, 0.0), _seam_along_x(1, 1.5)],
    }
    path = tmp_path / "seams.json"
    path.write_text(json.dumps(doc))
    data = load_seams(path)
    geometry = CellGeometry(Reach(radius_m=0.6, preferred_m=0.35), TrackAxis(0.0, 2.5, np.array([0.0, 1.0, 0.0])))
    weld_path = plan_for_export(data, params=WeldParams(), geometry=geometry)
    assert len(weld_path.track_positions_m) == 2  # the second seam is out of reach until the carriage moves
    written = write_programs(tmp_path / "w.script", weld_path, language="urscript", name="two")
    assert [p.name for p in written] == ["w_1.script", "w_2.script"]
    assert [p.read_text().splitlines()[0] for p in written] == ["def TWO_1():", "def TWO_2():"]
    # the route in the seams' frame (the base at the capture's track position): each arc-on and arc-off TCP sits
    # stickout above a seam end, whatever track position its pass was planned at
    route = route_poses(data, weld_path)
    ends = {(round(x, 6), round(y, 6)) for s in doc["seams"] for x, y, _z in (s["points"][0], s["points"][-1])}
    k = 0
    for p in weld_path.passes:
        arc_on, arc_off = route[k + 1], route[k + len(p.waypoints) - 2]
        for X in (arc_on, arc_off):
            assert (round(X[0, 3], 6), round(X[1, 3], 6)) in ends
            assert X[2, 3] == pytest.approx(0.015, abs=1e-9)  # torch z points down: the tip is 15 mm above
        k += len(p.waypoints)
    assert k == len(route)
