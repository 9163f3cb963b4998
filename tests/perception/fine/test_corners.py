"""Corners: two straight seams on one face meeting at an angle end at their lines' crossing."""

from __future__ import annotations

import numpy as np

from perception.fine.corners import join_corners
from perception.fine.types import NoiseModel, SeamCurve

NM = NoiseModel(sigma_1m_m=5e-4, floor_m=5e-5, pixel_angle_rad=0.001)  # 0.8 mm spacing, 0.3 mm sigma at 0.8 m
Z = 0.8
CORNER = np.array([0.0, 0.0, Z])


def seam(a, b, faces=(0, 1)) -> SeamCurve:
    pts = np.array([a, b], dtype=np.float64)
    n = np.tile([0.0, 0.0, -1.0], (2, 1))
    return SeamCurve("linear", "fillet", pts, n, n, faces, 100, 1e-4)


def test_the_two_fillets_round_a_bar_corner_end_at_the_corner() -> None:
    # along x towards the corner, stopping 1.5 mm past it; along y away from it, starting 1.2 mm short
    a = seam([-0.06, 0.0, Z], [0.0015, 0.0, Z], (0, 1))
    b = seam([0.0, 0.0012, Z], [0.0, 0.05, Z], (0, 2))
    a2, b2 = join_corners([a, b], NM)
    assert np.allclose(a2.points[-1], CORNER, atol=1e-9) and np.allclose(a2.points[0], a.points[0])
    assert np.allclose(b2.points[0], CORNER, atol=1e-9) and np.allclose(b2.points[-1], b.points[-1])


def test_no_corner_at_a_tee_far_ends_other_faces_or_three_seams() -> None:
    # a seam ending at the middle of another (a tee): the other's ends are far from the crossing
    a = seam([-0.06, 0.0, Z], [0.06, 0.0, Z], (0, 1))
    b = seam([0.0, 0.001, Z], [0.0, 0.05, Z], (0, 2))
    assert [s.points.tolist() for s in join_corners([a, b], NM)] == [a.points.tolist(), b.points.tolist()]
    # ends 10 mm apart: not one corner
    c = seam([-0.06, 0.0, Z], [-0.01, 0.0, Z], (0, 1))
    assert join_corners([c, b], NM)[0].points.tolist() == c.points.tolist()
    # the same lines on no common face
    d = seam([0.0, 0.0012, Z], [0.0, 0.05, Z], (3, 2))
    e = seam([-0.06, 0.0, Z], [0.0015, 0.0, Z], (0, 1))
    assert join_corners([e, d], NM)[0].points.tolist() == e.points.tolist()
    # three seams at one corner (a box's inside corner): two seams' crossing is not the three planes' corner
    up = seam([0.0, 0.0, Z - 0.0012], [0.0, 0.0, Z - 0.05], (1, 2))
    f = seam([0.0, 0.0012, Z], [0.0, 0.05, Z], (0, 2))
    out = join_corners([e, f, up], NM)
    assert [s.points.tolist() for s in out] == [e.points.tolist(), f.points.tolist(), up.points.tolist()]
