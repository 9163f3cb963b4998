"""From regions to seams: edge points between regions, seam candidates, the paper's line / curve fits,
and the refinement from full-resolution points that goes below the voxel size.

Geometry conventions: camera frame, metres; surface normals point out of the material, towards the
camera (the side a torch comes from).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from perception.cloud import Neighbourhoods, kdtree

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SeamParams:
    min_edge_points: int = 6
    patch_radius_m: float = 0.012  # surface points this close to the junction describe it
    min_fold_rad: float = math.radians(25.0)  # surfaces meeting at a sharper turn than this can form a fillet
    max_coplanar_rad: float = math.radians(8.0)  # surfaces this parallel can only form a butt joint
    concave_margin_m: float = 0.0005
    max_gap_m: float = 0.005  # widest butt-joint gap
    min_gap_m: float = 0.0003  # a narrower "gap" is one surface split by the segmenter, not a joint
    butt_max_rms_m: float = 0.0015
    butt_min_gap_share: float = 0.5
    curved_sagitta_m: float = 0.0025  # a fitted line this far from the binned edge path means "curved"
    min_length_m: float = 0.012
    end_trim_m: float = 0.002  # keep path ends this far inside the measured extent
    refine: bool = True
    support_bin_m: float = 0.002
    max_hole_m: float = 0.006  # a longer stretch without both faces seen splits the seam (occluder)
    refine_exclude_m: float = 0.0012  # ignore points this close to the junction (mixed, noisy)
    refine_band_m: float = 0.010
    plane_gate_sigma: float = 3.0
    slab_half_width_m: float = 0.0025  # cross-section slab for curved seams
    curve_step_m: float = 0.002
    max_incidence_rad: float = math.radians(78.0)


@dataclass(frozen=True)
class SeamGeometry:
    """A seam before path sampling: a dense centre line with the two surface normals along it.

    points: (N, 3) ordered centre line; normals_a / normals_b: (N, 3) outward unit normals;
    regions: the two region ids; kind; support: number of edge points behind it; rms_m: plane-fit RMS.
    """

    kind: Literal["linear", "curved"]
    joint: Literal["fillet", "inside_corner", "lap", "v_groove", "butt"]
    points: FloatArray
    normals_a: FloatArray
    normals_b: FloatArray
    regions: tuple[int, int]
    labels: tuple[int, int]
    support: int
    rms_m: float


# --------------------------------------------------------------------------------------------------
# Small geometric helpers


def fit_plane(p: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Least-squares plane: (centroid, unit normal, RMS distance), from the 3x3 scatter matrix."""
    c = p.mean(axis=0)
    q = p - c
    evals, evecs = np.linalg.eigh(q.T @ q)
    return c, evecs[:, 0], float(np.sqrt(max(evals[0], 0.0) / max(len(p), 1)))


def fit_plane_robust(
    p: FloatArray, *, sigma_gate: float = 3.0, iters: int = 3
) -> tuple[FloatArray, FloatArray, float, NDArray[np.bool_]]:
    """Plane fit with iterative ``sigma_gate`` * RMS outlier rejection; returns the inlier mask too."""
    keep = np.ones(len(p), bool)
    c, n, rms = fit_plane(p)
    for _ in range(iters):
        d = np.abs((p - c) @ n)
        new = d <= max(sigma_gate * rms, 1e-5)
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
        c, n, rms = fit_plane(p[keep])
    return c, n, rms, keep


