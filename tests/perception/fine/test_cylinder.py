"""The cylinder fit: exact on exact points of a cylinder, none for a plane."""

from __future__ import annotations

import numpy as np
import pytest

from perception.fine.cylinder import fit_cylinder


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
