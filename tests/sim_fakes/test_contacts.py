"""Seams from touching solids: exact lines on constructed weldments, and the rules that clip them."""

from __future__ import annotations

import numpy as np
import pytest

from perception.transforms import make_X
from sim_fakes.contacts import fold_seams, inside_solid
from sim_fakes.hull import box_corners, convex_hull, prism
from sim_fakes.scenes import CYL_SIDE, Part


def hull_part(name: str, corners: np.ndarray, x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> Part:
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Part(name, "hull", (0, 0, 0), make_X(R, [x, y, z]), (0.5, 0.5, 0.5), corners_part=corners)


def lines(seams) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(s.points[0], s.points[-1]) for s in seams]


def has_line(seams, a, b, tol: float = 1e-9) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return any(
        (np.allclose(p, a, atol=tol) and np.allclose(q, b, atol=tol))
        or (np.allclose(p, b, atol=tol) and np.allclose(q, a, atol=tol))
        for p, q in lines(seams)
    )


def test_a_box_hull_has_six_exact_faces_and_knows_its_inside() -> None:
    h = convex_hull(box_corners(0.2, 0.1, 0.01))
    assert len(h.faces) == 6
    normals = sorted(tuple(np.round(f.normal, 12)) for f in h.faces)
    assert normals == sorted([(-1.0, 0, 0), (1.0, 0, 0), (0, -1.0, 0), (0, 1.0, 0), (0, 0, -1.0), (0, 0, 1.0)])
    top = next(f for f in h.faces if f.normal[2] > 0.5)
    assert abs(top.offset + 0.01) < 1e-15
    assert h.contains(np.array([[0.0, 0.0, 0.005], [0.0, 0.0, 0.011]])).tolist() == [True, False]
    assert len(h.triangles) == 12 and set(h.triangle_face.tolist()) == set(range(6))


def test_a_bevelled_plate_is_a_prism_with_its_bevel_face() -> None:
    beta = np.radians(30.0)
    sec = np.array([[-0.1, 0.0], [0.0, 0.0], [0.0, 0.001], [-0.009 * np.tan(beta), 0.01], [-0.1, 0.01]])
    h = convex_hull(prism(sec, 0.2))
    assert len(h.faces) == 7
    bevel = max(h.faces, key=lambda f: f.normal @ np.array([np.cos(beta), 0.0, np.sin(beta)]))
    np.testing.assert_allclose(bevel.normal, [np.cos(beta), 0.0, np.sin(beta)], atol=1e-12)


def test_a_web_on_a_plate_gives_both_fillets_and_its_end_fillets_exactly() -> None:
    base = hull_part("base", box_corners(0.3, 0.2, 0.01))
    web = hull_part("web", box_corners(0.006, 0.12, 0.08), z=0.01)
    seams = fold_seams([base, web])
    assert len(seams) == 4
    assert has_line(seams, [-0.003, -0.06, 0.01], [-0.003, 0.06, 0.01])
    assert has_line(seams, [0.003, -0.06, 0.01], [0.003, 0.06, 0.01])
    assert has_line(seams, [-0.003, -0.06, 0.01], [0.003, -0.06, 0.01])
    for s in seams:
        # face a is the base's top, face b the web's side: into-directions lie in the faces, away from the seam
        assert s.faces[0][0] == 0 and s.faces[1][0] == 1
        np.testing.assert_allclose(s.into_b[0], [0.0, 0.0, 1.0], atol=1e-12)
        assert abs(s.into_a[0][2]) < 1e-12
        assert s.reach_b_m == pytest.approx(0.08)


def test_a_rotated_rib_gives_its_fillets_along_its_own_axis() -> None:
    base = hull_part("base", box_corners(0.4, 0.4, 0.012))
    yaw = np.radians(37.0)
    rib = hull_part("rib", box_corners(0.15, 0.005, 0.05), x=0.02, y=-0.01, z=0.012, yaw=yaw)
    seams = [s for s in fold_seams([base, rib]) if np.linalg.norm(s.points[1] - s.points[0]) > 0.1]
    assert len(seams) == 2
    axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    for s in seams:
        d = (s.points[1] - s.points[0]) / np.linalg.norm(s.points[1] - s.points[0])
        assert abs(abs(d @ axis) - 1.0) < 1e-12
        assert np.linalg.norm(s.points[1] - s.points[0]) == pytest.approx(0.15, abs=1e-9)
        # 2.5 mm off the rib's centre line, on the base's top
        off = s.points[0][:2] - np.array([0.02, -0.01])
        assert abs(abs(off @ np.array([-np.sin(yaw), np.cos(yaw)])) - 0.0025) < 1e-9
        assert s.points[0][2] == pytest.approx(0.012, abs=1e-12)


def test_a_flush_outside_corner_is_not_a_seam_and_an_overhang_is_clipped() -> None:
    base = hull_part("base", box_corners(0.2, 0.2, 0.01))
    # a wall standing flush on the base's +x edge: only its inner fillet is a seam
    wall = hull_part("wall", box_corners(0.01, 0.2, 0.1), x=0.095, z=0.01)
    seams = fold_seams([base, wall])
    assert len(seams) == 1 and has_line(seams, [0.09, -0.1, 0.01], [0.09, 0.1, 0.01])
    # a web running 40 mm past the base's -y edge: its fillets stop where the base does
    web = hull_part("web", box_corners(0.006, 0.12, 0.05), y=-0.1, z=0.01)
    long = [s for s in fold_seams([base, web]) if np.linalg.norm(s.points[1] - s.points[0]) > 0.02]
    assert len(long) == 2
    for s in long:
        ys = sorted(s.points[:, 1])
        assert ys[0] == pytest.approx(-0.1, abs=5e-4) and ys[1] == pytest.approx(-0.04, abs=1e-9)


