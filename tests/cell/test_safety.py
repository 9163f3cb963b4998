"""Safety validation: a valid path passes; each rule refuses with its reason (which pose, which value, which limit)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cell.errors import SafetyViolation
from cell.planning import CellGeometry, Reach, TrackAxis, WeldParams, WeldPath, plan_weld_path
from cell.safety import SafetyLimits, validate
from cell.world_seams import world_seams
from perception.seams import Seam
from perception.transforms import make_X

TRACK = TrackAxis(min_m=0.0, max_m=2.0)
GEOMETRY = CellGeometry(Reach(radius_m=1.0, preferred_m=0.6), TRACK)


def seam(seam_id: int, p0: tuple[float, float, float], p1: tuple[float, float, float]) -> Seam:
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    pts = np.linspace(a, b, 21)
    x = (b - a) / np.linalg.norm(b - a)
    z = np.array([0.0, 0.0, -1.0])
    R = np.column_stack([x, np.cross(z, x), z])
    return Seam(
        seam_id, "linear", pts, np.stack([make_X(R, p) for p in pts]), float(np.linalg.norm(b - a)), 0.9, frame="base"
    )


def limits(**changes: object) -> SafetyLimits:
    base: dict[str, object] = dict(
        workspace_min_world=np.array([-0.5, -0.5, -0.05]),
        workspace_max_world=np.array([1.5, 3.0, 0.8]),
        geometry=GEOMETRY,
        max_speed_m_s=0.25,
        max_blend_m=0.005,
        max_step_m=0.08,
        max_step_rad=math.radians(20),
        max_tilt_rad=math.radians(60),
    )
    base.update(changes)
    return SafetyLimits(**base)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def path() -> WeldPath:
    seams = world_seams(
        [
            seam(0, (0.5, -0.1, 0.0), (0.5, 0.1, 0.0)),
            seam(1, (0.6, 0.2, 0.0), (0.45, 0.2, 0.0)),
            seam(2, (0.55, 1.9, 0.0), (0.55, 2.1, 0.0)),  # needs the track
        ]
    )
    return plan_weld_path(seams, WeldParams(blend_m=0.002), geometry=GEOMETRY, p_world_start=[0.3, 0.0, 0.5])


def replace_waypoint(path: WeldPath, pass_index: int, label: str, **changes: object) -> WeldPath:
    p = path.passes[pass_index]
    wps = [dataclasses.replace(w, **changes) if w.label == label else w for w in p.waypoints]  # type: ignore[arg-type]
    assert any(w.label == label for w in p.waypoints)
    passes = list(path.passes)
    passes[pass_index] = dataclasses.replace(p, waypoints=tuple(wps))
    return dataclasses.replace(path, passes=tuple(passes))


def moved_pose(path: WeldPath, pass_index: int, label: str, X_change: np.ndarray, *, right: bool = False) -> WeldPath:
    (w,) = [w for w in path.passes[pass_index].waypoints if w.label == label]
    X = w.X_base_tcp @ X_change if right else X_change @ w.X_base_tcp
    return replace_waypoint(path, pass_index, label, X_base_tcp=X)


def refused(path: WeldPath, lim: SafetyLimits) -> str:
    with pytest.raises(SafetyViolation) as info:
        validate(path, lim)
    return str(info.value)


# ------------------------------------------------------------------------------------------------ the good case
def test_a_planned_path_passes_including_air_moves_and_a_track_move(path: WeldPath) -> None:
    assert len(path.passes) == 3
    assert len(path.track_positions_m) == 2  # the far seam was planned at another track position
    validate(path, limits())  # returns without raising


def test_an_empty_path_passes() -> None:
    validate(WeldPath(passes=(), params=WeldParams()), limits())


# ------------------------------------------------------------------------------------------------ each rule
def test_nan_and_inf_are_refused(path: WeldPath) -> None:
    X = path.passes[0].travel[3].X_base_tcp.copy()
    X[1, 3] = np.nan
    msg = refused(replace_waypoint(path, 0, "travel[3]", X_base_tcp=X), limits())
    assert f"pass 1 (seam {path.passes[0].seam_id}) travel[3] pose: contains NaN or inf at [1, 3]" in msg
    msg = refused(replace_waypoint(path, 1, "arc_off", speed_m_s=math.inf), limits())
    assert "arc_off: speed is inf, not a finite number" in msg
    msg = refused(replace_waypoint(path, 0, "travel[2]", blend_m=math.nan), limits())
    assert "travel[2]: blend radius is nan" in msg


def test_improper_rotations_are_refused(path: WeldPath) -> None:
    msg = refused(moved_pose(path, 0, "approach", np.diag([1.0, 1.0, 1.001, 1.0]), right=True), limits())
    assert "approach pose: rotation part is not orthonormal" in msg
    msg = refused(moved_pose(path, 0, "approach", np.diag([1.0, 1.0, -1.0, 1.0]), right=True), limits())
    assert "approach pose: rotation part is a reflection (det = -1.000" in msg


def test_outside_the_workspace_box_is_refused(path: WeldPath) -> None:
    msg = refused(path, limits(workspace_max_world=np.array([1.5, 3.0, 0.03])))
    # the first pose is an approach 0.065 m above the table
    assert (
        "pass 1 (seam" in msg and "approach: TCP z = 0.0650 m (world) above the workspace box max z = 0.0300 m" in msg
    )
    msg = refused(path, limits(workspace_max_world=np.array([1.5, 1.0, 0.8])))
    assert "TCP y = 1.9000 m (world) above the workspace box max y = 1.0000 m" in msg


def test_out_of_reach_in_the_commanded_frame_is_refused(path: WeldPath) -> None:
    # the far seam is in reach only from its own track position: command the same world poses with the carriage
    # at 0 (base = world) and they are out of reach
    p = path.passes[2]
    assert p.track_position_m > 1.0
    unmoved = tuple(dataclasses.replace(w, X_base_tcp=path.X_world_tcp(p, w)) for w in p.waypoints)
    bad = dataclasses.replace(
        path, passes=(*path.passes[:2], dataclasses.replace(p, track_position_m=0.0, waypoints=unmoved))
    )
    msg = refused(bad, limits())
    assert "pass 3 (seam 2) approach: TCP at" in msg and "(base frame, track at 0.0000 m)" in msg
    assert "beyond the reach radius 1.0000 m" in msg
    geometry = CellGeometry(Reach(radius_m=0.5, preferred_m=0.4), TRACK)
    assert "beyond the reach radius 0.5000 m" in refused(path, limits(geometry=geometry))


def test_track_position_outside_its_limits_is_refused(path: WeldPath) -> None:
    geometry = CellGeometry(GEOMETRY.reach, TrackAxis(min_m=0.0, max_m=1.0))
    msg = refused(path, limits(geometry=geometry))
    assert "pass 3 (seam 2) approach: track position" in msg and "outside the track limits [0.0000, 1.0000] m" in msg
    no_track = refused(path, limits(geometry=CellGeometry(GEOMETRY.reach)))
    assert "outside the track limits [0.0000, 0.0000] m" in no_track


def test_speed_blend_and_acceleration_limits(path: WeldPath) -> None:
    msg = refused(replace_waypoint(path, 1, "approach", speed_m_s=0.3), limits())
    assert "pass 2 (seam" in msg and "approach: speed 0.3000 m/s outside (0, 0.2500] m/s" in msg
    assert "speed 0.0000 m/s outside" in refused(replace_waypoint(path, 0, "arc_on", speed_m_s=0.0), limits())
    msg = refused(path, limits(max_blend_m=0.001))
    assert "blend radius 0.0020 m outside [0, 0.0010] m" in msg
    msg = refused(dataclasses.replace(path, params=WeldParams(accel_m_s2=2.0)), limits())
    assert "acceleration 2.0000 m/s^2 outside (0, 1.2000] m/s^2" in msg


def test_jumps_are_refused_except_into_air_moves(path: WeldPath) -> None:
    shift = make_X(np.eye(3), [0.0, 0.0, 0.1])
    msg = refused(moved_pose(path, 0, "travel[5]", shift), limits())
    assert "travel[5]: jump of 0.1" in msg and "from pass 1 (seam" in msg and "exceeds max_step_m 0.0800 m" in msg
    turn = make_X(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [0, 0, 0])
    msg = refused(moved_pose(path, 0, "travel[5]", turn, right=True), limits())
    assert "travel[5]: rotation step of 30.00 deg" in msg and "exceeds max_step_rad 20.00 deg" in msg
    # the approach of the next pass is an air move: a jump there is allowed (pass 2 starts far from pass 1's end)
    a = path.passes[0].retract.X_base_tcp[:3, 3]
    b = path.passes[1].approach.X_base_tcp[:3, 3]
    assert np.linalg.norm(a - b) > 0.08
    validate(path, limits())
    # but the approach distance itself is a checked step
    msg = refused(path, limits(max_step_m=0.03))
    assert "arc_on: jump of 0.0500 m from pass 1 (seam" in msg


def test_a_torch_pointing_upward_is_refused(path: WeldPath) -> None:
    tilt = make_X(Rotation.from_euler("x", 70, degrees=True).as_matrix(), [0, 0, 0])
    msg = refused(moved_pose(path, 0, "approach", tilt, right=True), limits())
    assert "approach: torch axis" in msg and "is 70.00 deg from straight down, beyond the limit 60.00 deg" in msg
    flipped = make_X(Rotation.from_euler("x", 180, degrees=True).as_matrix(), [0, 0, 0])
    assert "180.00 deg from straight down" in refused(moved_pose(path, 0, "approach", flipped, right=True), limits())


def test_a_path_planned_for_another_track_axis_is_refused(path: WeldPath) -> None:
    other = dataclasses.replace(path, track_axis_base=np.array([1.0, 0.0, 0.0]))
    assert "planned with track axis [1.0, 0.0, 0.0] but the cell's is [0.0, 1.0, 0.0]" in refused(other, limits())
