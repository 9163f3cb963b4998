"""Fine-stage steps on synthetic clouds with exact answers."""

from __future__ import annotations

import numpy as np
import pytest

from perception.cloud import (
    grow_regions,
    merge_coplanar_regions,
    neighbourhoods,
    normals_and_curvature,
    pass_through,
    smallest_eigenpairs,
    stray_points,
    voxel_downsample,
)


def grid_plane(n: int, spacing: float, origin, u, v) -> np.ndarray:
    a, b = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    return np.asarray(origin) + a.reshape(-1, 1) * np.asarray(u) + b.reshape(-1, 1) * np.asarray(v)


def test_voxel_centroids_are_exact() -> None:
    # two points in voxel (0,0,0), one in (1,0,0), with labels voting
    pts = np.array([[0.0005, 0.0005, 0.0005], [0.0015, 0.0025, 0.0005], [0.0035, 0.0001, 0.0002]])
    grid = voxel_downsample(pts, voxel_m=0.003, labels=np.array([2, 2, 5], np.int32))
    order = np.argsort(grid.centroids[:, 0])
    assert np.allclose(grid.centroids[order], [[0.001, 0.0015, 0.0005], [0.0035, 0.0001, 0.0002]])
    assert grid.counts[order].tolist() == [2, 1]
    assert grid.labels[order].tolist() == [2, 5]
    # every point maps to the voxel holding it
    assert np.allclose(grid.centroids[grid.point_voxel][:2], [0.001, 0.0015, 0.0005])


def test_voxel_size_must_be_positive() -> None:
    with pytest.raises(ValueError, match="positive"):
        voxel_downsample(np.zeros((3, 3)), voxel_m=0.0)


def test_pass_through_range_and_box() -> None:
    pts = np.array([[0, 0, 0.05], [0, 0, 0.5], [0.2, 0, 0.5], [np.nan, 0, 0.5], [0, 0, 4.0]])
    keep = pass_through(pts, z_range_m=(0.1, 3.0), box_min=np.array([-0.1, -1, 0]), box_max=np.array([0.1, 1, 1]))
    assert keep.tolist() == [False, True, False, False, False]


def test_plane_normals_face_the_viewpoint_and_curvature_is_zero() -> None:
    pts = grid_plane(20, 0.003, [0, 0, 0.5], [1, 0, 0], [0, 1, 0])
    nbh = neighbourhoods(pts, k=12, radius_m=0.0075)
    n, c = normals_and_curvature(pts, nbh)
    assert np.allclose(n, [0, 0, -1], atol=1e-9)  # towards the camera at the origin
    assert c.max() < 1e-12


def test_curvature_grows_as_the_radius_shrinks() -> None:
    """Surface variation of a cylinder patch scales with (neighbourhood / radius)^2: half the radius,
    about four times the curvature."""

    def median_curvature(r: float) -> float:
        ang = np.arange(0, np.pi * r, 0.001) / r
        z = np.arange(0, 0.03, 0.001)
        A, Z = np.meshgrid(ang, z)
        pts = np.column_stack([r * np.cos(A).ravel(), Z.ravel(), 0.5 + r * np.sin(A).ravel()])
        nbh = neighbourhoods(pts, k=40, radius_m=0.004)
        _, c = normals_and_curvature(pts, nbh)
        return float(np.median(c))

    c20, c40 = median_curvature(0.02), median_curvature(0.04)
    assert c20 > 0 and c40 > 0
    assert c20 / c40 == pytest.approx(4.0, rel=0.15)


def test_region_growing_splits_a_fold_and_seeds_from_the_flattest() -> None:
    floor = grid_plane(20, 0.003, [0, 0, 0.5], [1, 0, 0], [0, 1, 0])
    wall = grid_plane(20, 0.003, [0, 0, 0.5], [0, 1, 0], [0, 0, -1])[20:]  # shares the x=0 line
    pts = np.vstack([floor, wall])
    nbh = neighbourhoods(pts, k=12, radius_m=0.0075)
    n, c = normals_and_curvature(pts, nbh, viewpoint=np.array([0.1, 0.03, 0.3]))
    reg = grow_regions(n, c, nbh)
    assert reg.max() == 1  # exactly two regions
    flat_floor = reg[: len(floor)][np.abs(floor[:, 0]) > 0.01]
    flat_wall = reg[len(floor) :][np.abs(wall[:, 2] - 0.5) > 0.01]
    assert len(set(flat_floor)) == 1 and len(set(flat_wall)) == 1
    assert flat_floor[0] != flat_wall[0]
    # region 0 is seeded first: both are flat, ties go to the lower index, the floor
    assert flat_floor[0] == 0


