"""perception.fits: planes, lines and their intersection, coordinates along a line, order along a curve."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.fits import (
    connected_components,
    cross3,
    fit_line,
    fit_plane,
    fit_plane_robust,
    line_coordinates,
    mean_rows,
    neighbour_components,
    order_along_curve,
    orient_towards,
    outer_boundary,
    percentile,
    plane_intersection,
    sum_rows,
    trimmed_line,
)


def _grid_on_plane(c: np.ndarray, n: np.ndarray, size: int = 11) -> np.ndarray:
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    a, b = np.meshgrid(np.linspace(-0.05, 0.05, size), np.linspace(-0.05, 0.05, size))
    return c + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v


def test_fit_plane_recovers_an_exact_plane_and_its_rms() -> None:
    n = np.array([1.0, 2.0, 2.0]) / 3.0
    c = np.array([0.1, -0.2, 0.5])
    pts = _grid_on_plane(c, n)
    centre, normal, rms = fit_plane(pts)
    np.testing.assert_allclose(centre, c, atol=1e-15)
    assert abs(normal @ n) == pytest.approx(1.0, abs=1e-14) and rms < 1e-15
    # half the points 1 mm above, half 1 mm below: RMS exactly 1 mm
    offset = np.where(np.arange(len(pts)) % 2 == 0, 0.001, -0.001)[:, None] * n
    assert fit_plane(pts + offset)[2] == pytest.approx(0.001 * math.sqrt(1 - 1 / len(pts) ** 2), rel=1e-6)


def test_fit_plane_robust_drops_the_outliers() -> None:
    n = np.array([0.0, 0.0, 1.0])
    pts = _grid_on_plane(np.zeros(3), n)
    noisy = pts + np.where(np.arange(len(pts)) % 2 == 0, 1e-4, -1e-4)[:, None] * n
    outliers = np.array([[0.0, 0.0, 0.02], [0.01, 0.01, -0.03]])
    _, normal, rms, keep = fit_plane_robust(np.vstack([noisy, outliers]))
    assert keep.sum() == len(pts) and not keep[-2:].any()
    assert abs(normal[2]) == pytest.approx(1.0, abs=1e-12) and rms == pytest.approx(1e-4, rel=1e-3)


def test_fit_line_and_line_coordinates() -> None:
    d = np.array([3.0, 4.0, 0.0]) / 5.0
    pts = np.array([0.1, 0.2, 0.3]) + np.outer(np.linspace(-0.5, 1.0, 7), d)
    c, direction = fit_line(pts)
    np.testing.assert_allclose(c, pts.mean(axis=0), atol=1e-15)
    assert abs(direction @ d) == pytest.approx(1.0, abs=1e-14)
    t, dist = line_coordinates(np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 2.0]]), np.zeros(3), d)
    np.testing.assert_allclose(t, [0.0, 5.0], atol=1e-15)
    np.testing.assert_allclose(dist, [0.0, 2.0], atol=1e-7)


def test_plane_intersection_is_the_point_of_the_line_nearest_to_the_hint() -> None:
    # floor z = 0 and wall y = 0.2 meet along x at (., 0.2, 0)
    point, d = plane_intersection(
        np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.2, 0.0]), np.array([0.0, 1.0, 0.0]),
        np.array([0.3, 1.0, 1.0]),
    )  # fmt: skip
    np.testing.assert_allclose(point, [0.3, 0.2, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.abs(d), [1.0, 0.0, 0.0], atol=1e-15)


def test_orient_towards_turns_a_normal_to_the_viewpoint() -> None:
    n = np.array([0.0, 0.0, 1.0])
    np.testing.assert_array_equal(orient_towards(n, np.zeros(3), np.array([0.0, 0.0, -1.0])), -n)
    np.testing.assert_array_equal(orient_towards(n, np.zeros(3), np.array([0.0, 0.0, 2.0])), n)


def test_components_and_the_order_along_a_curve() -> None:
    arc = np.array([[math.cos(a), math.sin(a), 0.0] for a in np.linspace(0.0, math.pi / 2, 31)]) * 0.1
    far = arc + np.array([1.0, 0.0, 0.0])
    lab = connected_components(np.vstack([arc, far]), radius=0.01)
    assert len(set(lab[:31])) == 1 and len(set(lab[31:])) == 1 and lab[0] != lab[31]
    shuffled = np.random.default_rng(0).permutation(31)
    s = order_along_curve(arc[shuffled], radius=0.01)
    chord = 2 * 0.1 * math.sin(math.pi / 4 / 30)  # neighbours along the arc
    expected = np.arange(31) * chord
    got = s[np.argsort(shuffled)]
    if got[0] > got[-1]:  # either end may be the start
        got = got.max() - got
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_scan_lines_far_apart_join_and_a_floating_cluster_does_not() -> None:
    """A LiDAR-like scan: a table's lines 1 mm apart along them and 4 mm across; a wall standing on it seen at a
    slant, its lines 6 mm apart (six in-line spacings) and the first 6 mm over the table; a 20 x 20 mm bracket
    sampled on a 2 mm grid 20 mm over the wall's top. Joined to their 16 nearest, the table and wall are one
    piece and the bracket another; three in-line spacings part the wall's lines."""
    s = np.arange(0.0, 0.2, 0.001)
    table = np.array([[x, y, 0.0] for y in np.arange(0.0, 0.2, 0.004) for x in s])
    wall = np.array([[x, 0.1, z] for z in np.arange(0.006, 0.1, 0.006) for x in s])
    g = np.arange(0.0, 0.02, 0.002)
    bracket = np.array([[0.1 + a, 0.09 + b, 0.116] for a in g for b in g])
    lab = neighbour_components(np.vstack([table, wall, bracket]), 16)
    n_t, n_w = len(table), len(wall)
    assert len(np.unique(lab[: n_t + n_w])) == 1
    assert len(np.unique(lab[n_t + n_w :])) == 1 and lab[-1] != lab[0]
    assert len(np.unique(connected_components(np.vstack([table, wall]), 0.003))) > 10
    # too few points to have neighbours: one piece each
    assert neighbour_components(np.zeros((1, 3)), 16).tolist() == [0]


