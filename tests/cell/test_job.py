"""Job files: the example loads; welding parameters merge job over cell over planner defaults, in SI; every mistake is
a ConfigError naming the file and the key; the new config tables check their values."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest

from cell.config import DetectionConfig, WeldingConfig, config_from_dict, load_config
from cell.errors import ConfigError
from cell.job import detect_params, job_from_text, load_job, weld_params
from cell.planning import WeldParams
from cell.runner import safety_limits
from cell.world_seams import SeamFilter
from perception.transforms import X_from_ur_pose, X_from_xyzwpr_mm_deg, invert_X, transform_points

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"

CAPTURE = "[[capture]]\nxyz_m = [0.5, 0.0, 0.4]\nrotvec_rad = [3.14159, 0.0, 0.0]\n"


def error_of(text: str, source: str = "job.toml") -> str:
    with pytest.raises(ConfigError) as info:
        job_from_text(text, source=source)
    return str(info.value)


def test_the_ribs_example_loads_and_its_parameters_override_the_cells() -> None:
    job = load_job(EXAMPLES / "jobs" / "ribs.toml")
    assert (job.workpiece, job.spec.approval, job.spec.frame, len(job.captures)) == ("ribs", False, "fixture", 3)
    # from the side the fillets face (fixture frame): the -x side, then the -y side from two angles
    poses = [
        [-0.4003, -0.27962, 0.36439, -2.59847, -0.64206, -1.21239],
        [-0.12443, -0.4782, 0.30119, -2.1316, -1.23701, -1.07076],
        [-0.13153, -0.43999, 0.32551, -2.26852, -1.18112, -1.03028],
    ]
    for i, (capture, pose) in enumerate(zip(job.captures, poses, strict=True)):
        assert capture.prompts == "camera" and job.prompts_px(i) is None and capture.track_position_m == 0.0
        assert np.allclose(capture.X_base_tool(), X_from_ur_pose(pose))
    config = load_config(EXAMPLES / "sim-cell-fanuc.toml")
    params = weld_params(config.welding, job.spec.welding, job.spec.seams.seam_filter())
    assert params.travel_speed_m_s == 0.025 and params.approach_m == 0.04  # the job's
    assert params.air_speed_m_s == 0.25  # the cell's
    assert params.max_segment_m == WeldParams().max_segment_m  # the planner's
    assert params.travel_angle_rad == pytest.approx(math.radians(10.0)) and params.work_angle_rad == 0.0
    assert (params.arc_do_index, params.weld_job) == (0, 3)
    assert params.seam_filter == SeamFilter(kinds=frozenset({"linear"}), min_length_m=0.02)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("example", ["sim-cell-fanuc.toml", "sim-cell.toml"])
def test_the_ribs_job_sees_and_plans_every_fillet_of_the_ribs_scene(example: str) -> None:
    # what `weldcell run examples/jobs/ribs.toml` does up to the path, without moving: the fake camera renders
    # frames 0, 1 and 2 from the capture poses; the merged seams must be the scene's 10 fillets, once each
    from dataclasses import replace

    from cell.factory import build_camera
    from cell.planning import plan_weld_path
    from cell.safety import validate
    from cell.world_seams import X_world_base, collect_seams
    from perception.detect import detect

    config = load_config(EXAMPLES / example)
    job = load_job(EXAMPLES / "jobs" / "ribs.toml")
    limits = safety_limits(config)
    assert config.fixture is not None and config.home.pose is not None
    X_world_fixture = np.asarray(config.fixture.X_world_fixture, dtype=np.float64)
    pose: dict[str, Any] = {"X_base_tool": np.eye(4), "track_m": 0.0}
    # the fake camera takes a pose callable where a Robot is typed (sim_fakes.fake_camera.FakeCamera)
    robot, track = cast(Any, lambda: pose["X_base_tool"]), cast(Any, lambda: pose["track_m"])
    camera: Any = build_camera(config, robot=robot, track=track)
    camera.connect()
    found = []
    for spec in job.captures:
        X_base_world = X_world_base(-spec.track_position_m, limits.geometry.axis_base)
        pose["X_base_tool"] = X_base_world @ X_world_fixture @ spec.X_base_tool()
        pose["track_m"] = spec.track_position_m
        frame = replace(camera.capture(), X_base_tool=pose["X_base_tool"], X_tool_camera=config.X_tool_camera())
        found.append((spec.track_position_m, detect(frame, detect_params(config.detection)).seams))
    seams = collect_seams(
        found,
        axis_base=limits.geometry.axis_base,
        tol_m=config.detection.merge_tol_m,
        min_overlap_m=config.detection.merge_min_overlap_m,
    )
    params = weld_params(config.welding, job.spec.welding, job.spec.seams.seam_filter())
    p_world_home = config.home.pose.X_base_tool()[:3, 3]
    path = plan_weld_path(seams, params, geometry=limits.geometry, p_world_start=p_world_home)
    validate(path, limits)
    assert (len(seams), len(path.passes), path.skipped) == (10, 10, ())

    truth = camera.scene.seams  # in the scene's world frame, which is the fixture frame
    matched = []
    for seam in seams:
        p_fixture = transform_points(invert_X(X_world_fixture), seam.points_world)
        distances, coverage = [], []
        for t in truth:
            a, b = t.points[0], t.points[-1]
            u = (b - a) / np.linalg.norm(b - a)
            s = np.clip((p_fixture - a) @ u, 0.0, np.linalg.norm(b - a))
            distances.append(float(np.median(np.linalg.norm(p_fixture - (a + s[:, None] * u), axis=1))))
            coverage.append(float((s.max() - s.min()) / np.linalg.norm(b - a)))
        k = int(np.argmin(distances))
        assert distances[k] < 0.002, (seam.id, truth[k].name, distances[k])
        assert coverage[k] > 0.85, (seam.id, truth[k].name, coverage[k])  # the ends stop short of the corners
        matched.append(truth[k].name)
    assert sorted(matched) == sorted(t.name for t in truth)


def test_both_example_cells_run_the_ribs_job_from_their_fixture() -> None:
    for name in ("sim-cell.toml", "sim-cell-fanuc.toml"):
        config = load_config(EXAMPLES / name)
        assert config.fixture is not None and config.home.pose is not None
        limits = safety_limits(config)
        assert limits.max_tilt_rad == pytest.approx(math.radians(60.0))
        assert limits.geometry.track is not None and limits.geometry.track.max_m == 2.5
    ur = load_config(EXAMPLES / "sim-cell.toml")
    assert ur.fixture is not None and ur.camera.X_base_world == ur.fixture.X_world_fixture


def test_a_pose_is_xyz_and_rotation_vector_or_xyzwpr() -> None:
    job = job_from_text(
        'workpiece = "w"\n[[capture]]\ntrack_position_m = 0.4\nxyzwpr_mm_deg = [500, 10, 400, 180, 0, 90]\n',
        source="j.toml",
    )
    assert job.spec.frame == "base" and job.captures[0].track_position_m == 0.4
    assert np.allclose(job.captures[0].X_base_tool(), X_from_xyzwpr_mm_deg([500, 10, 400, 180, 0, 90]))
    both = 'workpiece = "w"\n' + CAPTURE + "xyzwpr_mm_deg = [500, 10, 400, 180, 0, 90]\n"
    assert error_of(both) == "job.toml: capture[0]: give either xyz_m with rotvec_rad, or xyzwpr_mm_deg"
    half = 'workpiece = "w"\n[[capture]]\nxyz_m = [0.5, 0.0, 0.4]\n'
    assert error_of(half) == "job.toml: capture[0]: xyz_m and rotvec_rad go together"


def test_mistakes_name_the_file_and_the_key() -> None:
    assert error_of(CAPTURE) == "job.toml: workpiece: required key is missing"
    assert error_of('workpiece = "w"\n') == "job.toml: capture: required key is missing"
    unknown = error_of('workpiece = "w"\n' + CAPTURE + "[welding]\ncurrent_a = 180\n")
    assert unknown.startswith("job.toml: welding.current_a: unknown key (allowed: travel_speed_m_s, ")
    assert error_of('workpiece = "w"\nspeed = 1\n' + CAPTURE).startswith("job.toml: speed: unknown key (allowed: ")
    typed = error_of('workpiece = "w"\n' + CAPTURE + '[welding]\ntravel_speed_m_s = "fast"\n')
    assert typed == "job.toml: welding.travel_speed_m_s: Input should be a valid number (got 'fast')"
    angle = error_of('workpiece = "w"\n' + CAPTURE + "[welding]\nwork_angle_deg = 95\n")
    assert angle == "job.toml: welding.work_angle_deg: Input should be less than 90 (got 95)"
    kinds = error_of('workpiece = "w"\n' + CAPTURE + '[seams]\nkinds = ["zigzag"]\n')
    assert kinds.startswith("job.toml: seams.kinds[0]: Input should be 'linear' or 'curved'")
    assert "malformed TOML" in error_of('workpiece = "w\n')


def test_prompts_come_from_a_file_relative_to_the_job(tmp_path: Path) -> None:
    (tmp_path / "p.json").write_text(json.dumps({"prompts_px": [[10.5, 20.0], [300.0, 40.0]]}), encoding="utf-8")
    path = tmp_path / "job.toml"
    path.write_text('workpiece = "w"\n' + CAPTURE + 'prompts = "p.json"\n', encoding="utf-8")
    prompts = load_job(path).prompts_px(0)
    assert prompts is not None and prompts.tolist() == [[10.5, 20.0], [300.0, 40.0]]
    path.write_text('workpiece = "w"\n' + CAPTURE + 'prompts = "missing.json"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"job\.toml: capture\[0\]\.prompts: cannot read the prompts file"):
        load_job(path)
    with pytest.raises(ConfigError, match=r"nope\.toml: job file does not exist"):
        load_job(tmp_path / "nope.toml")


def test_detection_and_welding_tables_map_to_the_library_parameters() -> None:
    p = detect_params(DetectionConfig(voxel_m=0.004, crop=False, z_range_m=[0.2, 1.5], method="paper"))
    assert (p.voxel_m, p.crop, p.z_range_m, p.method) == (0.004, False, (0.2, 1.5), "paper")
    assert detect_params(DetectionConfig(method="surfaces")).method == "surfaces"
    with pytest.raises(ValueError, match="surfaces"):
        DetectionConfig(method="best")  # type: ignore[arg-type]
    # without prompts: the part the camera is aimed at (the default), or every surface off the table
    assert detect_params(DetectionConfig()).unprompted == "aim"
    assert detect_params(DetectionConfig(unprompted="all")).unprompted == "all"
    with pytest.raises(ValueError, match="aim"):
        DetectionConfig(unprompted="everything")  # type: ignore[arg-type]
    params = weld_params(WeldingConfig(work_angle_deg=30.0), WeldingConfig(arc_output=3), SeamFilter())
    assert params.work_angle_rad == pytest.approx(math.pi / 6) and params.arc_do_index == 3


def test_the_new_config_tables_refuse_impossible_values() -> None:
    base = {"robot": {"kind": "fanuc", "host": "192.0.2.10"}, "camera": {"kind": "oakd"}}
    safety = {
        "workspace_min_world": [0.0, 0.0, 0.0],
        "workspace_max_world": [1.0, -1.0, 1.0],
        "reach_radius_m": 1.0,
        "reach_preferred_m": 0.5,
    }
    with pytest.raises(ConfigError, match=r"workspace_min_world .* must lie below workspace_max_world"):
        config_from_dict({**base, "safety": safety}, source="c.toml")
    safety["workspace_max_world"] = [1.0, 1.0, 1.0]
    with pytest.raises(ConfigError, match=r"c\.toml: safety: reach_preferred_m=2\.0 exceeds reach_radius_m=1\.0"):
        config_from_dict({**base, "safety": {**safety, "reach_preferred_m": 2.0}}, source="c.toml")
    with pytest.raises(ConfigError, match="track_axis_base must be a unit vector"):
        config_from_dict({**base, "safety": {**safety, "track_axis_base": [0.0, 2.0, 0.0]}}, source="c.toml")
    with pytest.raises(ConfigError, match=r"daemon\.token: String should have at least 16 characters"):
        config_from_dict({**base, "daemon": {"host": "10.0.0.5", "token": "short"}}, source="c.toml")
    config = config_from_dict({**base, "daemon": {"host": "10.0.0.5", "token": "0123456789abcdef"}})
    assert config.daemon.token == "0123456789abcdef"
    with pytest.raises(ConfigError, match=r"running jobs needs a \[safety\] table"):
        safety_limits(config)