def fit_line(p: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares 3D line through points: (centroid, unit direction)."""
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    return c, vt[0]


def orient_towards(n: FloatArray, p: FloatArray, viewpoint: FloatArray) -> FloatArray:
    return n if float(n @ (viewpoint - p)) >= 0 else -n


def plane_intersection(
    c1: FloatArray, n1: FloatArray, c2: FloatArray, n2: FloatArray, near: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Line of two planes: (the point on it closest to ``near``, unit direction)."""
    d = np.cross(n1, n2)
    d /= np.linalg.norm(d)
    # minimise |x - near|^2 subject to n1.x = n1.c1, n2.x = n2.c2
    A = np.array([[2.0, 0, 0, n1[0], n2[0]], [0, 2.0, 0, n1[1], n2[1]], [0, 0, 2.0, n1[2], n2[2]],
                  [n1[0], n1[1], n1[2], 0, 0], [n2[0], n2[1], n2[2], 0, 0]])  # fmt: skip
    b = np.concatenate([2 * near, [n1 @ c1, n2 @ c2]])
    x = np.linalg.solve(A, b)
    return x[:3], d


def _components(points: FloatArray, radius: float) -> NDArray[np.int64]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = kdtree(points).query_pairs(radius, output_type="ndarray")
    n = len(points)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    return lab.astype(np.int64)


def order_along_curve(points: FloatArray, radius: float) -> FloatArray:
    """(N,) parameter along a thin curve-like point set: geodesic distance from one end."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    tree = kdtree(points)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    n = len(points)
    w = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    g = coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    d0 = dijkstra(g, directed=False, indices=0)
    d0[~np.isfinite(d0)] = -1
    end = int(np.argmax(d0))
    s = dijkstra(g, directed=False, indices=end)
    s[~np.isfinite(s)] = np.nan
    return np.asarray(s)


# --------------------------------------------------------------------------------------------------
# Candidates


@dataclass(frozen=True)
class EdgeSet:
    """Edge points between two regions a < b (indices into the voxel cloud), one connected piece."""

    a: int
    b: int
    points_a: NDArray[np.int64]
    points_b: NDArray[np.int64]


def region_edges(
    regions: NDArray[np.int32], nbh: Neighbourhoods, *, min_points: int, link_m: float, bridge: bool = False
) -> list[EdgeSet]:
    """Points of each region that have a neighbour in another region, grouped by region pair and split
    into connected pieces (two regions may meet in more than one place). With ``bridge``, regions also
    meet across one unassigned point (sparse scans: every neighbourhood at the fold straddles it)."""
    idx = nbh.idx
    ra = regions[:, None]
    rb = regions[idx]
    cross = nbh.valid & (ra >= 0) & (rb >= 0) & (rb != ra)
    rows, cols = np.nonzero(cross)
    # (point, neighbour) pairs on either side of a junction
    p1, p2 = rows, idx[rows, cols]
    bridged = _bridged_pairs(regions, nbh) if bridge else None
    if bridged is not None:
        p1, p2 = np.concatenate([p1, bridged[0]]), np.concatenate([p2, bridged[1]])
    if len(p1) == 0:
        return []
    r1 = regions[p1].astype(np.int64)
    r2 = regions[p2].astype(np.int64)
    lo, hi = np.minimum(r1, r2), np.maximum(r1, r2)
    key = lo * (int(regions.max()) + 1) + hi
    out: list[EdgeSet] = []
    for k in np.unique(key):
        sel = key == k
        pts = np.unique(np.concatenate([p1[sel], p2[sel]]))
        a, b = int(lo[sel][0]), int(hi[sel][0])
        if len(pts) < 2 * min_points:
            continue
        out.extend(_split_pieces(a, b, pts, regions, min_points, link_m, nbh))
    return out


def _bridged_pairs(
    regions: NDArray[np.int32], nbh: Neighbourhoods
) -> tuple[NDArray[np.int64], NDArray[np.int64]] | None:
    """Regions that meet only across a strip of unassigned points (a sparse scan's fold, where every
    neighbourhood straddles the corner): pairs of points of two regions that share an unassigned
    neighbour."""
    un = np.flatnonzero(regions < 0)
    if len(un) == 0:
        return None
    nb = nbh.idx[un]
    nreg = np.where(nbh.valid[un], regions[nb], -1)
    n_reg = int(regions.max(initial=-1)) + 1
    if n_reg < 2:
        return None
    out_a: list[NDArray[np.int64]] = []
    out_b: list[NDArray[np.int64]] = []
    for j in range(nb.shape[1]):
        for i in range(j + 1, nb.shape[1]):
            ok = (nreg[:, i] >= 0) & (nreg[:, j] >= 0) & (nreg[:, i] != nreg[:, j])
            if ok.any():
                out_a.append(nb[ok, i])
                out_b.append(nb[ok, j])
    if not out_a:
        return None
    return np.concatenate(out_a), np.concatenate(out_b)


def _split_pieces(a, b, pts, regions, min_points, link_m, nbh) -> list[EdgeSet]:
    coords = nbh.tree.data[pts]
    lab = _components(coords, link_m)
    pieces = []
    for c in np.unique(lab):
        sel = pts[lab == c]
        pa = sel[regions[sel] == a]
        pb = sel[regions[sel] == b]
        if len(pa) >= min_points and len(pb) >= min_points:
            pieces.append(EdgeSet(a, b, pa, pb))
    return pieces


# --------------------------------------------------------------------------------------------------
# Fitting and refinement


@dataclass(frozen=True)
class FullRes:
    """Full-resolution points of the cropped cloud with their region (via their voxel) and a KD-tree;
    ``region_normals`` (R, 3) is each region's mean unit normal."""

    points: FloatArray
    regions: NDArray[np.int32]
    tree: cKDTree
    region_normals: FloatArray
    normals: FloatArray  # (N, 3) each point's voxel normal
    labels: NDArray[np.int32] | None = None  # (N,) coarse surface label, when the coarse stage ran
    unassigned_max_angle_rad: float = math.radians(60.0)

    def compatible(
        self, idx: NDArray[np.int64], n: FloatArray, max_angle_rad: float = math.radians(15.0)
    ) -> NDArray[np.bool_]:
        """Points (by index) that could be part of a face with normal ``n``: regions facing the same way
        (fragments of that face), or unassigned points whose own normal is within 30 degrees."""
        reg = self.regions[idx]
        ok = (reg < 0) & (np.abs(self.normals[idx] @ n) >= np.cos(self.unassigned_max_angle_rad))
        if len(self.region_normals):
            cos = np.abs(self.region_normals @ n)
            ok |= (reg >= 0) & (cos[np.maximum(reg, 0)] >= np.cos(max_angle_rad))
        return ok


def _indices_near_polyline(full: FullRes, line: FloatArray, radius: float) -> NDArray[np.int64]:
    """Indices of full-res points within about ``radius`` of a polyline (query balls along it)."""
    return indices_near_polyline(full.tree, len(full.points), line, radius)


def indices_near_polyline(tree: cKDTree, n_points: int, line: FloatArray, radius: float) -> NDArray[np.int64]:
    """Indices (sorted) of the ``n_points`` points in ``tree`` within about ``radius`` of a polyline."""
    from perception.evaluate import resample_polyline

    # balls every 2R of radius sqrt(2)R cover the cylinder of radius R around each segment
    samples = resample_polyline(line, 2 * radius)
    # small queries: scipy's worker threads would cost more than they save
    hits = tree.query_ball_point(samples, 1.42 * radius, return_sorted=False)
    if not len(hits):
        return np.zeros(0, np.int64)
    seen = np.zeros(n_points, dtype=bool)  # the balls overlap: mark, then list (no sort)
    for h in hits:
        seen[h] = True
    return np.flatnonzero(seen)


def _points_near_polyline(full: FullRes, region: int | tuple[int, ...], line: FloatArray, radius: float) -> FloatArray:
    """Full-res points of ``region`` within about ``radius`` of a polyline."""
    idx = _indices_near_polyline(full, line, radius)
    if idx.size == 0:
        return np.zeros((0, 3))
    regs = np.atleast_1d(np.asarray(region))
    return full.points[idx[np.isin(full.regions[idx], regs)]]


JOINT_KINDS = ("fillet", "convex", "butt", "none")


def classify_junction(
    pa: FloatArray, pb: FloatArray, params: SeamParams, viewpoint: FloatArray
) -> tuple[str, FloatArray, FloatArray, float]:
    """'fillet' | 'butt' | 'convex' | 'none' for two local surface patches; their normals; fit RMS."""
    ca, na, rms_a = fit_plane(pa)
    cb, nb, rms_b = fit_plane(pb)
    kinds, na_o, nb_o = _junction_kinds(ca[None], na[None], cb[None], nb[None], params, viewpoint)
    return JOINT_KINDS[int(kinds[0])], na_o[0], nb_o[0], max(rms_a, rms_b)


def _junction_kinds(
    ca: FloatArray, na: FloatArray, cb: FloatArray, nb: FloatArray, params: SeamParams, viewpoint: FloatArray
) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """The junction rules for K plane pairs (centroids and normals, (K, 3) each): the index of each pair's
    kind in JOINT_KINDS, and both normals turned towards ``viewpoint``. Two surfaces folded by at least
    ``min_fold_rad`` form a fillet when each lies on the outer (torch) side of the other's plane, else a
    convex edge; nearly parallel ones in one plane may be a butt joint."""
    na = np.where(((viewpoint - ca) * na).sum(axis=1, keepdims=True) >= 0, na, -na)
    nb = np.where(((viewpoint - cb) * nb).sum(axis=1, keepdims=True) >= 0, nb, -nb)
    angle = np.arccos(np.clip(np.abs((na * nb).sum(axis=1)), -1.0, 1.0))  # radians
    m = params.concave_margin_m
    concave = ((na * (cb - ca)).sum(axis=1) > m) & ((nb * (ca - cb)).sum(axis=1) > m)
    folded = angle >= params.min_fold_rad
    flush = (angle <= params.max_coplanar_rad) & (np.abs((na * (cb - ca)).sum(axis=1)) < 0.002)
    return np.where(folded, np.where(concave, 0, 1), np.where(flush, 2, 3)), na, nb


def classify_junction_local(
    edge_points: FloatArray,
    tree_a: cKDTree,
    tree_b: cKDTree,
    params: SeamParams,
    viewpoint: FloatArray,
    *,
    anchor_spacing_m: float = 0.008,
) -> tuple[str, FloatArray, FloatArray, float]:
    """Classify a junction from local plane pairs at anchors along it (a curved surface is planar only
    locally). Majority vote of the anchors; the normals returned are the mean of the winning anchors'."""
    # anchors: edge points about ``anchor_spacing_m`` apart along the junction's main direction
    c = edge_points.mean(axis=0)
    _, _, vt = np.linalg.svd(edge_points - c, full_matrices=False)
    t = (edge_points - c) @ vt[0]
    targets = np.arange(t.min(), t.max() + anchor_spacing_m / 2, anchor_spacing_m)
    order = np.argsort(t)
    pick = np.unique(order[np.clip(np.searchsorted(t[order], targets), 0, len(t) - 1)])
    anchors = edge_points[pick]
    r = params.patch_radius_m
    hits_a = tree_a.query_ball_point(anchors, r)
    hits_b = tree_b.query_ball_point(anchors, r)
    use = np.array([len(ia) >= 6 and len(ib) >= 6 for ia, ib in zip(hits_a, hits_b, strict=True)], dtype=bool)
    if not use.any():
        return "none", np.zeros(3), np.zeros(3), 0.0
    ca, na, rms_a = plane_patches(tree_a.data, list(hits_a[use]), anchors[use])
    cb, nb, rms_b = plane_patches(tree_b.data, list(hits_b[use]), anchors[use])
    kinds, na, nb = _junction_kinds(ca, na, cb, nb, params, viewpoint)
    # majority vote; a tie goes to the kind seen first along the junction
    counts = np.bincount(kinds, minlength=len(JOINT_KINDS))
    tied = np.flatnonzero(counts == counts.max())
    code = int(min(tied, key=lambda k: int(np.argmax(kinds == k))))
    joint = JOINT_KINDS[code]
    win = kinds == code
    n_a, n_b = na[win].mean(axis=0), nb[win].mean(axis=0)
    rms = float(np.median(np.maximum(rms_a, rms_b)[win]))
    return joint, n_a / np.linalg.norm(n_a), n_b / np.linalg.norm(n_b), rms


def plane_patches(
    data: FloatArray, hits: list[list[int]], refs: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Least-squares planes of many small point sets at once: ``hits`` are index lists into ``data`` and
    ``refs`` (K, 3) a point near each set (coordinates are taken relative to it, for precision).
    Returns (K, 3) centroids, (K, 3) unit normals (either sign) and (K,) RMS distances, as fit_plane."""
    lens = np.array([len(h) for h in hits])
    flat = np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])
    owner = np.repeat(np.arange(len(hits)), lens)
    q = data[flat] - refs[owner]
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
    mean = np.add.reduceat(q, starts, axis=0) / lens[:, None]
    second = np.add.reduceat(q[:, :, None] * q[:, None, :], starts, axis=0) / lens[:, None, None]
    cov = second - mean[:, :, None] * mean[:, None, :]
    evals, evecs = np.linalg.eigh(cov)  # a few matrices: one batched call beats the closed form's many
    return mean + refs, evecs[:, :, 0], np.sqrt(np.clip(evals[:, 0], 0.0, None))


def fit_edge_path(edge_points: FloatArray, params: SeamParams, voxel_m: float) -> tuple[str, FloatArray]:
    """The paper's fit of the edge points: a least-squares line, or, when the points bend away from it,
    a smooth curve in the plane the seam lies in. Returns (kind, ordered (N, 3) centre line)."""
    from scipy.interpolate import splev, splprep

    c, d = fit_line(edge_points)
    t = (edge_points - c) @ d
    # binned mean offsets from the line: noise and the two-sided edge spread average out, a bend does not
    nbins = max(2, int((t.max() - t.min()) / max(3 * voxel_m, 0.006)))
    bins = np.clip(((t - t.min()) / max(t.max() - t.min(), 1e-9) * nbins).astype(int), 0, nbins - 1)
    resid = edge_points - (c + t[:, None] * d)
    counts = np.bincount(bins, minlength=nbins)
    sums = np.column_stack([np.bincount(bins, weights=resid[:, k], minlength=nbins) for k in range(3)])
    means = sums[counts > 0] / counts[counts > 0, None]
    sagitta = float(np.linalg.norm(means, axis=1).max()) if len(means) else 0.0
    if sagitta < params.curved_sagitta_m:
        return "linear", np.array([c + t.min() * d, c + t.max() * d])
    # curved: the plane of the seam, then a smoothing spline through binned centroids ordered along it
    pc, pn, _ = fit_plane(edge_points)
    flat = edge_points - np.outer((edge_points - pc) @ pn, pn)
    s = order_along_curve(flat, 2.5 * voxel_m)
    ok = np.isfinite(s)
    flat, s = flat[ok], s[ok]
    step = max(2 * voxel_m, 0.004)
    nb = max(4, int(s.max() / step))
    sb = np.clip((s / max(s.max(), 1e-9) * nb).astype(int), 0, nb - 1)
    cent = np.array([flat[sb == k].mean(axis=0) for k in range(nb) if np.any(sb == k)])
    if len(cent) < 4:
        return "linear", np.array([c + t.min() * d, c + t.max() * d])
    tck, _ = splprep(cent.T, s=len(cent) * (0.5 * voxel_m) ** 2, k=3)
    dense = np.array(splev(np.linspace(0, 1, max(20, len(cent) * 4)), tck)).T
    return "curved", dense


def refine_linear(
    full: FullRes,
    ra: int | tuple[int, ...],
    rb: int | tuple[int, ...],
    line: FloatArray,
    na0: FloatArray,
    nb0: FloatArray,
    params: SeamParams,
    viewpoint: FloatArray,
    *,
    seed_labels: tuple[int, int] | None = None,
) -> list[tuple[FloatArray, FloatArray, FloatArray, float]] | None:
    """Intersect planes fitted to the full-resolution points of both surfaces near the seam.

    1. Seed: the regions' points near the coarse line give the first plane pair (or, with
       ``seed_labels``, the points of two coarse surface masks).
    2. Iterate: every full-resolution point near the line joins the face whose plane it is close to
       (regions facing another way are kept out), points near the junction (a few sigma) and near the
       seam's ends (where a third face meets it) are left out, the planes are refitted and intersected.
    3. Track: while both faces still support the line at an end of the search window, the window grows
       along the line, so a seam is found whole even when region growing saw only a piece of it.
    4. A seam split by a hole (an occluder, or two parts in line) is refitted piece by piece.
    Returns one (end points (2, 3), outward normal a, outward normal b, plane-fit RMS) per piece; None when
    a surface has too few points.
    """
    p0, p1 = line[0], line[-1]
    d = (p1 - p0) / np.linalg.norm(p1 - p0)
    R = params.refine_band_m
    center, direction = 0.5 * (p0 + p1), d
    half = 0.5 * float(np.linalg.norm(p1 - p0))
    window = (-half - R, half + R)
    idx = _indices_near_polyline(full, _segment(center, direction, window), R)
    if seed_labels is not None and full.labels is not None:
        lab = full.labels[idx]
        in_a, in_b = lab == seed_labels[0], lab == seed_labels[1]
    else:
        reg = full.regions[idx]
        in_a = np.isin(reg, np.atleast_1d(ra))
        in_b = np.isin(reg, np.atleast_1d(rb))
    if in_a.sum() < 20 or in_b.sum() < 20:
        return None
    exclude = max(params.refine_exclude_m, 0.5 * R / 3)
    t_lo, t_hi = -np.inf, np.inf
    fit = None
    runs: list[tuple[float, float]] = []
    for it in range(12):
        pts = full.points[idx]
        fit = _fit_plane_pair(
            pts, in_a, in_b, center, direction, exclude, R, (t_lo, t_hi), params, viewpoint, max_points=3000
        )
        if fit is None:
            return None
        ca, na, rms_a, cb, nb, rms_b = fit
        new_center, direction = plane_intersection(ca, na, cb, nb, center)
        if direction @ d < 0:
            direction = -direction
        shift = float((new_center - center) @ direction)
        moved = float(np.linalg.norm(new_center - center - shift * direction))
        center = new_center
        window = (window[0] - shift, window[1] - shift)
        exclude = max(params.refine_exclude_m, 2.5 * max(rms_a, rms_b))
        in_a, in_b = _membership(full, idx, pts, ca, na, rms_a, cb, nb, rms_b, params, seed_labels)
        runs = _runs_for(pts, in_a, in_b, center, direction, exclude, params)
        if not runs:
            return None
        lo, hi = runs[0][0], runs[-1][1]
        margin = max(0.003, 1.5 * exclude)
        if hi - lo > 4 * margin:
            t_lo, t_hi = lo + margin, hi - margin
        # track: grow the window where the seam reaches its edge
        grow_lo = lo < window[0] + R
        grow_hi = hi > window[1] - R
        if it >= 1 and not (grow_lo or grow_hi) and moved < 1e-5:
            break
        if grow_lo or grow_hi:
            step = max(0.03, 0.5 * (window[1] - window[0]))
            window = (window[0] - step * grow_lo, window[1] + step * grow_hi)
            idx = _indices_near_polyline(full, _segment(center, direction, window), R)
            pts = full.points[idx]
            in_a, in_b = _membership(full, idx, pts, ca, na, rms_a, cb, nb, rms_b, params, seed_labels)
    assert fit is not None
    # final fit on every point of the converged faces and extent
    final = _fit_plane_pair(
        full.points[idx], in_a, in_b, center, direction, exclude, R, (t_lo, t_hi), params, viewpoint
    )
    if final is not None:
        fit = final
        ca, na, rms_a, cb, nb, rms_b = fit
        center, direction = plane_intersection(ca, na, cb, nb, center)
        if direction @ d < 0:
            direction = -direction
    ca, na, rms_a, cb, nb, rms_b = fit
    # a fillet's faces each lie on the open side of the other's plane; on a convex edge they lie
    # behind it. Refinement may have settled on a different junction than the one classified, so check
    pts = full.points[idx]
    rel = pts - center
    _, dist_line = line_coordinates(pts, center, direction)
    ring = (dist_line > exclude) & (dist_line < R)
    if (ring & in_a).sum() < 10 or (ring & in_b).sum() < 10:
        return None
    side_a = float(np.median(rel[ring & in_a] @ nb))
    side_b = float(np.median(rel[ring & in_b] @ na))
    if side_a <= 0.5 * exclude or side_b <= 0.5 * exclude:
        return None
    if len(runs) > 1:
        # a hole split the seam: the pieces may be different parts whose faces are only nearly in line
        # (two stiffeners' faces a few mm apart), and one plane pair across both would tilt each piece
        pieces = [_refit_piece(full, idx, in_a, in_b, center, direction, run, exclude, params, viewpoint, seed_labels)
                  for run in runs]  # fmt: skip
    else:
        pieces = [(center, direction, runs[0], na, nb, max(rms_a, rms_b))]
    out: list[tuple[FloatArray, FloatArray, FloatArray, float]] = []
    for piece in pieces:
        if piece is None:
            continue
        c_k, d_k, (lo, hi), na_k, nb_k, rms_k = piece
        lo, hi = lo + params.end_trim_m, hi - params.end_trim_m
        if hi - lo >= params.min_length_m:
            out.append((np.array([c_k + lo * d_k, c_k + hi * d_k]), na_k, nb_k, rms_k))
    return out or None


def _refit_piece(
    full: FullRes,
    idx: NDArray[np.int64],
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    center: FloatArray,
    direction: FloatArray,
    run: tuple[float, float],
    exclude: float,
    params: SeamParams,
    viewpoint: FloatArray,
    seed_labels: tuple[int, int] | None,
) -> tuple[FloatArray, FloatArray, tuple[float, float], FloatArray, FloatArray, float] | None:
    """Fit the plane pair again on one piece's own points (its run along the line), and measure its run on
    the new line. Returns (point on the line, direction, (lo, hi) along it, normals, RMS) or None."""
    pts = full.points[idx]
    R = params.refine_band_m
    lo, hi = run
    for _ in range(2):
        margin = max(0.003, 1.5 * exclude)
        t_range = (lo + margin, hi - margin) if hi - lo > 4 * margin else (lo, hi)
        fit = _fit_plane_pair(pts, in_a, in_b, center, direction, exclude, R, t_range, params, viewpoint)
        if fit is None:
            return None
        ca, na, rms_a, cb, nb, rms_b = fit
        new_center, new_dir = plane_intersection(ca, na, cb, nb, center + 0.5 * (lo + hi) * direction)
        if new_dir @ direction < 0:
            new_dir = -new_dir
        in_a, in_b = _membership(full, idx, pts, ca, na, rms_a, cb, nb, rms_b, params, seed_labels)
        # the ends are measured again on the new line, within the piece's stretch: a better line may
        # shorten a piece, but not lengthen it by more than a bin (past a corner, flying pixels hang
        # near a face's plane)
        t_new, _ = line_coordinates(pts, new_center, new_dir)
        t_lo = float((center + lo * direction - new_center) @ new_dir) - params.support_bin_m
        t_hi = float((center + hi * direction - new_center) @ new_dir) + params.support_bin_m
        near = (t_new > t_lo) & (t_new < t_hi)
        runs = _runs_for(pts, in_a & near, in_b & near, new_center, new_dir, exclude, params)
        if not runs:
            return None
        center, direction = new_center, new_dir
        lo, hi = max(runs[0][0], t_lo), min(runs[-1][1], t_hi)
    return center, direction, (lo, hi), na, nb, max(rms_a, rms_b)


def line_coordinates(pts: FloatArray, center: FloatArray, direction: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(N,) position along a line through ``center`` with unit ``direction``, and (N,) distance from it."""
    rel = pts - center
    t = rel @ direction
    # Pythagoras instead of the perpendicular vectors: no (N, 3) temporaries (points lie within
    # centimetres of the line here, so the difference of squares loses nothing that matters)
    return t, np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0))