@pytest.mark.parametrize("order", ["C", "F", "strided"])
def test_sum_rows_and_mean_rows_are_numpys_own_values_bit_for_bit(order: str) -> None:
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 1000, 40001):
        p = rng.normal(size=(2 * n, 3)) * 0.01 + [0.1, -0.2, 0.6]
        w = rng.uniform(0.0, 2.0, size=2 * n)
        p, w = (p[::2], w[::2]) if order == "strided" else (np.asarray(p[:n], order=order), w[:n])
        assert np.array_equal(sum_rows(p), p.sum(axis=0))
        assert np.array_equal(sum_rows(p, w), (w[:, None] * p).sum(axis=0))
        assert np.array_equal(mean_rows(p), p.mean(axis=0))


def test_percentile_is_numpys_own_value_bit_for_bit() -> None:
    """Every percentile NumPy's default (linear) method gives, the very value: sizes 2 to 20 000, ties, a NaN (NaN
    as NumPy), infinities (their NaN differences as NumPy's), the ends 0 and 100."""
    rng = np.random.default_rng(5)
    qs = (0, 1, 2.5, 5, 10, 25, 50, 60, 75, 80, 90, 95, 97, 98, 99.0, 100, 33.3)
    for trial in range(1500):
        n = int(rng.integers(2, 200)) if trial % 10 else int(rng.integers(2, 20000))
        a = rng.normal(size=n) * 10.0 ** rng.uniform(-4, 2)
        if trial % 7 == 0:
            a = np.round(a, 1)  # ties
        for every, value in ((13, np.nan), (17, np.inf), (19, -np.inf)):
            if trial % every == 0:
                a[rng.integers(n)] = value
        q = qs[trial % len(qs)]
        with np.errstate(invalid="ignore"):
            assert np.array_equal(percentile(a, q), np.percentile(a, q), equal_nan=True), (n, q)
    # the blend itself: 99th of 0..10 is 9.9 by the upper value's side (weight 0.9), 12.5th of 0, 8 is 1
    assert percentile(np.arange(11.0), 99.0) == np.float64(10.0) - np.float64(1.0) * (1.0 - (10 * 0.99 - 9))
    assert percentile(np.array([8.0, 0.0]), 12.5) == 1.0
    # not a 1-D float64 array: NumPy's own answer
    assert percentile(np.array([[1.0, 3.0], [2.0, 4.0]]), 50) == 2.5 and percentile(np.array([1, 2, 3, 4]), 50) == 2.5


