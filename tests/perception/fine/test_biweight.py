"""perception.fine.biweight: a plane fitted with Tukey's biweight (compiled)."""

from __future__ import annotations

import numpy as np

from perception.fine.biweight import SETTLED_M, TUKEY_C, biweight_plane
from perception.fine.surfaces import _fit_plane


def _numpy_biweight(p: np.ndarray, weights: np.ndarray, iterations: int = 8) -> tuple[np.ndarray, float]:
    """The biweight as the refinement took it before it was compiled (NumPy calls), the reference."""
    n, off, _ = _fit_plane(p, weights)
    reach = float(np.sqrt(np.max(np.sum(p * p, axis=1))))
    for _ in range(iterations):
        r = p @ n + off
        scale = 1.4826 * float(np.median(np.abs(r)))
        if scale <= 0.0:
            break
        x = r / (TUKEY_C * scale)
        w = weights * np.where(np.abs(x) < 1, (1 - x * x) ** 2, 0)
        if w.sum() <= 0.0 or np.count_nonzero(w) < 10:
            break
        n_new, off_new, _ = _fit_plane(p, w)
        moved = abs(off_new - off) + float(np.linalg.norm(n_new - n)) * reach
        n, off = n_new, off_new
        if moved < SETTLED_M:
            break
    return n, off


def test_a_noise_free_plane_is_its_exact_plane_facing_the_camera() -> None:
    # z = 0.5 + 0.2 x - 0.1 y: normal (0.2, -0.1, -1) / |.| (towards the camera at the origin), offset 0.5 / |.|
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.05, 0.05, (500, 2))
    p = np.column_stack([xy, 0.5 + 0.2 * xy[:, 0] - 0.1 * xy[:, 1]])
    n, off = biweight_plane(p, np.ones(len(p)))
    k = np.linalg.norm([0.2, -0.1, -1.0])
    np.testing.assert_allclose(n, np.array([0.2, -0.1, -1.0]) / k, atol=1e-12)
    assert abs(off - 0.5 / k) < 1e-12
    assert np.abs(p @ n + off).max() < 1e-12


def test_a_few_points_of_another_surface_do_not_tilt_a_narrow_face() -> None:
    # a face 9 mm across and 60 mm long with 0.3 mm of noise, and along one of its edges four points of the
    # next surface 3 mm off it (the last pixel row of a convex edge): least squares tilts the face by degrees
    # (4.8); Tukey's biweight stays within 0.3 degrees of the face's own plane (the plane of its points alone,
    # itself uncertain by 0.6 degrees at this noise: the two estimators weigh the face's own tails differently)
    rng = np.random.default_rng(3)
    n = 120
    x, y = rng.uniform(0.0, 0.060, n), rng.uniform(0.0, 0.009, n)
    face = np.column_stack([x, y, 0.8 + 3e-4 * rng.standard_normal(n)])
    stray = np.column_stack([rng.uniform(0.0, 0.060, 4), np.full(4, 0.0092), np.full(4, 0.8 - 0.003)])
    pts = np.concatenate([face, stray])
    w = np.ones(len(pts))
    own = _fit_plane(face)[0]

    def degrees_off(normal: np.ndarray) -> float:
        return float(np.degrees(np.arccos(min(1.0, abs(float(normal @ own))))))

    assert degrees_off(_fit_plane(pts, w)[0]) > 3.0
    assert degrees_off(biweight_plane(pts, w)[0]) < 0.3


def test_the_biweight_stops_when_settled_within_a_micrometre_of_its_full_run() -> None:
    """A plate's points (0.5 mm noise) with a tenth of them from another face 5 mm off: the biweight stops once
    the plane moves less than SETTLED_M at the farthest point, and lands within that of the plane all eight
    iterations give; both within 0.05 mm of the true plane (z = 0.6 m)."""
    rng = np.random.default_rng(3)
    p = np.column_stack([rng.uniform(-0.05, 0.05, 4000), rng.uniform(-0.05, 0.05, 4000), np.full(4000, 0.6)])
    p[:, 2] += rng.normal(0.0, 0.0005, 4000)
    p[:400, 2] -= 0.005
    w = np.ones(len(p))
    n_settled, off_settled = biweight_plane(p, w)
    n_full, off_full = biweight_plane(p, w, settled_m=0.0)
    reach = float(np.linalg.norm(p, axis=1).max())
    assert abs(off_settled - off_full) + np.linalg.norm(n_settled - n_full) * reach < 2 * SETTLED_M
    for n, off in ((n_settled, off_settled), (n_full, off_full)):
        assert abs(n[2]) > np.cos(np.radians(0.1)) and abs(abs(off) - 0.6) < 5e-5


def test_the_compiled_fit_is_the_numpy_fit_to_rounding() -> None:
    """Against the NumPy reference on weighted faces with strays, a few hundred to 30 000 points: the planes
    agree to 1e-12 m at the farthest point (sums taken in another order), and a fit that stops on fewer than
    ten weighted points keeps its least-squares plane in both."""
    rng = np.random.default_rng(7)
    for trial in range(12):
        m = int(rng.integers(300, 30000))
        normal = rng.normal(size=3)
        normal[2] = -abs(normal[2]) - 1.0
        normal /= np.linalg.norm(normal)
        u = np.cross(normal, [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(normal, u)
        p = np.array([0.0, 0.0, 0.7]) + rng.uniform(-0.05, 0.05, (m, 1)) * u + rng.uniform(-0.05, 0.05, (m, 1)) * v
        p += rng.normal(0.0, 3e-4, (m, 1)) * normal
        p[: m // 10] += 0.004 * normal  # a tenth of them off the face
        w = np.where(rng.uniform(size=m) < 0.5, 1.0, 4.0)
        got, want = biweight_plane(p, w), _numpy_biweight(p, w)
        reach = float(np.linalg.norm(p, axis=1).max())
        assert abs(got[1] - want[1]) + np.linalg.norm(got[0] - want[0]) * reach < 1e-12, trial
    few = np.array([[0.0, 0.0, 0.5], [0.01, 0.0, 0.5], [0.0, 0.01, 0.5], [0.01, 0.01, 0.5001], [0.02, 0.0, 0.5]])
    got, want = biweight_plane(few, np.ones(5)), _numpy_biweight(few, np.ones(5))
    np.testing.assert_allclose(got[0], want[0], atol=1e-12)