def test_walls_on_a_larger_floor_give_outside_fillets_and_vertical_inside_corners() -> None:
    floor = hull_part("floor", box_corners(0.3, 0.3, 0.01))
    back = hull_part("back", box_corners(0.2, 0.008, 0.08), y=0.096, z=0.01)
    left = hull_part("left", box_corners(0.008, 0.192, 0.08), x=-0.096, y=-0.004, z=0.01)
    seams = fold_seams([floor, back, left])
    # back wall: inner fillet at y = 0.092 and outer fillet at y = 0.1 (the floor reaches 0.15)
    assert has_line(seams, [-0.1, 0.1, 0.01], [0.1, 0.1, 0.01])
    assert has_line(seams, [-0.092, 0.092, 0.01], [0.1, 0.092, 0.01])
    # the vertical inside corner where the left wall meets the back wall
    assert has_line(seams, [-0.092, 0.092, 0.01], [-0.092, 0.092, 0.09])
    vertical = [s for s in seams if abs(s.points[1][2] - s.points[0][2]) > 0.05]
    assert len(vertical) == 1 and {s.faces[0][0] for s in vertical} | {s.faces[1][0] for s in vertical} == {1, 2}


def test_a_seam_inside_another_solid_is_cut_out() -> None:
    base = hull_part("base", box_corners(0.4, 0.4, 0.01))
    rib_a = hull_part("a", box_corners(0.2, 0.006, 0.05), z=0.01)
    rib_b = hull_part("b", box_corners(0.006, 0.2, 0.05), z=0.01)  # crosses rib a at the origin
    seams = fold_seams([base, rib_a, rib_b])
    # each rib's two long fillets are cut in two by the other rib: 8 pieces of 97 mm
    pieces = sorted(np.linalg.norm(s.points[1] - s.points[0]) for s in seams if s.faces[0][0] == 0)
    long = [p for p in pieces if p > 0.05]
    assert len(long) == 8
    np.testing.assert_allclose(long, 0.097, atol=6e-4)
    for s in seams:
        mid = 0.5 * (s.points[0] + s.points[-1]) + 1e-4 * (s.into_a[0] + s.into_b[0])
        assert not any(inside_solid(p, mid[None])[0] for p in (base, rib_a, rib_b))


def test_a_pipe_on_a_plate_gives_one_exact_ring_clipped_to_the_plate() -> None:
    base = hull_part("base", box_corners(0.2, 0.2, 0.01))
    r = 0.03
    pipe = Part("pipe", "cylinder", (r, r, 0.1), make_X(np.eye(3), [0.0, 0.0, 0.01]), (0.5, 0.5, 0.5))
    (ring,) = fold_seams([base, pipe])
    assert ring.kind == "curved" and ring.faces[1] == (1, CYL_SIDE)
    np.testing.assert_allclose(np.hypot(ring.points[:, 0], ring.points[:, 1]), r, atol=1e-12)
    np.testing.assert_allclose(ring.points[:, 2], 0.01, atol=1e-12)
    np.testing.assert_allclose(ring.points[0], ring.points[-1], atol=1e-12)  # closed
    # the pipe standing over the plate's +x edge: only the part of the ring on the plate is a seam
    over = Part("pipe", "cylinder", (r, r, 0.1), make_X(np.eye(3), [0.09, 0.0, 0.01]), (0.5, 0.5, 0.5))
    found = fold_seams([base, over])
    (arc,) = [s for s in found if s.kind == "curved"]
    # and the hidden fold under the overhang: the plate's end face against the pipe's bottom cap
    (under,) = [s for s in found if s.kind == "linear"]
    assert under.faces[0] == (1, 1) and under.faces[1][0] == 0 and under.points[:, 0].tolist() == [0.1, 0.1]
    assert arc.points[:, 0].max() <= 0.1 + 1e-12
    # the arc spans the part of the circle with x <= 0.1 (angle beyond acos(1/3) either side of +x)
    ang = np.arctan2(arc.points[:, 1], arc.points[:, 0] - 0.09)
    assert np.abs(ang).min() == pytest.approx(np.arccos(1 / 3), abs=0.02)


def test_a_fillet_along_flush_faces_of_several_parts_is_one_seam() -> None:
    # a box's left wall stands between the front and back walls; outside, its face is flush with their ends
    floor = hull_part("floor", box_corners(0.4, 0.4, 0.01))
    front = hull_part("front", box_corners(0.2, 0.008, 0.08), y=-0.096, z=0.01)
    back = hull_part("back", box_corners(0.2, 0.008, 0.08), y=0.096, z=0.01)
    left = hull_part("left", box_corners(0.008, 0.184, 0.08), x=-0.096, z=0.01)
    seams = fold_seams([floor, front, back, left])
    # the outside fillet on the left runs the whole 200 mm (back end, left face, front end), not 184 mm
    assert has_line(seams, [-0.1, -0.1, 0.01], [-0.1, 0.1, 0.01])
    assert not any(np.linalg.norm(s.points[1] - s.points[0]) == pytest.approx(0.184) for s in seams
                   if abs(s.points[0][0] + 0.1) < 1e-9)  # fmt: skip