def test_coplanar_fragments_are_merged() -> None:
    pts = grid_plane(20, 0.003, [0, 0, 0.5], [1, 0, 0], [0, 1, 0])
    nbh = neighbourhoods(pts, k=12, radius_m=0.0075)
    regions = np.where(pts[:, 0] < 0.03, 0, 1).astype(np.int32)
    merged = merge_coplanar_regions(pts, regions, nbh)
    assert set(merged.tolist()) == {0}


def test_closed_form_smallest_eigenpair_matches_eigh() -> None:
    rng = np.random.default_rng(3)
    m = 2000
    rot, _ = np.linalg.qr(rng.normal(size=(m, 3, 3)))
    # plane-like (l0 << l1 <= l2) as in scan neighbourhoods, from 1e-12 to 3e-5 m^2
    lam = np.column_stack([rng.uniform(1e-12, 1e-6, m), rng.uniform(5e-6, 1e-5, m), rng.uniform(1e-5, 3e-5, m)])
    cov = np.einsum("mij,mj,mkj->mik", rot, lam, rot)
    special = np.array([np.diag([3.0, 1.0, 2.0]), np.zeros((3, 3)), np.eye(3), np.outer([1.0, 2, 2], [1.0, 2, 2])])
    cov = np.concatenate([cov, special])
    l0, v = smallest_eigenpairs(cov)
    evals, evecs = np.linalg.eigh(cov)
    scale = np.abs(evals).max(axis=1)
    # to rounding for distinct eigenvalues; to ~sqrt(eps) of the largest one where two coincide
    assert (np.abs(l0 - evals[:, 0]) <= 1e-12 * scale)[:m].all()
    assert (np.abs(l0 - evals[:, 0]) <= 1e-7 * scale).all()
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
    # the vector is an eigenvector of the smallest eigenvalue (any one where that eigenvalue repeats)
    residual = np.einsum("mij,mj->mi", cov, v) - l0[:, None] * v
    assert (np.abs(residual).max(axis=1) <= 1e-7 * np.maximum(scale, 1e-300)).all()
    distinct = evals[:, 1] - evals[:, 0] > 1e-3 * evals[:, 2]
    assert distinct[:m].all()
    assert np.abs(np.abs((v * evecs[:, :, 0]).sum(axis=1))[distinct] - 1.0).max() < 1e-9
    assert np.allclose(v[m + 0], [0, 1, 0]) or np.allclose(v[m + 0], [0, -1, 0])



def test_a_few_points_far_off_the_part_are_stray_and_a_part_in_pieces_is_not() -> None:
    """A plate sampled on a 2 mm grid (5 000 points) in two pieces 15 mm apart (over ten spacings: apart),
    a 60-point bracket 0.3 m off, three single returns 2 m away and a pair of flying pixels 40 mm off: the
    singles and the pair are stray (under 0.1% of the points each), the bracket and both pieces are not."""
    x, y = np.meshgrid(np.arange(0.0, 0.1, 0.002), np.arange(0.0, 0.2, 0.002))
    plate = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    plate[plate[:, 0] > 0.05, 0] += 0.015  # the second piece, 15 + 2 mm from the first
    bracket = np.column_stack([np.full(60, 0.4), np.linspace(0.0, 0.118, 60), np.zeros(60)])
    singles = np.array([[2.0, 0.0, 0.0], [-2.0, 0.1, 0.0], [0.0, 2.0, 0.5]])
    pair = np.array([[0.05, 0.24, 0.0], [0.051, 0.24, 0.0]])
    p = np.vstack([plate, bracket, singles, pair])
    stray = stray_points(p, 0.002)
    n = len(plate) + len(bracket)
    assert not stray[:n].any() and stray[n:].all()
    assert not stray_points(singles, 0.002).any()  # no piece large enough to keep: none is dropped
    # the same with the singles 1e13 m away: a voxel grid too large to number each voxel by one int64 (its rows
    # are compared instead), the same answer
    far = np.vstack([plate, bracket, singles * 5e12, pair])
    assert np.array_equal(stray_points(far, 0.002), stray)
