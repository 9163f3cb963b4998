"""perception.organized: smoothing, normals and edges on organized clouds of exactly known planes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.organized import (
    depth_edges,
    downsample_organized,
    normal_edges,
    organized_normals,
    pixel_angle_rad,
    points_at,
    smooth_points,
)

F = 500.0  # focal length, px


def plane_cloud(h: int = 40, w: int = 60, z_of=lambda u, v: np.full_like(u, 0.5)) -> np.ndarray:
    """(H, W, 3) float32 points of a pinhole camera (f = 500 px, centre at the image centre) on z = z_of(u, v)."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = z_of(u, v)
    x = (u - w / 2) / F * z
    y = (v - h / 2) / F * z
    return np.stack([x, y, z], axis=-1).astype(np.float32)


def test_smoothing_keeps_a_plane_and_needs_half_the_window() -> None:
    pts = plane_cloud()
    pts[10:20, 10:20] = np.nan
    sm, ok = smooth_points(pts, window_px=5)
    assert not ok[15, 15] and np.isnan(sm[15, 15]).all()
    assert ok[30, 40] and ok[2, 2]  # 3 x 3 of the 5 x 5 window (9 of 25) is not enough at a corner...
    assert not ok[0, 0]
    np.testing.assert_allclose(sm[30, 40], pts[30, 40], atol=1e-6)  # a plane's box mean is on the plane


def test_normals_of_a_fronto_parallel_plane_face_the_camera() -> None:
    n = organized_normals(plane_cloud(), window_px=5, step_px=2)
    np.testing.assert_allclose(n[20, 30], [0.0, 0.0, -1.0], atol=1e-6)
    assert np.isnan(n[0, 0]).all()


def test_a_fold_is_a_normal_edge_and_a_step_a_depth_edge() -> None:
    # a floor at z = 0.5 for u < 30 and a 45 degree slope beyond it: a fold along u = 30
    fold = plane_cloud(z_of=lambda u, v: 0.5 + np.maximum(u - 30, 0) * 0.001)
    n = organized_normals(fold, window_px=3, step_px=1)
    edges = normal_edges(n, max_angle_rad=math.radians(10.0), step_px=1)
    # the fold's three pixels, and the image border where the normals are undefined
    np.testing.assert_array_equal(np.flatnonzero(edges[20]), [0, 1, 29, 30, 31, 58, 59])
    step = plane_cloud(z_of=lambda u, v: np.where(u < 30, 0.5, 0.52))
    jumps = depth_edges(step, jump_m=0.005)
    np.testing.assert_array_equal(np.flatnonzero(jumps[20]), [29, 30])


def test_pixel_angle_and_downsampling() -> None:
    pts = plane_cloud()
    assert pixel_angle_rad(pts) == pytest.approx(1.0 / F, rel=1e-6)
    small = downsample_organized(pts, 4)
    assert small.shape == (10, 15, 3) and np.array_equal(small[1, 2], pts[4, 8])
    assert downsample_organized(pts, 1) is pts


def test_points_at_are_the_pixels_points_in_order_as_float64() -> None:
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(40, 60, 3)).astype(np.float32)
    pts[5, 7] = np.nan
    rows = np.array([5, 0, 39, 12, 12], dtype=np.intp)
    cols = np.array([7, 0, 59, 3, 4], dtype=np.intp)
    got = points_at(pts, rows, cols)
    assert got.dtype == np.float64 and got.shape == (5, 3)
    assert np.array_equal(got, pts[rows, cols].astype(np.float64), equal_nan=True)
    assert np.isnan(got[0]).all() and got[2].tolist() == pts[39, 59].astype(np.float64).tolist()
    assert points_at(pts, rows[:0], cols[:0]).shape == (0, 3)