def test_cross3_is_numpys_cross_bit_for_bit() -> None:
    rng = np.random.default_rng(6)
    for _ in range(2000):
        a, b = rng.normal(size=3) * 10.0 ** rng.uniform(-3, 3), rng.normal(size=3)
        assert np.array_equal(cross3(a, b), np.cross(a, b))
    assert cross3(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])).tolist() == [0.0, 0.0, 1.0]


def test_a_trimmed_line_ignores_a_third_of_its_points_on_another_face() -> None:
    """A lap's edge face at 1.6 mm across, rising 0.4 mm over 200 mm, its points with 0.15 mm of noise; near the
    plate's corner (the first 20 mm) 150 more points lie on the plate's end face, 5 mm inside it (a third of
    all). The line is the face's within 0.05 mm all along; a first least-squares fit on every point would turn
    towards the end face (its offset at the corner 2 mm off)."""
    rng = np.random.default_rng(4)
    t = rng.uniform(-0.10, 0.10, 300)
    a = 0.0016 + 0.002 * t + rng.normal(0.0, 0.00015, 300)
    t_end = rng.uniform(-0.10, -0.08, 150)
    a_end = -0.0034 + rng.normal(0.0, 0.0003, 150)
    off, slope = trimmed_line(np.concatenate([t, t_end]), np.concatenate([a, a_end]))
    for tt in (-0.1, 0.0, 0.1):
        assert abs(off + slope * tt - (0.0016 + 0.002 * tt)) < 5e-5


def test_an_outer_boundary_is_the_line_of_each_bins_outermost_point_and_a_ragged_one_is_none() -> None:
    """A face's points fill 0 <= out <= 5 mm + 0.05 along over 40 mm along, one sample every 0.5 mm both ways:
    the boundary is the line through the outermost samples (up to a grid step inside the edge); two strays 1.5
    mm beyond it (mixed pixels) do not move it. Cut unevenly by +-1 mm from bin to bin, it scatters past a 0.3
    mm tolerance: None. Fewer than five bins: None."""
    along, out = np.meshgrid(np.arange(0.0, 0.04, 0.0005), np.arange(0.0, 0.0101, 0.0005))
    along, out = along.ravel(), out.ravel()
    face = out <= 0.005 + 0.05 * along
    strays = np.array([0.010, 0.030])
    a = np.concatenate([along[face], strays])
    o = np.concatenate([out[face], 0.005 + 0.05 * strays + 0.0015])
    off, slope = outer_boundary(a, o, 0.002, 0.0003)
    for x in (0.0, 0.02, 0.04):
        assert -0.0005 <= off + slope * x - (0.005 + 0.05 * x) <= 1e-9
    block = np.round(along / 0.0005).astype(int) // 8  # 4 mm blocks: two bins each
    ragged = out <= 0.004 + 0.001 * np.where(block % 2 == 0, 1.0, -1.0)
    assert outer_boundary(along[ragged], out[ragged], 0.002, 0.0003) is None
    short = along < 0.008
    assert outer_boundary(along[short & face], out[short & face], 0.002, 0.0003) is None
