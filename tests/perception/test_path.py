"""perception.path: path points evenly spaced, torch poses from the two surfaces' normals, angles in radians."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.path import TorchParams, interpolate_rows, sample_uniform, torch_poses


def test_sample_uniform_spaces_points_evenly_at_most_step_apart_ends_included() -> None:
    line = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.023, 0.0]])  # 0.123 m with a corner
    pts, s = sample_uniform(line, 0.01)
    assert len(pts) == 14  # ceil(0.123 / 0.01) + 1
    np.testing.assert_allclose(s, np.linspace(0.0, 0.123, 14), atol=1e-12)
    np.testing.assert_allclose(pts[[0, -1]], line[[0, -1]], atol=1e-12)
    assert np.max(np.linalg.norm(np.diff(pts, axis=0), axis=1)) <= 0.01
    pts2, _ = sample_uniform(np.array([[0.0, 0.0, 0.0], [0.004, 0.0, 0.0]]), 0.01)
    np.testing.assert_allclose(pts2, [[0.0, 0.0, 0.0], [0.004, 0.0, 0.0]])  # never fewer than the two ends


def test_interpolate_rows_keeps_unit_vectors_unit() -> None:
    rows = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    out = interpolate_rows(np.array([0.0, 1.0]), rows, np.array([0.0, 0.5, 1.0]), unit=True)
    h = math.sqrt(0.5)
    np.testing.assert_allclose(out, [[1.0, 0.0, 0.0], [h, h, 0.0], [0.0, 1.0, 0.0]], atol=1e-15)
    raw = interpolate_rows(np.array([0.0, 1.0]), rows, np.array([0.5]), unit=False)
    np.testing.assert_allclose(raw, [[0.5, 0.5, 0.0]])


def test_torch_poses_bisect_the_normals_and_turn_by_the_angles_in_radians() -> None:
    p = np.array([[0.0, 0.0, 0.5], [0.05, 0.0, 0.5], [0.1, 0.0, 0.5]])
    floor = np.tile([0.0, 0.0, -1.0], (3, 1))  # outward normals, towards a camera at the origin
    wall = np.tile([0.0, -1.0, 0.0], (3, 1))
    X = torch_poses(p, floor, wall)
    h = math.sqrt(0.5)
    for Xk, pk in zip(X, p, strict=True):
        np.testing.assert_allclose(Xk[:3, 2], [0.0, h, h], atol=1e-15)  # into the joint: minus the bisector
        np.testing.assert_allclose(Xk[:3, 0], [1.0, 0.0, 0.0], atol=1e-15)  # along the travel
        np.testing.assert_allclose(Xk[:3, 1], np.cross(Xk[:3, 2], Xk[:3, 0]), atol=1e-15)
        np.testing.assert_array_equal(Xk[:3, 3], pk)
    push = torch_poses(p, floor, wall, params=TorchParams(travel_angle_rad=math.radians(10.0)))
    assert math.asin(push[1, :3, 2] @ [1.0, 0.0, 0.0]) == pytest.approx(math.radians(10.0), abs=1e-14)
    work = torch_poses(p, floor, wall, params=TorchParams(work_angle_rad=0.25))
    assert math.acos(work[1, :3, 2] @ X[1, :3, 2]) == pytest.approx(0.25, abs=1e-12)
    np.testing.assert_allclose(work[:, :3, 0], X[:, :3, 0], atol=1e-15)  # the work angle turns about travel


def test_torch_params_refuse_what_is_not_a_torch() -> None:
    with pytest.raises(ValueError, match=r"step_m must be finite and > 0, got 0\.0"):
        TorchParams(step_m=0.0)
    with pytest.raises(ValueError, match=r"work_angle_rad must be within \(-pi/2, pi/2\), got 1.6"):
        TorchParams(work_angle_rad=1.6)
    with pytest.raises(ValueError, match="travel_angle_rad must be within"):
        TorchParams(travel_angle_rad=float("nan"))
