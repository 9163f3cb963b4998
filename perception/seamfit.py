"""From regions to seams: edge points between regions, seam candidates, the paper's line / curve fits,
and the refinement from full-resolution points that goes below the voxel size.

Geometry conventions: camera frame, metres; surface normals point out of the material, towards the
camera (the side a torch comes from).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from perception.cloud import Neighbourhoods
from perception.fits import (
    connected_components,
    fit_line,
    fit_plane,
    fit_plane_robust,
    line_coordinates,
    order_along_curve,
    orient_towards,
    plane_intersection,
)

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
    lab = connected_components(coords, link_m)
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


# long: steps 2 and 3 below are one loop over a dozen shared variables (faces, line, window, extent); split apart
# they would be passed back and forth, and the algorithm would be harder to follow.
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
    in_a, in_b = _seed_faces(full, idx, ra, rb, seed_labels)
    if in_a.sum() < 20 or in_b.sum() < 20:
        return None
    exclude = max(params.refine_exclude_m, 0.5 * R / 3)
    t_lo, t_hi = -np.inf, np.inf
    fit = None
    runs: list[tuple[float, float]] = []
    # steps 2 and 3 are one loop over shared state (faces, line, window, extent): kept together on purpose
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
    if not _faces_on_open_sides(full.points[idx], in_a, in_b, center, direction, na, nb, exclude=exclude, band_m=R):
        return None
    if len(runs) == 1:
        return _trimmed([(center, direction, runs[0], na, nb, max(rms_a, rms_b))], params) or None
    # a hole split the seam: the pieces may be different parts whose faces are only nearly in line
    # (two stiffeners' faces a few mm apart), and one plane pair across both would tilt each piece
    pieces = [_refit_piece(full, idx, in_a, in_b, center, direction, run, exclude, params, viewpoint, seed_labels)
              for run in runs]  # fmt: skip
    return _trimmed(pieces, params) or None


def _seed_faces(
    full: FullRes,
    idx: NDArray[np.int64],
    ra: int | tuple[int, ...],
    rb: int | tuple[int, ...],
    seed_labels: tuple[int, int] | None,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Which of the points ``idx`` seed face a and face b: those of regions ``ra`` / ``rb``, or of the two coarse
    surface masks ``seed_labels`` when given."""
    if seed_labels is not None and full.labels is not None:
        lab = full.labels[idx]
        return lab == seed_labels[0], lab == seed_labels[1]
    reg = full.regions[idx]
    return np.isin(reg, np.atleast_1d(ra)), np.isin(reg, np.atleast_1d(rb))


def _faces_on_open_sides(
    pts: FloatArray,
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    center: FloatArray,
    direction: FloatArray,
    na: FloatArray,
    nb: FloatArray,
    *,
    exclude: float,
    band_m: float,
) -> bool:
    """A fillet's faces each lie on the open side of the other's plane; on a convex edge they lie behind it.
    Refinement may have settled on a different junction than the one classified, so this checks it on the
    (N, 3) points ``pts`` in the ring between ``exclude`` and ``band_m`` from the line."""
    rel = pts - center
    _, dist_line = line_coordinates(pts, center, direction)
    ring = (dist_line > exclude) & (dist_line < band_m)
    if (ring & in_a).sum() < 10 or (ring & in_b).sum() < 10:
        return False
    side_a = float(np.median(rel[ring & in_a] @ nb))
    side_b = float(np.median(rel[ring & in_b] @ na))
    return not (side_a <= 0.5 * exclude or side_b <= 0.5 * exclude)


def _trimmed(
    pieces: list[tuple[FloatArray, FloatArray, tuple[float, float], FloatArray, FloatArray, float] | None],
    params: SeamParams,
) -> list[tuple[FloatArray, FloatArray, FloatArray, float]]:
    """Each piece as (end points (2, 3), normal a, normal b, RMS), its ends trimmed by ``end_trim_m``; pieces
    shorter than ``min_length_m`` after trimming (and None pieces) dropped."""
    out: list[tuple[FloatArray, FloatArray, FloatArray, float]] = []
    for piece in pieces:
        if piece is None:
            continue
        c_k, d_k, (lo, hi), na_k, nb_k, rms_k = piece
        lo, hi = lo + params.end_trim_m, hi - params.end_trim_m
        if hi - lo >= params.min_length_m:
            out.append((np.array([c_k + lo * d_k, c_k + hi * d_k]), na_k, nb_k, rms_k))
    return out


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


