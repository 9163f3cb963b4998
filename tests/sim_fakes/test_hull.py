"""Convex polyhedra of the simulator (sim_fakes/hull.py): exact faces, planes, polygons and inside tests."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_fakes.hull import box_corners, convex_hull, prism


def test_box_corners_stand_on_z_0_centred_in_x_and_y() -> None:
    c = box_corners(0.2, 0.1, 0.01)
    assert c.shape == (8, 3)
    assert sorted({tuple(p) for p in c.tolist()}) == sorted(
        (x, y, z) for x in (-0.1, 0.1) for y in (-0.05, 0.05) for z in (0.0, 0.01)
    )


def test_a_box_has_six_faces_with_exact_outward_planes_and_four_cornered_polygons() -> None:
    hull = convex_hull(box_corners(0.2, 0.1, 0.01))
    assert len(hull.faces) == 6
    planes = sorted((tuple(np.round(f.normal, 12) + 0.0), round(f.offset, 12) + 0.0) for f in hull.faces)
    assert planes == sorted(
        [
            ((1.0, 0.0, 0.0), -0.1), ((-1.0, 0.0, 0.0), -0.1),
            ((0.0, 1.0, 0.0), -0.05), ((0.0, -1.0, 0.0), -0.05),
            ((0.0, 0.0, 1.0), -0.01), ((0.0, 0.0, -1.0), 0.0),
        ]
    )  # fmt: skip
    for f in hull.faces:
        assert f.polygon.shape == (4, 3)
        assert np.abs(f.polygon @ f.normal + f.offset).max() < 1e-12  # every corner on its face's plane
        # ordered around the face: consecutive corners share an edge of the box (one coordinate changes), no
        # diagonal (two change) among them
        steps = np.diff(np.vstack([f.polygon, f.polygon[:1]]), axis=0)
        assert (np.count_nonzero(np.abs(steps) > 1e-12, axis=1) == 1).all()
    # two triangles per face, each labelled with the face its three corners lie on
    assert hull.triangles.shape == (12, 3) and np.bincount(hull.triangle_face).tolist() == [2] * 6
    for tri, fid in zip(hull.triangles, hull.triangle_face, strict=True):
        f = hull.faces[fid]
        assert np.abs(hull.vertices[tri] @ f.normal + f.offset).max() < 1e-12


def test_inside_means_inside_every_face_by_more_than_the_margin() -> None:
    hull = convex_hull(box_corners(0.2, 0.1, 0.01))
    p = np.array([[0.0, 0.0, 0.005], [0.099, 0.0, 0.005], [0.101, 0.0, 0.005], [0.0, 0.0, 0.0], [0.0, 0.0, -0.001]])
    assert hull.contains(p).tolist() == [True, True, False, False, False]  # on a face is not inside
    assert hull.contains(p, margin_m=0.002).tolist() == [True, False, False, False, False]
    assert hull.contains(np.array([0.0, 0.0, 0.005])).tolist() == [True]  # one point is a row


def test_a_faces_polygon_holds_the_points_of_its_plane_inside_its_edges() -> None:
    hull = convex_hull(box_corners(0.2, 0.1, 0.01))
    [top] = [f for f in hull.faces if f.normal[2] > 0.5]
    assert top.centroid() == pytest.approx([0.0, 0.0, 0.01], abs=1e-15)
    q = np.array([[0.0, 0.0, 0.01], [0.1, 0.05, 0.01], [0.1 + 1e-6, 0.0, 0.01], [0.0, -0.06, 0.01]])
    assert top.contains(q).tolist() == [True, True, False, False]  # the corner itself is in (tolerance 1e-9)
    assert top.contains(q, tol_m=2e-6).tolist() == [True, True, True, False]


def test_a_prism_extrudes_its_x_z_polygon_over_y_and_merges_coplanar_triangles() -> None:
    # a right triangle in x-z (a gusset's section) over 0.3 m of y: 2 ends and 3 sides
    corners = prism(np.array([[0.0, 0.0], [0.05, 0.0], [0.0, 0.04]]), 0.3)
    assert corners.tolist() == [
        [0.0, -0.15, 0.0], [0.05, -0.15, 0.0], [0.0, -0.15, 0.04],
        [0.0, 0.15, 0.0], [0.05, 0.15, 0.0], [0.0, 0.15, 0.04],
    ]  # fmt: skip
    hull = convex_hull(corners)
    sizes = sorted(len(f.polygon) for f in hull.faces)
    assert sizes == [3, 3, 4, 4, 4]
    [slope] = [f for f in hull.faces if f.normal[0] > 0.1 and f.normal[2] > 0.1]
    # the hypotenuse x/0.05 + z/0.04 = 1: outward normal (0.04, 0, 0.05) / |.|, through (0.05, y, 0)
    n = np.array([0.04, 0.0, 0.05]) / math.hypot(0.04, 0.05)
    assert slope.normal == pytest.approx(n, abs=1e-12)
    assert slope.offset == pytest.approx(-0.05 * n[0], abs=1e-12)
    assert len(hull.triangles) == 2 * 1 + 3 * 2  # a fan of one triangle per end, two per side
    assert hull.contains(np.array([[0.01, 0.1, 0.01], [0.03, 0.0, 0.03]])).tolist() == [True, False]
