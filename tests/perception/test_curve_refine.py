"""perception.curve_refine: a curved seam traced slab by slab, on a pipe standing on a plate whose seam is known.

The pipe (radius 30 mm, axis along camera z) stands on a floor z = 0.6 m; its wall is sampled from 100 to 260 deg
around the axis, the floor for x < 0 outside it, every 0.5 mm with 0.1 mm noise; the viewpoint (-0.3, 0, 0.3) m
sees both. The seam is the circle x² + y² = 30², z = 0.6 m.
"""

from __future__ import annotations

import numpy as np
import pytest

from perception.cloud import kdtree
from perception.curve_refine import _corner_2d, _fit_line_2d, _seen_well, refine_curve
from perception.seamfit import FullRes, SeamParams

R, Z = 0.03, 0.6
VIEW = np.array([-0.3, 0.0, 0.3])


def pipe_on_plate(noise_m: float = 0.0001) -> FullRes:
    X, Y = np.meshgrid(np.arange(-0.08, 0.0, 0.0005), np.arange(-0.05, 0.05, 0.0005))
    floor = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, Z)])
    floor = floor[np.hypot(floor[:, 0], floor[:, 1]) > R]
    th, z = np.meshgrid(np.arange(np.radians(100), np.radians(260), 0.0005 / R), np.arange(0.52, Z, 0.0005))
    wall = np.column_stack([R * np.cos(th.ravel()), R * np.sin(th.ravel()), z.ravel()])
    pts = np.vstack([floor, wall]) + np.random.default_rng(0).normal(0.0, noise_m, (len(floor) + len(wall), 3))
    regions = np.r_[np.zeros(len(floor), np.int32), np.ones(len(wall), np.int32)]
    radial = np.column_stack([np.cos(th.ravel()), np.sin(th.ravel()), np.zeros(th.size)])
    normals = np.vstack([np.tile([0.0, 0.0, -1.0], (len(floor), 1)), radial])
    return FullRes(pts, regions, kdtree(pts), np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]), normals)


def arc(radius: float, z: float, deg_from: float, deg_to: float, n: int = 13) -> np.ndarray:
    a = np.radians(np.linspace(deg_from, deg_to, n))
    return np.column_stack([radius * np.cos(a), radius * np.sin(a), np.full(n, z)])


@pytest.fixture(scope="module")
def full() -> FullRes:
    return pipe_on_plate()


def test_a_coarse_arc_a_millimetre_off_is_pulled_onto_the_seam_and_tracked_past_its_ends(full: FullRes) -> None:
    res = refine_curve(full, 0, 1, arc(0.031, 0.601, 150, 210), SeamParams(), VIEW)
    assert res is not None
    pts, n_a, n_b, rms = res
    assert np.abs(np.hypot(pts[:, 0], pts[:, 1]) - R).max() < 0.0002  # on the circle within 0.2 mm (1 mm given)
    assert np.abs(pts[:, 2] - Z).max() < 0.0001
    angles = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]) % (2 * np.pi))
    assert angles.min() < 125 and angles.max() > 235  # tracked well past 150..210, inside the data's 100..260
    assert np.all(np.diff(np.sign(np.diff(angles))) == 0)  # in order along the seam, no back-tracking
    assert 5e-5 < rms < 3e-4  # the 0.1 mm noise
    # the floor's normal faces the viewpoint; the pipe's is radial (at each point's own angle); each from one
    # 5 mm slab's 2-D line fits under the noise (measured: at most 2.5 and 4.0 deg)
    assert np.all(n_a @ [0.0, 0.0, -1.0] > np.cos(np.radians(4.0)))
    radial = np.column_stack([np.cos(np.radians(angles)), np.sin(np.radians(angles)), np.zeros(len(angles))])
    assert np.all(np.sum(n_b * radial, axis=1) > np.cos(np.radians(6.0)))
    assert np.degrees(np.arccos(np.median(np.sum(n_b * radial, axis=1)))) < 2.0


def test_too_short_a_seam_or_one_without_both_faces_gives_none(full: FullRes) -> None:
    # two coarse points 1.6 mm apart: fewer than four slab fits
    assert refine_curve(full, 0, 1, arc(R, Z, 180, 183, n=2), SeamParams(), VIEW) is None
    # the regions named are not there: no slab sees two faces
    assert refine_curve(full, 5, 6, arc(R, Z, 150, 210), SeamParams(), VIEW) is None


def test_the_2d_corner_of_two_exact_lines_is_their_intersection() -> None:
    T = np.array([0.0, 1.0, 0.0])  # the slab is the x-z plane; e1 = T x z = (1, 0, 0), e2 = T x e1 = (0, 0, -1)
    s = np.linspace(0.001, 0.008, 20)
    floor = np.column_stack([-s, np.zeros(20), np.zeros(20)])  # z = 0 for x < 0
    wall = np.column_stack([np.zeros(20), np.zeros(20), -s])  # x = 0 towards the viewer (z < 0)
    rel = np.vstack([floor, wall]) + np.array([0.0005, 0.0, 0.0002])  # the corner is off the slab centre
    in_a = np.r_[np.ones(20, bool), np.zeros(20, bool)]
    res = _corner_2d(rel, in_a, ~in_a, T, SeamParams(), to_view=np.array([-0.3, 0.0, -0.3]))
    assert res is not None
    corner, n_a, n_b, rms = res
    np.testing.assert_allclose(corner, [0.0005, 0.0, 0.0002], atol=1e-12)
    np.testing.assert_allclose(n_a, [0.0, 0.0, -1.0], atol=1e-12)  # both towards the viewer
    np.testing.assert_allclose(n_b, [-1.0, 0.0, 0.0], atol=1e-12)
    assert rms < 1e-12
    # two parallel traces have no corner
    parallel = np.vstack([floor, floor + np.array([0.0, 0.0, 0.003])])
    assert _corner_2d(parallel, in_a, ~in_a, T, SeamParams(), VIEW) is None


def test_a_2d_line_fit_drops_an_outlier_and_reports_the_rms_of_the_rest() -> None:
    x = np.linspace(0.0, 0.01, 50)
    p = np.column_stack([x, 0.5 * x + 0.001])
    p[10, 1] += 0.002  # one point 2 mm off the line
    c, d, rms = _fit_line_2d(p, gate=3.0)
    assert abs(abs(d[1] / d[0]) - 0.5) < 1e-9 and rms < 1e-12
    assert abs(c[1] - (0.5 * c[0] + 0.001)) < 1e-12


def test_a_face_seen_beyond_the_incidence_limit_is_not_seen_well() -> None:
    p = np.zeros(3)
    up = np.array([0.0, 0.0, 1.0])
    view_at = np.array([np.sin(np.radians(70.0)), 0.0, np.cos(np.radians(70.0))])  # 70 deg off the normal
    assert _seen_well((p, up, up, 0.0), view_at, SeamParams())
    grazing = np.array([np.sin(np.radians(80.0)), 0.0, np.cos(np.radians(80.0))])
    assert not _seen_well((p, up, up, 0.0), grazing, SeamParams())  # max_incidence_rad is 78 deg
