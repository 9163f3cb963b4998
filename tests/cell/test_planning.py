"""Weld planning: optimal order (checked by brute force), exact pass geometry, track positions, multi-capture merge."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cell.errors import ConfigError, SafetyViolation
from cell.planning import (
    CellGeometry,
    MoveKind,
    Reach,
    TrackAxis,
    WeldParams,
    choose_track_position,
    pass_poses_world,
    plan_weld_path,
)
from cell.route import route_length
from cell.world_seams import SeamFilter, X_world_base, collect_seams, world_seams
from tests.cell.planning_helpers import brute_force, make_seam

UP = np.array([0.0, 0.0, 1.0])


GEOMETRY = CellGeometry(Reach(radius_m=1.2, preferred_m=0.7))


def test_planned_path_order_and_directions_are_optimal_for_real_seams() -> None:
    seams = world_seams(
        [
            make_seam(0, (0.5, -0.3, 0.0), (0.5, -0.1, 0.0)),
            make_seam(1, (0.7, 0.2, 0.0), (0.5, 0.2, 0.0)),
            make_seam(2, (0.4, 0.0, 0.0), (0.6, 0.05, 0.0)),
            make_seam(3, (0.8, -0.2, 0.0), (0.8, 0.1, 0.0), z=(0.3, 0.0, -1.0)),
            make_seam(4, (0.3, 0.3, 0.02), (0.3, 0.1, 0.02)),
        ]
    )
    params = WeldParams(approach_m=0.05, retract_m=0.03, stickout_m=0.012)
    start = np.array([0.4, -0.4, 0.3])
    path = plan_weld_path(seams, params, geometry=GEOMETRY, p_world_start=start)
    P = [[pass_poses_world(s, params, reverse=r) for r in (False, True)] for s in seams]
    entries = np.array([[P[i][d][0, :3, 3] for d in (0, 1)] for i in range(len(seams))])
    exits = np.array([[P[i][d][-1, :3, 3] for d in (0, 1)] for i in range(len(seams))])
    assert path.air_length_m == pytest.approx(brute_force(entries, exits, start), abs=1e-12)
    # and the passes really are in that order and direction
    route = [(p.seam_id, p.reversed) for p in path.passes]
    assert route_length(route, entries, exits, start) == pytest.approx(path.air_length_m, abs=1e-12)
    # deterministic
    again = plan_weld_path(seams, params, geometry=GEOMETRY, p_world_start=start)
    assert [(p.seam_id, p.reversed) for p in again.passes] == route


# ------------------------------------------------------------------------------------------------ pass geometry
def test_approach_arc_on_travel_retract_geometry_is_exact() -> None:
    seam = world_seams([make_seam(5, (0.5, -0.1, 0.02), (0.5, 0.1, 0.02), step_m=1.0)])[0]  # two points
    params = WeldParams(stickout_m=0.015, approach_m=0.05, retract_m=0.04, max_segment_m=0.05)
    path = plan_weld_path([seam], params, geometry=GEOMETRY)
    (p,) = path.passes
    assert p.track_position_m == 0.0
    kinds = [w.kind for w in p.waypoints]
    assert kinds[0] is MoveKind.AIR and kinds[1] is MoveKind.APPROACH and kinds[-1] is MoveKind.RETRACT
    assert all(k is MoveKind.WELD for k in kinds[2:-1])
    R = seam.X_world_torch[0, :3, :3] if not p.reversed else seam.reversed().X_world_torch[0, :3, :3]
    # torch z points straight down: the contact tip is stick-out above the seam, approach/retract further up
    start_pt = np.array([0.5, -0.1, 0.02]) if not p.reversed else np.array([0.5, 0.1, 0.02])
    end_pt = np.array([0.5, 0.1, 0.02]) if not p.reversed else np.array([0.5, -0.1, 0.02])
    np.testing.assert_allclose(p.arc_on.X_base_tcp[:3, 3], start_pt + 0.015 * UP, atol=1e-12)
    np.testing.assert_allclose(p.approach.X_base_tcp[:3, 3], start_pt + 0.065 * UP, atol=1e-12)
    np.testing.assert_allclose(p.arc_off.X_base_tcp[:3, 3], end_pt + 0.015 * UP, atol=1e-12)
    np.testing.assert_allclose(p.retract.X_base_tcp[:3, 3], end_pt + 0.055 * UP, atol=1e-12)
    for w in p.waypoints:
        np.testing.assert_allclose(w.X_base_tcp[:3, :3], R, atol=1e-12)
    # travel: 0.2 m subdivided into 0.05 m steps, evenly, straight
    xyz = np.array([w.X_base_tcp[:3, 3] for w in p.travel])
    assert len(xyz) == 5
    np.testing.assert_allclose(np.linalg.norm(np.diff(xyz, axis=0), axis=1), 0.05, atol=1e-12)
    # speeds and blends per segment
    assert p.approach.speed_m_s == params.air_speed_m_s
    assert p.arc_on.speed_m_s == params.approach_speed_m_s == p.retract.speed_m_s
    assert all(w.speed_m_s == params.travel_speed_m_s for w in p.travel[1:])
    assert p.arc_on.blend_m == 0.0 and p.arc_off.blend_m == 0.0 and p.approach.blend_m == 0.0
    assert all(w.blend_m == params.blend_m for w in p.travel[1:-1])


def test_angles_and_stickout_keep_the_wire_tip_on_the_seam_and_lean_the_same_way_both_directions() -> None:
    seam = world_seams([make_seam(0, (0.5, 0.0, 0.0), (0.6, 0.0, 0.0), z=(0.0, -1.0, -1.0))])[0]
    params = WeldParams(
        work_angle_rad=math.radians(10), travel_angle_rad=math.radians(15), stickout_m=0.02, approach_m=0.03
    )
    fwd = pass_poses_world(seam, params, reverse=False)
    rev = pass_poses_world(seam, params, reverse=True)
    for X, pts, travel_dir in ((fwd, seam.points_world, [1, 0, 0]), (rev, seam.points_world[::-1], [-1, 0, 0])):
        travel = X[1:-1]
        z = travel[:, :3, 2]
        # wire tip = contact tip + stick-out along the (tilted) torch axis = the seam point
        np.testing.assert_allclose(travel[:, :3, 3] + 0.02 * z, pts, atol=1e-12)
        np.testing.assert_allclose(X[0, :3, 3], travel[0, :3, 3] - 0.03 * z[0], atol=1e-12)
        # push: the torch axis leans ahead by the travel angle
        np.testing.assert_allclose(z @ np.asarray(travel_dir, float), math.sin(math.radians(15)), atol=1e-12)
        for R in X[:, :3, :3]:
            np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
            assert np.linalg.det(R) == pytest.approx(1.0)
    # the work angle tilts towards the same plate whatever the direction: same sideways component
    np.testing.assert_allclose(fwd[1, :3, 2][1:], rev[1, :3, 2][1:], atol=1e-12)
    assert not np.allclose(fwd[1, :3, 2], rev[1, :3, 2])  # while the travel lean flips with the direction


def test_blend_is_clamped_to_half_of_the_neighbouring_segments() -> None:
    seam = world_seams([make_seam(0, (0.5, 0.0, 0.0), (0.5, 0.012, 0.0), step_m=0.004)])[0]
    path = plan_weld_path([seam], WeldParams(blend_m=0.005), geometry=GEOMETRY)
    travel = path.passes[0].travel
    assert [w.blend_m for w in travel] == pytest.approx([0.0, 0.002, 0.002, 0.0])


# ------------------------------------------------------------------------------------------------ track and reach
def test_track_positions_bring_every_seam_into_reach() -> None:
    track = TrackAxis(min_m=0.0, max_m=4.0)
    geometry = CellGeometry(Reach(radius_m=0.9, preferred_m=0.6, centre_base=np.array([0.0, 0.0, 0.1])), track)
    # a long part along the track (world y): seams every 0.8 m, all at x = 0.55 from the rail
    raw = [make_seam(k, (0.55, 0.8 * k - 0.1, 0.0), (0.55, 0.8 * k + 0.1, 0.0)) for k in range(5)]
    seams = world_seams(raw)
    path = plan_weld_path(seams, WeldParams(), geometry=geometry, track_position_m=0.0, p_world_start=[0.3, 0, 0.4])
    assert sorted(p.seam_id for p in path.passes) == list(range(5))
    assert path.passes[0].seam_id == 0 and path.passes[0].track_position_m == 0.0  # in reach: the track stays
    for p in path.passes:
        assert track.min_m <= p.track_position_m <= track.max_m
        for w in p.waypoints:
            d = np.linalg.norm(w.X_base_tcp[:3, 3] - geometry.reach.centre_base)
            assert d <= geometry.reach.radius_m + 1e-12
        # the commanded base pose and the track position give back the world pose of the seam
        X_world = X_world_base(p.track_position_m, track.axis_base) @ p.arc_on.X_base_tcp
        seam = seams[p.seam_id]
        ends = [seam.points_world[0], seam.points_world[-1]]
        assert min(np.linalg.norm(X_world[:3, 3] - np.add(e, [0, 0, 0.015])) for e in ends) < 1e-12
    moved = [p for p in path.passes if p.track_position_m != 0.0]
    assert moved, "seams 2 m away must move the track"
    for p in moved:
        # a moved pass puts the seam's centre at the preferred working distance
        seam = seams[p.seam_id]
        poses = pass_poses_world(seam, path.params, reverse=p.reversed)
        centre = poses[:, :3, 3].mean(axis=0) - p.track_position_m * track.axis_base
        assert np.linalg.norm(centre - geometry.reach.centre_base) == pytest.approx(0.6, abs=1e-9)
    assert len(path.track_positions_m) == len({p.track_position_m for p in path.passes})


def test_track_position_falls_back_to_the_largest_margin_and_refuses_the_unreachable() -> None:
    track = TrackAxis(min_m=0.0, max_m=2.0)
    geometry = CellGeometry(Reach(radius_m=0.5, preferred_m=0.45), track)
    # a seam parallel to the track, 0.5 m long at 0.3 m: the preferred distance would leave an end out of reach
    pts = np.array([[0.3, 1.0, 0.0], [0.3, 1.5, 0.0]])
    t = choose_track_position(pts, geometry=geometry, current_m=0.0)
    assert np.all(np.linalg.norm(pts - [0.0, t, 0.0], axis=1) <= 0.5 + 1e-9)
    assert t == pytest.approx(1.25, abs=1e-6)  # both preferred positions (0.915, 1.585) leave an end out
    with pytest.raises(SafetyViolation, match=r"seam 9: no track position in \[0.000, 2.000\] m"):
        choose_track_position([[0.3, 3.0, 0.0], [0.3, 1.0, 0.0]], geometry=geometry, current_m=0.0, label="seam 9")
    with pytest.raises(SafetyViolation, match="no track"):
        plan_weld_path(
            world_seams([make_seam(3, (2.0, 0.0, 0.0), (2.1, 0.0, 0.0))]),
            WeldParams(),
            geometry=CellGeometry(Reach(radius_m=1.0, preferred_m=0.5)),
        )


# ------------------------------------------------------------------------------------------------ merging
def test_a_seam_seen_in_two_captures_is_welded_once_over_the_union_of_its_extents() -> None:
    axis = np.array([0.0, 1.0, 0.0])
    # world truth: one fillet from y = 0.0 to y = 0.6 at x = 0.5; a parallel one 50 mm away; and, 2 mm from the
    # first, the fillet on the other side of a thin plate (torch from the other side): three distinct seams
    cap_a_t, cap_b_t = 0.0, 0.5
    cap_a = [
        make_seam(0, (0.5, 0.0, 0.0), (0.5, 0.4, 0.0), z=(-1, 0, -1)),
        make_seam(1, (0.55, 0.0, 0.0), (0.55, 0.3, 0.0), z=(-1, 0, -1)),
        make_seam(2, (0.502, 0.0, 0.0), (0.502, 0.3, 0.0), z=(1, 0, -1)),
    ]
    # capture B, carriage at 0.5 m: base coordinates are world minus 0.5 m along y; detected in reverse order
    cap_b = [make_seam(0, (0.5, 0.6 - 0.5, 0.0), (0.5, 0.25 - 0.5, 0.0), z=(-1, 0, -1))]
    merged = collect_seams([(cap_a_t, cap_a), (cap_b_t, cap_b)], axis_base=axis, tol_m=0.0015)
    assert [s.id for s in merged] == [0, 1, 2]
    seam = merged[0]
    assert seam.sources == ((0, 0), (1, 0))
    y = seam.points_world[:, 1]
    assert y.min() == pytest.approx(0.0) and y.max() == pytest.approx(0.6)
    assert np.all(np.diff(y) > 0), "every stretch of the seam appears once, in order"
    assert seam.length_m == pytest.approx(0.6)
    np.testing.assert_allclose(seam.points_world[:, [0, 2]], [[0.5, 0.0]] * len(y), atol=1e-12)
    # planned: three passes, the long seam welded once over its whole length
    geometry = CellGeometry(Reach(radius_m=1.5, preferred_m=0.8), TrackAxis(0.0, 2.0, axis))
    path = plan_weld_path(merged, WeldParams(), geometry=geometry)
    assert sorted(p.seam_id for p in path.passes) == [0, 1, 2]
    (p0,) = [p for p in path.passes if p.seam_id == 0]
    assert p0.length_m == pytest.approx(0.6)
    ends = sorted([p0.arc_on.X_base_tcp[1, 3], p0.arc_off.X_base_tcp[1, 3]])
    t = p0.track_position_m
    assert ends[0] + t == pytest.approx(0.0, abs=1e-3) and ends[1] + t == pytest.approx(0.6, abs=1e-3)


# ------------------------------------------------------------------------------------------------ inputs
def test_seam_filter_by_ids_kind_and_length() -> None:
    seams = world_seams(
        [
            make_seam(0, (0.5, 0.0, 0.0), (0.5, 0.2, 0.0)),
            make_seam(1, (0.6, 0.0, 0.0), (0.6, 0.02, 0.0)),
            make_seam(2, (0.7, 0.0, 0.0), (0.7, 0.2, 0.0), kind="curved"),
        ]
    )
    by_length = plan_weld_path(seams, WeldParams(seam_filter=SeamFilter(min_length_m=0.05)), geometry=GEOMETRY)
    assert sorted(p.seam_id for p in by_length.passes) == [0, 2]
    assert by_length.skipped == ((1, "length 0.0200 m below min_length_m 0.0500 m"),)
    by_kind = plan_weld_path(seams, WeldParams(seam_filter=SeamFilter(kinds=frozenset({"curved"}))), geometry=GEOMETRY)
    assert [p.seam_id for p in by_kind.passes] == [2]
    by_id = plan_weld_path(seams, WeldParams(seam_filter=SeamFilter(ids=frozenset({0, 1}))), geometry=GEOMETRY)
    assert sorted(p.seam_id for p in by_id.passes) == [0, 1]
    assert [s for s, _ in by_id.skipped] == [2]


def test_camera_frame_seams_and_bad_params_are_refused() -> None:
    with pytest.raises(ConfigError, match="seam 4 of capture 0 is in the 'camera' frame"):
        world_seams([make_seam(4, (0, 0, 0.5), (0.1, 0, 0.5), frame="camera")])
    with pytest.raises(ConfigError, match="travel_speed_m_s"):
        WeldParams(travel_speed_m_s=float("nan"))
    with pytest.raises(ConfigError, match="arc_do_index"):
        WeldParams(arc_do_index=-1)
    with pytest.raises(ConfigError, match="preferred_m"):
        Reach(radius_m=0.5, preferred_m=0.7)


def test_nothing_to_weld_is_an_empty_path() -> None:
    path = plan_weld_path([], WeldParams(), geometry=GEOMETRY, p_world_start=[0.3, 0.0, 0.4])
    assert path.passes == () and path.air_length_m == 0.0 and path.summary()["weld_length_m"] == 0.0
