"""cell.job_checks: the safety limits read from the example config, and a job refused before it is queued with
the job's key and the cell's limit named. No device is involved."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cell.errors import ConfigError
from cell.job import job_from_text
from cell.job_checks import MAX_DWELL_S, capture_pose, check_job, safety_limits, station_of
from cell.planning import X_world_base
from perception.transforms import make_X
from tests.cell.runner_rig import cell_config, job_text

CONFIG = cell_config(Path("unused"), "sim-cell-fanuc.toml")  # the example with [safety] max_speed_m_s = 0.6
LIMITS = safety_limits(CONFIG)


def test_the_limits_are_the_configs_in_si_units() -> None:
    assert LIMITS.max_speed_m_s == 0.6 and LIMITS.max_accel_m_s2 == 1.2 and LIMITS.max_blend_m == 0.005
    assert LIMITS.max_step_rad == pytest.approx(math.radians(20.0)) and LIMITS.max_tilt_rad == math.radians(60.0)
    np.testing.assert_array_equal(LIMITS.workspace_min_world, [0.30, -0.40, 0.025])
    assert LIMITS.geometry.reach.radius_m == 1.20
    assert LIMITS.geometry.track is not None and (LIMITS.geometry.track.min_m, LIMITS.geometry.track.max_m) == (0, 2.5)
    np.testing.assert_array_equal(LIMITS.geometry.axis_base, [0.0, 1.0, 0.0])


@pytest.mark.parametrize(
    ("changes", "error"),
    [
        ({"travel_speed_m_s": 0.25}, None),
        ({"travel_speed_m_s": 0.61}, "travel_speed_m_s: 0.61 exceeds the cell's limit [safety] max_speed_m_s = 0.6"),
        ({"track_position_m": 2.6}, "capture[0].track_position_m: 2.6 m is outside the track's soft limits"),
    ],
)  # fmt: skip
def test_a_job_over_the_cells_limits_is_refused_with_the_key_and_the_limit(changes: dict, error: str | None) -> None:
    job = job_from_text(job_text(**changes), source="job.toml", base_dir=Path("."))
    if error is None:
        check_job(CONFIG, LIMITS, job)
        return
    with pytest.raises(ConfigError) as info:
        check_job(CONFIG, LIMITS, job)
    assert error in str(info.value)


def test_dwells_are_bounded() -> None:
    text = job_text().replace("arc_output = 0\n", f"arc_output = 0\narc_on_dwell_s = {MAX_DWELL_S + 1}\n")
    with pytest.raises(ConfigError, match=r"welding.arc_on_dwell_s: 11.0 s exceeds the limit of 10.0 s"):
        check_job(CONFIG, LIMITS, job_from_text(text, source="job.toml", base_dir=Path(".")))


def test_a_fixture_relative_capture_pose_is_brought_into_the_base_frame_at_its_track_position() -> None:
    job = job_from_text(job_text(track_position_m=0.4), source="job.toml", base_dir=Path("."))
    assert job.spec.frame == "fixture" and CONFIG.fixture is not None
    X_world_fixture = np.asarray(CONFIG.fixture.X_world_fixture)
    expected = X_world_base(-0.4, LIMITS.geometry.axis_base) @ X_world_fixture @ job.captures[0].X_base_tool()
    np.testing.assert_allclose(capture_pose(CONFIG, LIMITS, job, 0), expected, atol=1e-15)
    # the carriage 0.4 m along base y moves the pose 0.4 m the other way in the base frame
    at_zero = capture_pose(CONFIG, LIMITS, job_from_text(job_text(), source="j", base_dir=Path(".")), 0)
    np.testing.assert_allclose(capture_pose(CONFIG, LIMITS, job, 0)[:3, 3] - at_zero[:3, 3], [0, -0.4, 0], atol=1e-12)


def test_a_dry_run_station_is_home_or_one_of_the_jobs_capture_poses_within_5_mm_and_1_degree() -> None:
    job = job_from_text(job_text(track_position_m=0.5), source="job.toml", base_dir=Path("."))
    assert CONFIG.home.pose is not None and CONFIG.home.track_position_m == 0.0
    X_home = CONFIG.home.pose.X_base_tool()
    X_capture = capture_pose(CONFIG, LIMITS, job, 0)

    def shifted(X: np.ndarray, *, dx_m: float = 0.0, turn_deg: float = 0.0) -> np.ndarray:
        turn = make_X(Rotation.from_euler("z", turn_deg, degrees=True).as_matrix(), np.zeros(3))  # about tool z
        out = X @ turn
        out[0, 3] += dx_m
        return out

    assert station_of(CONFIG, LIMITS, job, X_home, 0.0) == "home"
    assert station_of(CONFIG, LIMITS, job, shifted(X_home, dx_m=0.004, turn_deg=0.9), 0.0009) == "home"
    assert station_of(CONFIG, LIMITS, job, X_capture, 0.5) == "capture pose 1"
    assert station_of(CONFIG, LIMITS, job, X_capture, 0.0) is None  # the carriage not where that capture wants it
    assert station_of(CONFIG, LIMITS, job, X_home, 0.5) is None
    assert station_of(CONFIG, LIMITS, job, shifted(X_home, dx_m=0.006), 0.0) is None
    assert station_of(CONFIG, LIMITS, job, shifted(X_home, turn_deg=1.1), 0.0) is None
