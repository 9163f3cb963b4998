"""A V-groove's open root fitted as a profile to the pixels' ranges: rays traced through an exact groove
section (two 30-degree bevels, root faces, a gap and the table below) with depth noise."""

from __future__ import annotations

import numpy as np
import pytest

from perception.fine.root import _section_profile, open_root
from perception.fine.types import Surface

BETA = np.radians(30.0)  # the bevels from the vertical


def _trace(gap: float, root: float, *, sigma: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of the groove seen from a camera at the origin looking along +z: the groove's section in the
    camera's x/z plane, its root line along y, 0.6 m away; the points, their sigma, and the bevels'
    intersection (a point on it)."""
    rng = np.random.default_rng(seed)
    z_root = 0.6  # the camera looks along +z; up (out of the groove) is -z
    x_edge = gap / 2
    tan_b = np.tan(BETA)
    # the bevels run up (towards the camera) from the root edges at (+-x_edge, root); the intersection is
    # (g/2) cot(beta) below the root
    z_int = z_root + x_edge / tan_b
    pts = []
    for y in np.linspace(-0.05, 0.05, 120):
        for x_px in rng.uniform(-0.004, 0.004, 60):  # rays through the section, 0.13 mm apart at the root
            d = np.array([x_px / z_root, y / z_root, 1.0])
            d /= np.linalg.norm(d)
            hits = []
            for sign in (-1.0, 1.0):  # bevel: x = sign * (x_edge + (z_root - z) * tan_b), above the edge
                # points on the bevel: sign*x - x_edge = (z_root - z) tan_b  ->  solve along the ray
                lam = (x_edge + z_root * tan_b) / (sign * d[0] + d[2] * tan_b)
                p = lam * d
                if lam > 0 and p[2] <= z_root and sign * p[0] >= x_edge:
                    hits.append(lam)
                lam_w = sign * x_edge / d[0] if d[0] != 0 else np.inf  # root face, below the edge
                p = lam_w * d
                if lam_w > 0 and z_root <= p[2] <= z_root + root:
                    hits.append(lam_w)
            lam_f = (z_root + root) / d[2]  # the table below the root faces, between them
            if abs((lam_f * d)[0]) <= x_edge:
                hits.append(lam_f)
            if hits:
                lam = min(hits)
                pts.append(d * (lam + rng.normal(0.0, sigma)))
    q = np.array(pts)
    return q, np.full(len(q), sigma), np.array([0.0, 0.0, z_int])


def _faces() -> tuple[tuple[Surface, Surface], tuple[np.ndarray, np.ndarray]]:
    faces = []
    across = []
    for sign in (-1.0, 1.0):
        n = np.array([-sign * np.cos(BETA), 0.0, -np.sin(BETA)])  # towards the camera and the groove's middle
        faces.append(Surface(0, "plane", n, 0.0, 1e-4, 100, np.zeros(3), 0.6))
        across.append(np.array([sign * np.sin(BETA), 0.0, -np.cos(BETA)]))  # up the bevel, away from the root
    return (faces[0], faces[1]), (across[0], across[1])


@pytest.mark.parametrize(("gap", "root"), [(0.0016, 0.001), (0.001, 0.0), (0.002, 0.002)])
def test_the_root_height_and_gap_of_an_open_root(gap: float, root: float) -> None:
    q, sig, line0 = _trace(gap, root, sigma=3e-4, seed=1)
    faces, across = _faces()
    edges = open_root(q, sig, line0, np.array([0.0, 1.0, 0.0]), across, faces, (-0.05, 0.05), radius_m=0.006)
    assert edges is not None
    h_true = (gap / 2) / np.tan(BETA)  # the root above the bevels' intersection
    h = edges[0] * np.cos(BETA)
    assert h == pytest.approx(h_true, abs=1e-4)
    gap_found = 2 * edges[0] * np.sin(BETA)
    assert gap_found == pytest.approx(gap, abs=2e-4)


def test_a_closed_root_stays_at_the_intersection_under_noise() -> None:
    q, sig, line0 = _trace(0.0, 0.0, sigma=5e-4, seed=2)
    faces, across = _faces()
    assert open_root(q, sig, line0, np.array([0.0, 1.0, 0.0]), across, faces, (-0.05, 0.05), radius_m=0.006) is None


def test_the_rays_no_height_changes_are_costed_once_and_the_sum_is_the_same() -> None:
    """The split of a profile into the rays whose trace no candidate height changes (their summed cost) and the
    others: at every height the two add up to the whole profile's cost."""
    q, sig, line0 = _trace(0.0016, 0.001, sigma=3e-4, seed=1)
    faces, across = _faces()
    profile = _section_profile(q, sig, line0, np.array([0.0, 1.0, 0.0]), across, faces, (-0.05, 0.05),
                               radius_m=0.006)  # fmt: skip
    assert profile is not None
    fixed, varying = profile.split(0.003)
    assert 0 < len(varying.rng) < len(profile.rng)
    for h in np.arange(0.0, 0.003, 2e-4):
        assert fixed + varying.cost(float(h)) == pytest.approx(profile.cost(float(h)), rel=1e-12, abs=1e-9)
