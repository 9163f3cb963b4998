"""The cylinder fit: exact on exact points of a cylinder, none for a plane."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from perception.fine.cylinder import (
    MAX_EVALUATIONS,
    MAX_RADIUS_M,
    _radial,
    _settle,
    _turning_start,
    axis_basis,
    fit_cylinder,
)
from perception.fits import median, percentile, soft_l1_least_squares


def test_fit_cylinder_is_exact_on_exact_points_and_refuses_a_plane() -> None:
    rng = np.random.default_rng(0)
    ang = rng.uniform(0, np.pi, 500)
    h = rng.uniform(0, 0.1, 500)
    axis = np.array([0.0, 0.6, 0.8])
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(axis, e1)
    c = np.array([0.01, 0.02, 0.5])
    p = c + 0.025 * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2) + h[:, None] * axis
    n = np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2
    fit = fit_cylinder(p, n)
    assert fit is not None
    a, centre, r, rms = fit
    assert r == pytest.approx(0.025, abs=1e-7) and rms < 1e-7 and abs(abs(a @ axis) - 1) < 1e-9
    assert np.linalg.norm(np.cross(centre - c, axis)) < 1e-7
    flat = np.column_stack([rng.uniform(0, 0.1, 100), rng.uniform(0, 0.1, 100), np.full(100, 0.5)])
    assert fit_cylinder(flat, np.tile([0.0, 0.0, -1.0], (100, 1))) is None


def test_a_circle_fitted_by_distances_holds_its_radius_where_the_algebraic_fit_shrinks_it() -> None:
    """A 30 mm pipe's arc as a camera sees it (160 degrees facing it), each point moved 1 mm (sigma) along the
    rays: over 50 draws the algebraic fit's radius comes out 0.24 mm short on average, the fit by distances
    0.06 mm; both scatter by 0.06 mm."""
    from perception.fine.cylinder import circle_across, circle_fit_across

    radius, axis = 0.03, np.array([0.0, 0.0, 1.0])
    algebraic, geometric = [], []
    for seed in range(50):
        rng = np.random.default_rng(seed)
        th = rng.uniform(np.radians(100), np.radians(260), 800)
        p = np.column_stack([radius * np.cos(th) + rng.normal(0.0, 0.001, 800), radius * np.sin(th),
                             rng.uniform(0.0, 0.02, 800)])  # fmt: skip
        algebraic.append(circle_across(p, axis)[1] - radius)
        centre, r = circle_fit_across(p, axis)
        geometric.append(r - radius)
        assert np.linalg.norm(centre[:2]) < 0.0005
    assert np.mean(algebraic) < -0.00015 and abs(np.mean(geometric)) < 0.0001
    assert circle_fit_across(np.zeros((5, 3)), axis) is None


@pytest.mark.parametrize("inside", [False, True])
def test_the_turning_start_is_exact_on_exact_points_seen_from_outside_or_inside(inside: bool) -> None:
    """The radius from how fast exact normals turn across the axis, and the centre a radius behind each point
    (in front of it, for a cylinder seen from inside): exact."""
    rng = np.random.default_rng(3)
    axis = np.array([0.2, 0.6, 0.7]) / np.linalg.norm([0.2, 0.6, 0.7])
    e1, e2 = axis_basis(axis)
    centre = np.array([0.05, -0.02, 0.8])
    theta, h = rng.uniform(-1.2, 1.2, 500), rng.uniform(0.0, 0.05, 500)
    radial = np.outer(np.cos(theta), e1) + np.outer(np.sin(theta), e2)
    points = centre + 0.019 * radial + np.outer(h, axis)
    normals = -radial if inside else radial  # towards the viewer: out of a pipe, into a bore
    start = _turning_start(points, normals, axis)
    assert start is not None
    c, r = start
    assert r == pytest.approx(0.019, abs=1e-9)
    on_plane = centre - (centre @ axis) * axis  # the centre on the plane across the axis through the origin
    assert np.allclose(c, on_plane, atol=1e-9)


def test_a_small_pipe_under_high_noise_gets_its_own_radius_not_the_algebraic_circles() -> None:
    """Zoo dev pipe 11: a pipe of 19 mm radius standing on a plate 0.78 m away, under the high-noise stereo
    (1.2 mm at its depth). The algebraic circle of its front's noisy arc was 48 mm and the fit settled near it
    (47 mm, the axis 4 degrees off the plate's normal): the ring was 1.0 mm off its truth at the median and
    2.5 mm at worst. From the normals' turning the fit finds the pipe's own radius."""
    from perception.detect import DetectParams
    from perception.detect_surfaces import detect_surfaces
    from perception.evaluate import point_to_polyline_distance
    from perception.transforms import invert_X, transform_points
    from sim_fakes.zoo import draw_capture

    zc = draw_capture("pipe", 11)
    (whole,) = zc.result.scene.seams  # the ring, whole (the seam found runs a little past its seen part)
    truth = transform_points(invert_X(zc.result.X_world_camera), whole.points)
    res = detect_surfaces(zc.result.capture, DetectParams(method="surfaces"))
    (seam,) = res.seams
    assert seam.kind == "curved"
    err = point_to_polyline_distance(seam.points, truth)
    assert float(np.median(err)) < 0.3e-3 and float(err.max()) < 0.5e-3
    (cylinder,) = [s for s in res.artifacts["surfaces"].surfaces if s.kind == "cylinder"]
    assert cylinder.radius == pytest.approx(0.019, abs=0.002)


def test_a_blurred_convex_edge_left_between_two_walls_is_no_cylinder(tmp_path: Path) -> None:
    """Zoo dev open box 112 (0.34 m), as the bench reads it (saved and loaded): the band along two walls'
    rounded, blurred convex edge is left between the grown walls as a narrow piece. Its normals turn with the
    blur, and a start from their turning fitted it as a 9 mm cylinder that took the walls' inside corner seam
    with it; a narrow piece's fit starts from the algebraic circle alone. No cylinder, and each inside corner
    that is seen is found."""
    from cell.zoo_bench import ensure_capture
    from perception.capture import load_capture
    from perception.detect import DetectParams
    from perception.detect_surfaces import detect_surfaces
    from perception.evaluate import point_to_polyline_distance

    cap = load_capture(ensure_capture(tmp_path, "open_box", 112))
    res = detect_surfaces(cap, DetectParams(method="surfaces"))
    assert not [s for s in res.artifacts["surfaces"].surfaces if s.kind == "cylinder"]
    truths = [t for t in cap.ground_truth or () if t.joint == "inside_corner"]
    assert truths
    for truth in truths:
        near = [s for s in res.seams if float(np.median(point_to_polyline_distance(s.points, truth.points_camera)))
                < 1e-3]  # fmt: skip
        assert len(near) == 1 and near[0].joint == "inside_corner"


def _settle_by_reference(rows: np.ndarray, axis: np.ndarray, centre: np.ndarray, r: float):
    """The cylinder's settle as NumPy closures handed to the generic solver (what it was before it was compiled)."""
    e1, e2 = axis_basis(axis)
    scale = max(r, 1e-3)

    def resid(x: np.ndarray) -> np.ndarray:
        a = axis + x[0] * e1 + x[1] * e2
        a /= np.linalg.norm(a)
        return _radial(rows, centre + x[2] * e1 + x[3] * e2, a)[2] - x[4]

    def jac(x: np.ndarray) -> np.ndarray:
        b = axis + x[0] * e1 + x[1] * e2
        nb = float(np.linalg.norm(b))
        da, radial, length = _radial(rows, centre + x[2] * e1 + x[3] * e2, b / nb)
        n = (radial / np.maximum(length, 1e-12)).T
        n1, n2 = n @ e1, n @ e2
        return np.column_stack([-da * n1 / nb, -da * n2 / nb, -n1, -n2, -np.ones(len(da))])

    x0 = np.array([0.0, 0.0, 0.0, 0.0, r])
    r0 = resid(x0)
    rows = rows[:, np.abs(r0) <= percentile(np.abs(r0), 70)]
    sig0 = float(median(np.abs(resid(x0)))) + 1e-6
    x, settled = soft_l1_least_squares(resid, jac, x0, f_scale=max(sig0, 1e-4),
                                       x_scale=np.array([0.05, 0.05, scale, scale, scale]),
                                       max_evaluations=MAX_EVALUATIONS, give_up=lambda x: bool(x[4] > MAX_RADIUS_M))
    if not settled or x[4] <= 0:
        return None
    a = axis + x[0] * e1 + x[1] * e2
    return a / np.linalg.norm(a), centre + x[2] * e1 + x[3] * e2, float(x[4])


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_settle_is_the_generic_soft_l1_solvers_fit(seed: int) -> None:
    """A pipe (radius 15-60 mm, 0.5 m off, 0.2-1 mm of noise along the rays) from a start three degrees, two
    millimetres and a fifth of its radius off: the compiled fit lands where the generic solver
    on NumPy closures lands (to 1e-9, the sums run in another order), within the noise of the true pipe; a
    nearly flat patch runs off past MAX_RADIUS_M in both and is no cylinder."""
    rng = np.random.default_rng(seed)
    radius, noise = rng.uniform(0.015, 0.06), rng.uniform(2e-4, 1e-3)
    axis = np.array([1.0, rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)])
    axis /= np.linalg.norm(axis)
    e1, e2 = axis_basis(axis)
    centre = np.array([0.0, 0.0, 0.5]) + rng.uniform(-0.02, 0.02, 3)
    ang = rng.uniform(np.pi, 2 * np.pi, 3000)  # half of it
    along = rng.uniform(-0.1, 0.1, 3000)
    p = centre + radius * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2) + along[:, None] * axis
    p *= 1.0 + rng.normal(0.0, noise, (3000, 1)) / p[:, 2:3]  # along the rays
    rows = np.ascontiguousarray(p.T)
    tilted = axis + 0.05 * e1
    tilted /= np.linalg.norm(tilted)
    start = (rows, tilted, centre + 0.002 * e2 - float((centre + 0.002 * e2) @ tilted) * tilted, 1.2 * radius)
    got, want = _settle(*start), _settle_by_reference(*start)
    assert got is not None and want is not None
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, atol=1e-9)
    a, c, r = got
    assert abs(r - radius) < 3 * noise and abs(abs(float(a @ axis)) - 1.0) < 1e-3
    assert np.linalg.norm(np.cross(c - centre, axis)) < 3 * noise
    flat = np.vstack([rng.uniform(-0.1, 0.1, 2000), rng.uniform(-0.1, 0.1, 2000), 0.5 + rng.normal(0, 2e-4, 2000)])
    start_flat = (flat, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.9]), 0.4)
    assert _settle(*start_flat) is None and _settle_by_reference(*start_flat) is None

