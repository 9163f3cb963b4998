"""The cylinder fit: exact on exact points of a cylinder, none for a plane."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from perception.fine.cylinder import (
    MAX_RADIUS_M,
    _radial,
    _settle,
    _soft_l1_cylinder,
    _turning_start,
    axis_basis,
    fit_cylinder,
)
from perception.fits import median, percentile


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


def _pipe(seed: int) -> tuple[np.ndarray, tuple, float, float, np.ndarray, np.ndarray]:
    """Half a pipe (radius 15-60 mm, 0.5 m off, 0.2-1 mm of noise along the rays) as (3, N) rows, a start three
    degrees, two millimetres and a fifth of its radius off (rows, axis, centre, radius), and the truth."""
    rng = np.random.default_rng(seed)
    radius, noise = rng.uniform(0.015, 0.06), rng.uniform(2e-4, 1e-3)
    axis = np.array([1.0, rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)])
    axis /= np.linalg.norm(axis)
    e1, e2 = axis_basis(axis)
    centre = np.array([0.0, 0.0, 0.5]) + rng.uniform(-0.02, 0.02, 3)
    ang = rng.uniform(np.pi, 2 * np.pi, 3000)
    along = rng.uniform(-0.1, 0.1, 3000)
    p = centre + radius * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2) + along[:, None] * axis
    p *= 1.0 + rng.normal(0.0, noise, (3000, 1)) / p[:, 2:3]  # along the rays
    tilted = axis + 0.05 * e1
    tilted /= np.linalg.norm(tilted)
    start_centre = centre + 0.002 * e2 - float((centre + 0.002 * e2) @ tilted) * tilted
    return np.ascontiguousarray(p.T), (tilted, start_centre, 1.2 * radius), radius, noise, axis, centre


@pytest.mark.parametrize("seed", range(6))
def test_the_settle_is_scipys_soft_l1_least_squares_fit(seed: int) -> None:
    """The compiled settle against ``scipy.optimize.least_squares(loss="soft_l1")`` on the same residuals (the
    start's worst 30% left out, the same scale and variables, scipy to 1e-12): the same cylinder to a
    micrometre (the settle stops when a step gains less than 1e-6 of the cost), within the noise of the true
    pipe."""
    from scipy.optimize import least_squares

    rows, (axis0, centre0, r0), radius, noise, axis, centre = _pipe(seed)
    e1, e2 = axis_basis(axis0)

    def resid(x: np.ndarray, pts: np.ndarray) -> np.ndarray:
        a = axis0 + x[0] * e1 + x[1] * e2
        return _radial(pts, centre0 + x[2] * e1 + x[3] * e2, a / np.linalg.norm(a))[2] - x[4]

    x0 = np.array([0.0, 0.0, 0.0, 0.0, r0])
    first = np.abs(resid(x0, rows))
    kept = rows[:, first <= percentile(first, 70)]
    f_scale = max(float(median(np.abs(resid(x0, kept)))) + 1e-6, 1e-4)
    ref = least_squares(resid, x0, args=(kept,), loss="soft_l1", f_scale=f_scale,
                        x_scale=np.array([0.05, 0.05, r0, r0, r0]), ftol=1e-12, xtol=1e-12).x  # fmt: skip
    got = _settle(rows, axis0, centre0, r0)
    assert got is not None
    a_ref = (axis0 + ref[0] * e1 + ref[1] * e2) / np.linalg.norm(axis0 + ref[0] * e1 + ref[1] * e2)
    np.testing.assert_allclose(got[0], a_ref, atol=1e-5)
    np.testing.assert_allclose(got[1], centre0 + ref[2] * e1 + ref[3] * e2, atol=1e-6)
    assert abs(got[2] - ref[4]) < 1e-6
    assert abs(got[2] - radius) < 3 * noise and abs(abs(float(got[0] @ axis)) - 1.0) < 1e-3
    assert np.linalg.norm(np.cross(got[1] - centre, axis)) < 3 * noise


def test_a_flat_patchs_radius_runs_off_and_a_fit_still_moving_at_its_limit_is_not_settled() -> None:
    """A flat patch (a plate under 0.2 mm of noise) from a 0.4 m cylinder: the radius runs past MAX_RADIUS_M
    and the fit gives up there (no cylinder); a pipe's fit held to three evaluations is not settled."""
    rng = np.random.default_rng(1)
    flat = np.vstack([rng.uniform(-0.1, 0.1, 2000), rng.uniform(-0.1, 0.1, 2000), 0.5 + rng.normal(0, 2e-4, 2000)])
    e1, e2 = axis_basis(np.array([1.0, 0.0, 0.0]))
    x, settled = _soft_l1_cylinder(flat, np.array([1.0, 0.0, 0.0]), e1, e2, np.array([0.0, 0.0, 0.9]), 0.4, 2e-4,
                                   np.array([0.05, 0.05, 0.4, 0.4, 0.4]), 200, MAX_RADIUS_M)  # fmt: skip
    assert not settled and x[4] > MAX_RADIUS_M
    assert _settle(flat, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.9]), 0.4) is None
    rows, (axis0, centre0, r0), *_ = _pipe(0)
    e1, e2 = axis_basis(axis0)
    x, settled = _soft_l1_cylinder(rows, axis0, e1, e2, centre0, 3 * r0, 1e-4, np.full(5, 0.05), 3, MAX_RADIUS_M)
    assert not settled