def _segment(center: FloatArray, direction: FloatArray, window: tuple[float, float]) -> FloatArray:
    return np.array([center + window[0] * direction, center + window[1] * direction])


def _fit_plane_pair(
    pts: FloatArray,
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    center: FloatArray,
    direction: FloatArray,
    exclude: float,
    band: float,
    t_range: tuple[float, float],
    params: SeamParams,
    viewpoint: FloatArray,
    max_points: int = 0,
) -> tuple[FloatArray, FloatArray, float, FloatArray, FloatArray, float] | None:
    t, dist_line = line_coordinates(pts, center, direction)
    use = (dist_line > exclude) & (dist_line < band) & (t > t_range[0]) & (t < t_range[1])
    sel_a, sel_b = np.flatnonzero(use & in_a), np.flatnonzero(use & in_b)
    if len(sel_a) < 10 or len(sel_b) < 10:
        return None
    if max_points:
        # evenly thinned (deterministic): the intermediate passes only need the planes roughly
        sel_a = sel_a[:: max(1, len(sel_a) // max_points)]
        sel_b = sel_b[:: max(1, len(sel_b) // max_points)]
    ca, na, rms_a, _ = fit_plane_robust(pts[sel_a], sigma_gate=params.plane_gate_sigma)
    cb, nb, rms_b, _ = fit_plane_robust(pts[sel_b], sigma_gate=params.plane_gate_sigma)
    na = orient_towards(na, ca, viewpoint)
    nb = orient_towards(nb, cb, viewpoint)
    if abs(na @ nb) > np.cos(np.radians(5.0)):
        return None
    return ca, na, rms_a, cb, nb, rms_b


def _membership(
    full: FullRes,
    idx: NDArray[np.int64],
    pts: FloatArray,
    ca: FloatArray,
    na: FloatArray,
    rms_a: float,
    cb: FloatArray,
    nb: FloatArray,
    rms_b: float,
    params: SeamParams,
    seed_labels: tuple[int, int] | None = None,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Each point joins the face whose plane it is near (within a few sigma, and nearer than to the
    other), provided its region faces that way (or, for a mask-seeded seam, its mask is that face's)."""
    da = np.abs((pts - ca) @ na)
    db = np.abs((pts - cb) @ nb)
    gate_a = params.plane_gate_sigma * max(rms_a, 2e-4)
    gate_b = params.plane_gate_sigma * max(rms_b, 2e-4)
    ok_a = full.compatible(idx, na)
    ok_b = full.compatible(idx, nb)
    if seed_labels is not None and full.labels is not None:
        lab = full.labels[idx]
        ok_a |= lab == seed_labels[0]
        ok_b |= lab == seed_labels[1]
    in_a = (da < gate_a) & (da < db) & ok_a
    in_b = (db < gate_b) & (db <= da) & ok_b
    return in_a, in_b


def _runs_for(
    both: FloatArray,
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    center: FloatArray,
    direction: FloatArray,
    exclude: float,
    params: SeamParams,
) -> list[tuple[float, float]]:
    """Only points clearly on one face count (beyond the exclusion zone, so the other face's plane cannot
    claim them). The seam runs where both faces are seen; a hole longer than ``max_hole_m`` splits it."""
    t, dist_line = line_coordinates(both, center, direction)
    near = (dist_line > max(0.0015, exclude)) & (dist_line < max(0.006, exclude + 0.004))
    ta, tb = t[near & in_a], t[near & in_b]
    if len(ta) < 5 or len(tb) < 5:
        return []
    return supported_runs(ta, tb, bin_m=params.support_bin_m, max_hole_m=params.max_hole_m)


def supported_runs(ta: FloatArray, tb: FloatArray, *, bin_m: float, max_hole_m: float) -> list[tuple[float, float]]:
    """Intervals of the seam parameter where both faces have points (bins of ``bin_m``), joined across
    holes up to ``max_hole_m``. Ends are the outermost supporting points of each run (robust: a bin
    counts once it holds points of both faces)."""
    t0 = min(ta.min(), tb.min())
    nb = int((max(ta.max(), tb.max()) - t0) / bin_m) + 1
    ha = np.bincount(((ta - t0) / bin_m).astype(int), minlength=nb)[:nb]
    hb = np.bincount(((tb - t0) / bin_m).astype(int), minlength=nb)[:nb]
    # a bin counts when both faces are there in earnest: a few stray points (a third face's corner,
    # flying pixels) do not extend a seam
    ok = (ha >= max(1.0, 0.3 * np.median(ha[ha > 0]))) & (hb >= max(1.0, 0.3 * np.median(hb[hb > 0])))
    runs: list[tuple[int, int]] = []
    max_hole = int(np.ceil(max_hole_m / bin_m))
    for i in (int(x) for x in np.flatnonzero(ok)):
        if runs and i - runs[-1][1] - 1 <= max_hole:
            runs[-1] = (runs[-1][0], i)
        else:
            runs.append((i, i))
    out = []
    for a, b in runs:
        lo_edge, hi_edge = t0 + a * bin_m, t0 + (b + 1) * bin_m
        in_a = ta[(ta >= lo_edge) & (ta < hi_edge)]
        in_b = tb[(tb >= lo_edge) & (tb < hi_edge)]
        out.append((max(in_a.min(), in_b.min()), min(in_a.max(), in_b.max())))
    return out


def refine_curve(
    full: FullRes,
    ra: int | tuple[int, ...],
    rb: int | tuple[int, ...],
    curve: FloatArray,
    params: SeamParams,
    viewpoint: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, float] | None:
    """Cross-section refinement of a curved seam: in thin slabs across the seam, fit the trace of each
    surface as a 2D line and intersect them; then track the seam beyond both ends of the coarse curve
    (extrapolate 2 mm along the tangent, fit the slab there, keep it while both faces are found near
    the prediction). Returns dense points, normals a / b and the median fit RMS."""
    from perception.evaluate import resample_polyline

    samples = resample_polyline(curve, params.curve_step_m)
    tang = np.gradient(samples, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
    fits: list[tuple[FloatArray, FloatArray, FloatArray, float]] = []
    for s, T in zip(samples, tang, strict=True):
        idx = np.asarray(full.tree.query_ball_point(s, params.refine_band_m), dtype=np.int64)
        if idx.size < 20:
            continue
        reg = full.regions[idx]
        in_a, in_b = np.isin(reg, np.atleast_1d(ra)), np.isin(reg, np.atleast_1d(rb))
        res = _slab_corner(full, idx, s, T, in_a, in_b, params, viewpoint)
        if res is not None:
            fits.append(res)
    fits = [f for f in fits if _seen_well(f, viewpoint, params)]
    if len(fits) < 4:
        return None
    fits = _track_curve(full, fits, params, viewpoint, forward=True)
    fits = _track_curve(full, fits, params, viewpoint, forward=False)
    pts = np.array([f[0] for f in fits])
    # light smoothing along the seam (3-point moving average, ends kept)
    sm = pts.copy()
    sm[1:-1] = (pts[:-2] + pts[1:-1] + pts[2:]) / 3.0
    # trim the ends
    seg = np.linalg.norm(np.diff(sm, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    keep = (cum >= params.end_trim_m) & (cum <= cum[-1] - params.end_trim_m)
    if keep.sum() < 2 or cum[-1] < params.min_length_m:
        return None
    na = np.array([f[1] for f in fits])
    nb = np.array([f[2] for f in fits])
    return sm[keep], na[keep], nb[keep], float(np.median([f[3] for f in fits]))


def _slab_corner(
    full: FullRes,
    idx: NDArray[np.int64],
    s: FloatArray,
    T: FloatArray,
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    params: SeamParams,
    viewpoint: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, float] | None:
    rel = full.points[idx] - s
    slab = np.abs(rel @ T) < params.slab_half_width_m
    res = _corner_2d(rel[slab], in_a[slab], in_b[slab], T, params, viewpoint - s)
    if res is None:
        return None
    corner, n_a, n_b, rms = res
    return s + corner, n_a, n_b, rms


def _seen_well(
    fit: tuple[FloatArray, FloatArray, FloatArray, float], viewpoint: FloatArray, params: SeamParams
) -> bool:
    """Both faces seen at less than ``max_incidence_rad``: beyond that, depth data are unreliable (and
    the simulator's ground truth stops there too)."""
    p, n_a, n_b, _ = fit
    v = viewpoint - p
    v /= max(float(np.linalg.norm(v)), 1e-12)
    c = np.cos(params.max_incidence_rad)
    return bool(abs(n_a @ v) >= c and abs(n_b @ v) >= c)


def _track_curve(
    full: FullRes,
    fits: list[tuple[FloatArray, FloatArray, FloatArray, float]],
    params: SeamParams,
    viewpoint: FloatArray,
    *,
    forward: bool,
    max_steps: int = 60,
) -> list[tuple[FloatArray, FloatArray, FloatArray, float]]:
    """Extend a curved seam past one end while the slab fit keeps finding both faces where expected."""
    seq = list(fits) if forward else list(reversed(fits))
    step = params.curve_step_m
    for _ in range(max_steps):
        p2, p1, p0 = seq[-3][0], seq[-2][0], seq[-1][0]
        # second-order prediction keeps the curvature
        nxt = p0 + (p0 - p1) + ((p0 - p1) - (p1 - p2))
        T = nxt - p0
        norm = np.linalg.norm(T)
        if norm < 1e-9:
            break
        T /= norm
        nxt = p0 + T * step
        idx = np.asarray(full.tree.query_ball_point(nxt, params.refine_band_m), dtype=np.int64)
        if idx.size < 20:
            break
        _, n_a, n_b, rms = seq[-1]
        q = full.points[idx]
        da = np.abs((q - p0) @ n_a)
        db = np.abs((q - p0) @ n_b)
        gate = params.plane_gate_sigma * max(rms, 3e-4) + 0.001
        in_a = (da < gate) & (da < db)
        in_b = (db < gate) & (db <= da)
        res = _slab_corner(full, idx, nxt, T, in_a, in_b, params, viewpoint)
        if res is None or np.linalg.norm(res[0] - nxt) > 0.0015:
            break
        if not _seen_well(res, viewpoint, params):
            break
        # both faces must still be seen in earnest on this slab, not a few stray points
        if min(int(in_a.sum()), int(in_b.sum())) < 15:
            break
        seq.append(res)
    return seq if forward else list(reversed(seq))


def _corner_2d(
    rel: FloatArray,
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    T: FloatArray,
    params: SeamParams,
    to_view: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, float] | None:
    """Intersect the 2D traces of two surfaces in a slab (coordinates relative to the slab centre)."""
    if len(rel) < 12:
        return None
    # 2D basis of the cross-section plane
    e1 = np.cross(T, [0.0, 0.0, 1.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(T, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(T, e1)
    xy = np.column_stack([rel @ e1, rel @ e2])
    corner = np.zeros(2)
    exclude = 0.5 * params.refine_band_m / 3
    la = lb = None
    for _ in range(3):
        dist = np.linalg.norm(xy - corner, axis=1)
        sa = in_a & (dist > exclude)
        sb = in_b & (dist > exclude)
        if sa.sum() < 6 or sb.sum() < 6:
            return None
        la = _fit_line_2d(xy[sa], params.plane_gate_sigma)
        lb = _fit_line_2d(xy[sb], params.plane_gate_sigma)
        (ca, da, ra_), (cb, db, rb_) = la, lb
        cross = da[0] * db[1] - da[1] * db[0]
        if abs(cross) < np.sin(np.radians(10)):
            return None
        # ca + s da = cb + u db
        s = ((cb - ca)[0] * db[1] - (cb - ca)[1] * db[0]) / cross
        corner = ca + s * da
        # membership by distance to the two lines
        na2 = np.array([-da[1], da[0]])
        nb2 = np.array([-db[1], db[0]])
        dA = np.abs((xy - ca) @ na2)
        dB = np.abs((xy - cb) @ nb2)
        gA = params.plane_gate_sigma * max(ra_, 2e-4)
        gB = params.plane_gate_sigma * max(rb_, 2e-4)
        in_a = (dA < gA) & (dA < dB)
        in_b = (dB < gB) & (dB <= dA)
        exclude = params.refine_exclude_m
    assert la is not None and lb is not None
    (ca, da, ra_), (cb, db, rb_) = la, lb
    n_a3 = np.array([-da[1], da[0]]) @ np.vstack([e1, e2])
    n_b3 = np.array([-db[1], db[0]]) @ np.vstack([e1, e2])
    p3 = corner @ np.vstack([e1, e2])
    n_a3 = orient_towards(n_a3, p3, to_view)
    n_b3 = orient_towards(n_b3, p3, to_view)
    return p3, n_a3, n_b3, max(ra_, rb_)


def _fit_line_2d(p: FloatArray, gate: float) -> tuple[FloatArray, FloatArray, float]:
    keep = np.ones(len(p), bool)
    for _ in range(3):
        c = p[keep].mean(axis=0)
        _, s, vt = np.linalg.svd(p[keep] - c, full_matrices=False)
        d = vt[0]
        n = np.array([-d[1], d[0]])
        rms = float(s[1] / np.sqrt(keep.sum()))
        new = np.abs((p - c) @ n) <= max(gate * rms, 1e-5)
        if new.sum() < 4 or np.array_equal(new, keep):
            break
        keep = new
    return c, d, rms


def butt_from_surfaces(
    pa: FloatArray,
    pb: FloatArray,
    scanlines: list[FloatArray] | Callable[[], list[FloatArray]],
    params: SeamParams,
    viewpoint: FloatArray,
) -> tuple[FloatArray, FloatArray, float, float] | None:
    """A butt joint between two surfaces: ``pa``, ``pb`` are the points of the two masks near where they
    meet; ``scanlines`` are the valid points of each image row (or column) crossing the joint, in
    order, or a callable giving them (built only once the planes say it may be a butt joint; masks are
    imprecise right at a gap, so the edges are traced on every point). Both surfaces must lie on one
    plane, and a real gap must separate them.

    On each scanline the gap is the widest step between consecutive top-surface samples near the joint
    (one scanline, one last sample per plate: no maximum over noisy rows, which would be biased).
    A plate's edge is its side wall where the camera sees that wall inside the gap, otherwise its
    last sample plus half the sample spacing (the mean shortfall of the last pixel).
    The seam is the mid-line of the two edge lines. Returns (end points (2, 3), plane normal, RMS,
    gap width), or None when it is not a butt joint.
    """
    if len(pa) < 30 or len(pb) < 30:
        return None
    # the plane tests need a few thousand points, not a mask's tens of thousands (evenly thinned)
    ca, na, rms_a, _ = fit_plane_robust(pa[:: max(1, len(pa) // 4000)], sigma_gate=params.plane_gate_sigma)
    cb, nb, rms_b, _ = fit_plane_robust(pb[:: max(1, len(pb) // 4000)], sigma_gate=params.plane_gate_sigma)
    if max(rms_a, rms_b) > params.butt_max_rms_m:
        return None  # not plates: curved or mixed surfaces
    if abs(na @ nb) < np.cos(params.max_coplanar_rad):
        return None
    tol = 0.002 + 3 * max(rms_a, rms_b)
    if abs((cb - ca) @ na) > tol or abs((ca - cb) @ nb) > tol:
        return None
    c, n, rms, keep = fit_plane_robust(np.vstack([pa, pb]), sigma_gate=params.plane_gate_sigma)
    if rms > 1.5 * max(rms_a, rms_b, 2e-4):
        return None
    n = orient_towards(n, c, viewpoint)
    qa, qb = pa[keep[: len(pa)]], pb[keep[len(pa) :]]
    da, _ = kdtree(qb).query(qa, distance_upper_bound=0.006)
    db, _ = kdtree(qa).query(qb, distance_upper_bound=0.006)
    border = np.vstack([qa[np.isfinite(da)], qb[np.isfinite(db)]])
    if len(border) < 20:
        return None
    mid, d = fit_line(border - np.outer((border - c) @ n, n))
    d -= (d @ n) * n
    d /= np.linalg.norm(d)
    across = np.cross(n, d)
    if (qb.mean(axis=0) - qa.mean(axis=0)) @ across < 0:
        across = -across
    sigma = max(rms, 1e-4)
    if callable(scanlines):
        scanlines = scanlines()
    rows = []
    for line_pts in scanlines:
        # points stay in pixel order: the last pixel on each plate is chosen by where it is in the
        # image, not by its (noisy) coordinate, so it carries noise but no selection bias
        rel = line_pts - mid
        x, h = rel @ across, (line_pts - c) @ n
        near = np.abs(x) < 0.006
        if near.sum() < 6:
            continue
        x, h, tt = x[near], h[near], rel[near] @ d
        top = np.flatnonzero(np.abs(h) < 2.5 * sigma)
        if len(top) < 6:
            continue
        xs = x[top]
        if xs[-1] < xs[0]:  # scanline runs from b to a: walk it from a to b
            top, xs = top[::-1], xs[::-1]
        steps = np.diff(xs)
        k = int(np.argmax(steps))
        spacing = float(np.median(np.abs(steps)))
        if steps[k] < 2.5 * max(spacing, 1e-5) or k < 1 or k + 2 >= len(xs):
            continue  # no gap on this scanline
        ia, ib = top[k], top[k + 1]
        xa_last, xb_first = float(x[ia]), float(x[ib])
        lo_i, hi_i = min(ia, ib), max(ia, ib)
        between = np.arange(lo_i + 1, hi_i)
        walls = between[h[between] < -3.0 * sigma]
        wall_b = x[walls][np.abs(x[walls] - xb_first) < 0.0005]
        wall_a = x[walls][np.abs(x[walls] - xa_last) < 0.0005]
        # signed steps: noise makes |step| too large on average, the signed median stays unbiased
        sp_a = float(np.median(np.diff(xs[: k + 1]))) if k >= 1 else spacing
        sp_b = float(np.median(np.diff(xs[k + 1 :]))) if k + 2 < len(xs) else spacing
        # the last pixel on a plate falls short of its edge by half the local spacing on average
        edge_a = float(np.median(wall_a)) if len(wall_a) >= 2 else xa_last + 0.5 * sp_a
        edge_b = float(np.median(wall_b)) if len(wall_b) >= 2 else xb_first - 0.5 * sp_b
        rows.append((float(np.mean(tt)), edge_a, edge_b))
    if len(rows) < 5:
        return None
    crossing = sum(1 for line_pts in scanlines if len(line_pts) >= 6)
    if len(rows) < params.butt_min_gap_share * max(crossing, 1):
        return None  # a real gap shows on most scanlines across the joint; noise shows on a few
    arr = np.array(rows)
    A = np.column_stack([np.ones(len(arr)), arr[:, 0]])
    coefs = []
    for col in (1, 2):
        # robust line: least squares, then reject beyond 3 MAD-sigmas and refit, twice
        ok = np.ones(len(arr), bool)
        coef, *_ = np.linalg.lstsq(A, arr[:, col], rcond=None)
        for _ in range(2):
            resid = arr[:, col] - A @ coef
            mad_sigma = 1.4826 * float(np.median(np.abs(resid[ok] - np.median(resid[ok]))))
            ok = np.abs(resid) < 3 * max(mad_sigma, 1e-5)
            coef, *_ = np.linalg.lstsq(A[ok], arr[ok, col], rcond=None)
        coefs.append(coef)
    lo = float(arr[:, 0].min()) + params.end_trim_m
    hi = float(arr[:, 0].max()) - params.end_trim_m
    if hi - lo < params.min_length_m:
        return None
    tt = np.array([lo, hi])
    xa = coefs[0][0] + coefs[0][1] * tt
    xb = coefs[1][0] + coefs[1][1] * tt
    gap = float(np.mean(xb - xa))
    if not params.min_gap_m <= gap <= params.max_gap_m:
        return None
    base = mid + np.outer(tt, d)
    base = base - np.outer((base - c) @ n, n)
    ends = base + np.outer(0.5 * (xa + xb), across)
    return ends, n, rms, gap
