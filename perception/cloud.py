"""Fine-stage steps on unorganized clouds: pass-through, voxel grid, KD-tree, normals and curvature,
and region growing. Each is a pure function; arrays are (N, 3) float64 metres in the camera frame."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def pass_through(
    points: FloatArray,
    *,
    z_range_m: tuple[float, float] = (0.1, 3.0),
    box_min: FloatArray | None = None,
    box_max: FloatArray | None = None,
) -> NDArray[np.bool_]:
    """(N,) mask of points inside the working range along z and inside the optional axis-aligned box."""
    keep = np.isfinite(points).all(axis=1)
    keep &= (points[:, 2] >= z_range_m[0]) & (points[:, 2] <= z_range_m[1])
    if box_min is not None:
        keep &= (points >= np.asarray(box_min)).all(axis=1)
    if box_max is not None:
        keep &= (points <= np.asarray(box_max)).all(axis=1)
    return keep


@dataclass(frozen=True)
class VoxelGrid:
    """Result of voxel downsampling.

    centroids: (M, 3) mean of the points in each occupied voxel.
    point_voxel: (N,) index of each input point's voxel (so per-voxel results map back to points).
    counts: (M,) points per voxel.
    labels: (M,) majority surface label per voxel (-1 when the input had none).
    """

    centroids: FloatArray
    point_voxel: IntArray
    counts: IntArray
    labels: NDArray[np.int32]
    voxel_m: float


def voxel_downsample(
    points: FloatArray, *, voxel_m: float = 0.003, labels: NDArray[np.int32] | None = None
) -> VoxelGrid:
    """Voxel grid with one centroid per occupied voxel (the paper's downsampling, default 3 mm)."""
    if voxel_m <= 0:
        raise ValueError(f"voxel size must be positive, got {voxel_m}")
    keys3 = np.floor(points / voxel_m).astype(np.int64)
    keys3 -= keys3.min(axis=0)
    dims = keys3.max(axis=0) + 1
    key = (keys3[:, 0] * dims[1] + keys3[:, 1]) * dims[2] + keys3[:, 2]
    uniq, inv = np.unique(key, return_inverse=True)
    m = len(uniq)
    counts = np.bincount(inv, minlength=m)
    cent = np.column_stack([np.bincount(inv, weights=points[:, k], minlength=m) for k in range(3)]) / counts[:, None]
    if labels is None:
        vlab = np.full(m, -1, np.int32)
    else:
        nl = int(labels.max(initial=-1)) + 2
        votes = np.bincount(inv * nl + (labels.astype(np.int64) + 1), minlength=m * nl).reshape(m, nl)
        vlab = (votes.argmax(axis=1) - 1).astype(np.int32)
    return VoxelGrid(cent, inv.astype(np.int64), counts.astype(np.int64), vlab, voxel_m)


@dataclass(frozen=True)
class Neighbourhoods:
    """k nearest neighbours of each point (self first); ``valid`` marks those within ``radius_m``."""

    tree: cKDTree
    idx: IntArray  # (M, k)
    dist: FloatArray  # (M, k)
    valid: NDArray[np.bool_]  # (M, k)


def surface_spacing(points: FloatArray, *, radius_m: float = 0.01, samples: int = 1000) -> float:
    """Typical distance between a surface's samples, 1 / sqrt(points per unit area), from the points in
    balls of ``radius_m`` around a deterministic sample (a LiDAR's scan lines count by their spacing,
    not by the dense points along each line, which the nearest-neighbour distance would report)."""
    if len(points) < 10:
        return 0.0
    tree = kdtree(points)
    pick = points[:: max(1, len(points) // samples)]
    counts = tree.query_ball_point(pick, radius_m, return_length=True)
    density = float(np.median(counts)) / (np.pi * radius_m**2)  # a planar neighbourhood
    return float(1.0 / np.sqrt(max(density, 1e-12)))


STRAY_GAP_SPACINGS = 10.0  # pieces of a cloud parted by a gap over this many sample spacings are apart
STRAY_SHARE = 0.001  # ... and a piece holding under this share of the points (at least 3) is stray


def stray_points(points: FloatArray, spacing_m: float) -> NDArray[np.bool_]:
    """(N,) whether each point lies in a stray piece of the cloud: a handful of points (under
    :data:`STRAY_SHARE` of them) parted from the rest by a gap of about :data:`STRAY_GAP_SPACINGS` sample
    spacings (``spacing_m``). Real scans hold such points, a LiDAR's returns off a far wall, a depth camera's flying
    pixels, a reflection: a few of them metres away would stretch the cloud's view until its pixels are too
    coarse for the part. Pieces are joined on a voxel grid that wide (each voxel to its 26 neighbours: points
    one to two voxels apart are joined), so that a dense cloud costs its voxels, not its points' pairs. None
    is stray when no piece is large enough to keep."""
    from perception.fits import connected_components

    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0 or not spacing_m > 0.0:
        return np.zeros(len(p), dtype=bool)
    cell = STRAY_GAP_SPACINGS * spacing_m
    keys = np.floor((p - p.min(axis=0)) / cell).astype(np.int64)
    dims = [int(d) + 1 for d in keys.max(axis=0)]
    if dims[0] * dims[1] * dims[2] < 2**63:
        # one integer per voxel, in the rows' lexicographic order (np.unique(keys, axis=0) sorts rows as
        # structured values: fifteen times slower on a LiDAR scan of 77k points)
        _, first, inv = np.unique((keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2], return_index=True,
                                  return_inverse=True)  # fmt: skip
        voxels = keys[first]
    else:  # a grid too large for one integer per voxel (a far point metres off a dense part): the rows
        voxels, inv = np.unique(keys, axis=0, return_inverse=True)
    piece = connected_components(voxels.astype(np.float64), 1.8)[inv.ravel()]  # sqrt(3) voxels: 26 neighbours
    size = np.bincount(piece)
    large = size >= max(3, STRAY_SHARE * len(p))
    if not large.any():
        return np.zeros(len(p), dtype=bool)
    return np.asarray(~large[piece])


def kdtree(points: FloatArray) -> cKDTree:
    """A KD-tree built with sliding midpoint splits: about twice as fast to build as scipy's default median
    splits, and as fast to query on scan data (measured on the ribs capture: 13 vs 30 ms for 146k points)."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False)


def neighbourhoods(points: FloatArray, *, k: int = 16, radius_m: float = 0.0075) -> Neighbourhoods:
    tree = kdtree(points)
    k_eff = min(k, len(points))
    # neighbours beyond the radius are never used: bounding the search saves ~20%; missing ones come
    # back as index len(points) at distance inf, and stand for the point itself (never valid)
    dist, idx = tree.query(points, k=k_eff, workers=2, distance_upper_bound=radius_m * (1 + 1e-9))
    dist = dist.reshape(len(points), k_eff)
    idx = idx.reshape(len(points), k_eff).astype(np.int64)
    missing = idx >= len(points)
    idx[missing] = np.broadcast_to(np.arange(len(points))[:, None], idx.shape)[missing]
    return Neighbourhoods(tree, idx, dist, dist <= radius_m)


def normals_and_curvature(
    points: FloatArray, nbh: Neighbourhoods, *, viewpoint: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Per point: unit normal (towards ``viewpoint``, default the camera origin) and the surface
    variation (curvature) delta = l0 / (l0 + l1 + l2) of its neighbourhood covariance (l0 smallest)."""
    # coordinates relative to each point keep the sums small (no cancellation in E[xx] - E[x]E[x])
    q = points[nbh.idx] - points[:, None, :]  # (M, k, 3)
    w = nbh.valid
    q *= w[..., None]
    cnt = np.maximum(w.sum(axis=1), 1).astype(np.float64)
    mean = q.sum(axis=1) / cnt[:, None]
    cov = np.einsum("mki,mkj->mij", q, q) / cnt[:, None, None] - mean[:, :, None] * mean[:, None, :]
    l0, normals = smallest_eigenpairs(cov)
    vp = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    flip = ((vp - points) * normals).sum(axis=1) < 0
    normals[flip] *= -1
    total = np.maximum(np.trace(cov, axis1=1, axis2=2), 1e-30)
    curvature = np.clip(l0, 0.0, None) / total
    curvature[cnt < 4] = 1.0 / 3.0  # too few neighbours: treat as maximally curved
    return normals, curvature


def smallest_eigenpairs(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Smallest eigenvalue and its unit eigenvector of each symmetric 3x3 matrix in ``A`` (M, 3, 3), in
    closed form (Smith 1961): the trigonometric solution of the characteristic cubic, then the eigenvector
    as the longest cross product of two rows of A - l0 I. Three times faster than a batched eigh. Exact to
    rounding for distinct eigenvalues; where two coincide, l0 is good to ~1e-8 of the largest one, and
    where the smallest is not distinct (no plane) the vector is arbitrary but unit, as eigh's is."""
    a00, a11, a22 = A[:, 0, 0], A[:, 1, 1], A[:, 2, 2]
    a01, a02, a12 = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    q = (a00 + a11 + a22) / 3.0
    p1 = a01**2 + a02**2 + a12**2
    p = np.sqrt(((a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1) / 6.0)
    safe = np.where(p > 0, p, 1.0)
    b00, b11, b22 = (a00 - q) / safe, (a11 - q) / safe, (a22 - q) / safe
    b01, b02, b12 = a01 / safe, a02 / safe, a12 / safe
    det = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    l0 = np.where(p > 0, q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0), q)
    r0 = np.stack([a00 - l0, a01, a02], axis=1)
    r1 = np.stack([a01, a11 - l0, a12], axis=1)
    r2 = np.stack([a02, a12, a22 - l0], axis=1)
    c = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)  # (M, 3, 3)
    n2 = (c**2).sum(axis=2)
    best = n2.argmax(axis=1)
    v = c[np.arange(len(A)), best]
    norm = np.sqrt(n2[np.arange(len(A)), best])
    out = np.zeros_like(v)
    out[:, 2] = 1.0
    ok = norm > 0
    out[ok] = v[ok] / norm[ok, None]
    return l0, out


@dataclass(frozen=True)
class RegionParams:
    max_angle_rad: float = math.radians(12.0)  # smoothness: neighbours join when their normals differ by less
    max_curvature: float = 0.04  # only points flatter than this keep growing the region
    min_region_points: int = 8


def grow_regions(
    normals: FloatArray,
    curvature: FloatArray,
    nbh: Neighbourhoods,
    *,
    params: RegionParams | None = None,
    labels: NDArray[np.int32] | None = None,
    max_link_m: float | None = None,
) -> NDArray[np.int32]:
    """Region growing as in PCL's RegionGrowing, seeded from the lowest curvature.

    A region starts at the flattest unassigned point; a neighbour joins when its normal is within
    ``max_angle_rad`` of the current point's (and, when ``labels`` are given, it has the same surface
    label); a joined neighbour keeps growing the region only if its curvature is below
    ``max_curvature``. Returns (M,) region ids numbered in seeding order, -1 for points in regions
    smaller than ``min_region_points``.

    Implemented without a per-point Python loop: the flat points ("growers") connected by smooth
    edges form the cores (connected components); a curved point joins the region of the earliest
    seeded grower next to it with a smooth edge, exactly what sequential growing produces; the
    remaining points seed their own (small) regions.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    p = params or RegionParams()
    m = len(normals)
    cos_t = np.cos(p.max_angle_rad)
    idx = nbh.idx
    nb_normals = normals[idx]  # (M, k, 3)
    linked = nbh.valid if max_link_m is None else nbh.valid & (nbh.dist <= max_link_m)
    smooth = linked & (np.abs((nb_normals * normals[:, None, :]).sum(axis=2)) >= cos_t)
    if labels is not None:
        smooth &= labels[idx] == labels[:, None]
    smooth[:, 0] = False  # self
    grower = curvature < p.max_curvature
    rows = np.repeat(np.arange(m), idx.shape[1]).reshape(idx.shape)
    e = smooth & grower[:, None] & grower[idx]
    graph = coo_matrix((np.ones(int(e.sum())), (rows[e], idx[e])), shape=(m, m))
    n_core, core = connected_components(graph, directed=False)
    # seeding order: each core is seeded at its flattest point; order cores by that curvature
    core_min = np.full(n_core, np.inf)
    np.minimum.at(core_min, core[grower], curvature[grower])
    region = np.full(m, -1, np.int64)
    region[grower] = core[grower]
    # a curved point joins a smooth grower neighbour's region, the earliest seeded one
    rank = np.empty(n_core, np.int64)
    rank[np.argsort(core_min, kind="stable")] = np.arange(n_core)
    curved = np.flatnonzero(~grower)
    if len(curved):
        nb = idx[curved]
        ok = smooth[curved] & grower[nb]
        nb_rank = np.where(ok, rank[np.where(grower[nb], core[nb], 0)], np.iinfo(np.int64).max)
        best = nb_rank.argmin(axis=1)
        has = ok[np.arange(len(curved)), best]
        chosen = nb[np.arange(len(curved)), best]
        region[curved[has]] = core[chosen[has]]
    # renumber by seeding order and drop small regions
    valid = region >= 0
    sizes = np.bincount(region[valid], minlength=n_core)
    keep_core = sizes >= p.min_region_points
    order = np.argsort(np.where(keep_core, core_min, np.inf), kind="stable")
    new_id = np.full(n_core, -1, np.int64)
    n_keep = int(keep_core.sum())
    new_id[order[:n_keep]] = np.arange(n_keep)
    out = np.full(m, -1, np.int32)
    out[valid] = new_id[region[valid]].astype(np.int32)
    return out


def merge_coplanar_regions(
    points: FloatArray,
    regions: NDArray[np.int32],
    nbh: Neighbourhoods,
    *,
    max_angle_rad: float = math.radians(10.0),
    max_offset_m: float = 0.0015,
) -> NDArray[np.int32]:
    """Join neighbouring regions that are one plane split by noise (normals within ``max_angle_rad``,
    each centroid within ``max_offset_m`` + 2 RMS of the other's plane). Region ids keep the order of
    their smallest member id, so the result stays deterministic."""
    n_reg = int(regions.max(initial=-1)) + 1
    if n_reg < 2:
        return regions
    planes = []
    for r in range(n_reg):
        p = points[regions == r]
        c = p.mean(axis=0)
        _, s, vt = np.linalg.svd(p - c, full_matrices=False)
        planes.append((c, vt[2], float(s[2] / np.sqrt(len(p)))))
    idx = nbh.idx
    ra = regions[:, None]
    rb = regions[idx]
    cross = nbh.valid & (ra >= 0) & (rb >= 0) & (rb != ra)
    a = np.broadcast_to(ra, rb.shape)[cross].astype(np.int64)
    b = rb[cross].astype(np.int64)
    pairs = np.unique(np.column_stack([np.minimum(a, b), np.maximum(a, b)]), axis=0)
    parent = list(range(n_reg))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    cos_t = np.cos(max_angle_rad)
    for i, j in pairs:
        ci, ni, ri = planes[i]
        cj, nj, rj = planes[j]
        if abs(ni @ nj) < cos_t:
            continue
        # the noise allowance is capped: a large, noisy region (a table) must not swallow a plate
        # standing a few millimetres above it
        if abs((cj - ci) @ ni) > max_offset_m + min(2 * ri, 0.002) or abs((ci - cj) @ nj) > max_offset_m + min(
            2 * rj, 0.002
        ):
            continue
        pi, pj = find(int(i)), find(int(j))
        if pi != pj:
            parent[max(pi, pj)] = min(pi, pj)
    roots = np.array([find(r) for r in range(n_reg)])
    _, new = np.unique(roots, return_inverse=True)
    out = regions.copy()
    ok = regions >= 0
    out[ok] = new[regions[ok]].astype(np.int32)
    return out
