"""The fine stage on voxel regions (the ``refined`` and ``paper`` methods): from a cropped cloud to seam geometry.

    pass-through -> voxel grid -> KD-tree -> normals + curvature -> region growing (geometry alone)
    -> edges between regions, concave ones kept (fillet candidates) -> coarse fit (line | curve)
    -> collinear pieces joined -> mask-pair candidates (two coarse masks meeting at a concave fold)
    -> refinement on the full-resolution points (plane pair | cross-section tracking) -> duplicates dropped

:func:`regions_to_seams` runs the steps, each timed in the :class:`perception.detect_params.StepLog`;
:func:`perception.detect.detect` and :func:`perception.detect.detect_cloud` call it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from perception.cloud import (
    Neighbourhoods,
    VoxelGrid,
    grow_regions,
    kdtree,
    merge_coplanar_regions,
    neighbourhoods,
    normals_and_curvature,
    pass_through,
    voxel_downsample,
)
from perception.curve_refine import refine_curve
from perception.detect_params import DetectParams, StepLog
from perception.errors import NoSeamFound
from perception.fits import fit_plane
from perception.seamfit import (
    EdgeSet,
    FullRes,
    SeamGeometry,
    SeamParams,
    classify_junction_local,
    fit_edge_path,
    indices_near_polyline,
    refine_linear,
    region_edges,
)

FloatArray = NDArray[np.float64]

REFERENCE_VOXEL_M = 0.003  # the lengths in SeamParams are tuned for this voxel (the paper's)


def regions_to_seams(
    pts: FloatArray,
    labels: NDArray[np.int32] | None,
    params: DetectParams,
    log: StepLog,
    viewpoint: FloatArray,
    pairs: dict[tuple[int, int], int] | None = None,
    spacing_m: float = 0.0,
) -> list[SeamGeometry]:
    """The fine stage on an unorganized cloud (camera frame): ``pts`` (N, 3) metres, ``labels`` (N,) each point's
    coarse mask (-1 background; None for a bare cloud), ``pairs`` the masks that meet in the seam band.
    ``spacing_m``: a sparse scan's sample spacing (0: dense). Raises NoSeamFound when the pass-through leaves
    fewer than 50 points."""
    pts, lab, grid = _filtered_grid(pts, labels, params, log)
    if params.method != "paper":  # the paper's plain method stays as published
        params = replace(params, seams=_scaled_to_data(params.seams, params.voxel_m, spacing_m))
    sp = params.seams
    with log.step("kdtree"):
        nbh = neighbourhoods(grid.centroids, k=params.knn, radius_m=params.normal_radius_voxels * params.voxel_m)
    with log.step("normals"):
        normals, curvature = normals_and_curvature(grid.centroids, nbh, viewpoint=viewpoint)
    with log.step("regions"):
        # geometry alone decides the regions (as in the paper); mask labels only vote afterwards, so
        # a mask that bleeds over a fold cannot split or join surfaces
        regions = grow_regions(normals, curvature, nbh, params=params.regions)
        regions = merge_coplanar_regions(grid.centroids, regions, nbh)
    log.counts["regions"] = int(regions.max(initial=-1)) + 1
    with log.step("candidates"):
        full, curved_regions = _full_res(pts, lab, grid, regions, normals)
        cands = _fillet_edges(grid.centroids, regions, nbh, params, viewpoint)
    log.counts["candidates"] = len(cands)
    with log.step("fit"):
        fitted = []
        for e, center_pts, na, nb, rms in cands:
            kind, line = fit_edge_path(center_pts, sp, params.voxel_m)
            fitted.append(_Cand(kind, line, (e.a,), (e.b,), na, nb, rms, len(center_pts)))
        fitted = _group_collinear(fitted, voxel_m=params.voxel_m)
        if lab is not None and pairs and params.method != "paper":
            fitted += _mask_pair_candidates(grid.centroids, grid.labels, pairs, fitted, sp, viewpoint, params.voxel_m)
    log.counts["seam_groups"] = len(fitted)
    with log.step("refine"):
        out = _refined(fitted, full, grid, regions, nbh, params, viewpoint, curved_regions=curved_regions)
    return out


def _filtered_grid(
    pts: FloatArray, labels: NDArray[np.int32] | None, params: DetectParams, log: StepLog
) -> tuple[FloatArray, NDArray[np.int32] | None, VoxelGrid]:
    """The points inside the working range and box, their labels, and their voxel grid; each labelled voxel
    set's plane goes into ``log.voxel_planes`` (the butt-joint step reads them)."""
    with log.step("pass_through"):
        keep = pass_through(
            pts,
            z_range_m=params.z_range_m,
            box_min=None if params.workspace_min_m is None else np.asarray(params.workspace_min_m),
            box_max=None if params.workspace_max_m is None else np.asarray(params.workspace_max_m),
        )
        pts = pts[keep]
        lab = None if labels is None else labels[keep]
    log.counts["pass_through"] = len(pts)
    if len(pts) < 50:
        raise NoSeamFound(f"only {len(pts)} points left after the pass-through filter")
    with log.step("voxel"):
        grid = voxel_downsample(pts, voxel_m=params.voxel_m, labels=lab)
        if lab is not None:
            for k in np.unique(grid.labels[grid.labels >= 0]):
                q = grid.centroids[grid.labels == k]
                if len(q) >= 6:
                    log.voxel_planes[int(k)] = fit_plane(q)
    log.counts["downsampled"] = len(grid.centroids)
    return pts, lab, grid


def _full_res(
    pts: FloatArray,
    lab: NDArray[np.int32] | None,
    grid: VoxelGrid,
    regions: NDArray[np.int32],
    normals: FloatArray,
) -> tuple[FullRes, frozenset[int]]:
    """The full-resolution points with their voxel's region and normal and each region's mean normal, and the
    regions whose normals fan out (mean resultant below cos 12 deg: curved surfaces)."""
    n_reg = int(regions.max(initial=-1)) + 1
    ok_r = regions >= 0
    region_normals = (
        np.column_stack([np.bincount(regions[ok_r], weights=normals[ok_r, k], minlength=n_reg) for k in range(3)])
        .astype(np.float64)
        .reshape(n_reg, 3)
    )
    counts_r = np.bincount(regions[ok_r], minlength=n_reg).astype(np.float64)
    resultant = np.linalg.norm(region_normals, axis=1) / np.maximum(counts_r, 1.0)
    curved_regions = frozenset(int(r) for r in np.flatnonzero(resultant < np.cos(np.radians(12.0))))
    region_normals /= np.maximum(np.linalg.norm(region_normals, axis=1, keepdims=True), 1e-12)
    full = FullRes(pts, regions[grid.point_voxel], kdtree(pts), region_normals, normals[grid.point_voxel], lab)
    return full, curved_regions


def _fillet_edges(
    centroids: FloatArray, regions: NDArray[np.int32], nbh: Neighbourhoods, params: DetectParams, viewpoint: FloatArray
) -> list[tuple[EdgeSet, FloatArray, FloatArray, FloatArray, float]]:
    """The edges between two regions that are concave junctions (convex edges are outer edges; coplanar
    neighbours are one surface): (edge, its voxel centroids, the two sides' normals, fit RMS)."""
    sp = params.seams
    edges = region_edges(
        regions,
        nbh,
        min_points=sp.min_edge_points,
        link_m=2.5 * params.voxel_m,
        bridge=params.voxel_m > REFERENCE_VOXEL_M and params.method != "paper",
    )
    trees: dict[int, cKDTree] = {}

    def tree_of(r: int) -> cKDTree:
        if r not in trees:
            trees[r] = kdtree(centroids[regions == r])
        return trees[r]

    cands = []
    for e in edges:
        center_pts = np.vstack([centroids[e.points_a], centroids[e.points_b]])
        joint, na, nb, rms = classify_junction_local(center_pts, tree_of(e.a), tree_of(e.b), sp, viewpoint)
        if joint == "fillet":
            cands.append((e, center_pts, na, nb, rms))
    return cands


def _refined(
    fitted: list[_Cand],
    full: FullRes,
    grid: VoxelGrid,
    regions: NDArray[np.int32],
    nbh: Neighbourhoods,
    params: DetectParams,
    viewpoint: FloatArray,
    *,
    curved_regions: frozenset[int],
) -> list[SeamGeometry]:
    """Each candidate refined on the full-resolution points, sides named by their masks, duplicates dropped."""
    sp = params.seams
    out: list[SeamGeometry] = []
    for c in fitted:
        if c.seed_labels:
            labs = c.seed_labels
        else:
            # each side is named by the masks of its voxels near the seam (a region can be larger
            # than the surface: without the crop a plate's top may grow into the table around it)
            near = indices_near_polyline(nbh.tree, len(grid.centroids), c.line, sp.patch_radius_m)
            la = _majority(grid.labels[near], regions[near], c.regions_a)
            # geometry decides: when one mask bled over the fold (a face seen at a grazing angle
            # merged into the plate), the other side is named by its own best other label
            labs = (la, _majority(grid.labels[near], regions[near], c.regions_b, avoid=la))
        if full.labels is not None and min(labs) < 0:
            # one side is mostly background (table, fixture): a workpiece edge standing on the
            # table is a concave junction, but not a seam of the workpiece
            continue
        curved_first = bool(curved_regions & set(c.regions_a + c.regions_b))
        out.extend(_finish(full, c, labs, params, viewpoint, curved_first=curved_first))
    return _dedupe(out)


def _scaled_to_data(sp: SeamParams, voxel_m: float, spacing_m: float) -> SeamParams:
    """Lengths tuned for the reference voxel and a dense scan, adapted to coarser data. With a coarser
    voxel the local patches (on voxel centroids) grow in proportion, so each still holds a few voxels;
    with a sparse scan (``spacing_m``: its sample spacing, 0 for a camera's dense cloud) the
    full-resolution refinement band, support bins and tolerated holes grow to hold a few samples. On the
    reference voxel and dense data nothing changes."""
    f = max(voxel_m / REFERENCE_VOXEL_M, 1.0)
    return replace(
        sp,
        patch_radius_m=sp.patch_radius_m * f,
        refine_band_m=max(sp.refine_band_m, 4.0 * spacing_m),
        support_bin_m=max(sp.support_bin_m, 1.2 * spacing_m),
        max_hole_m=max(sp.max_hole_m, 3.0 * spacing_m),
    )



@dataclass(frozen=True)
class _Cand:
    """A seam candidate: the coarse centre line and the region(s) on each side."""

    kind: str
    line: FloatArray
    regions_a: tuple[int, ...]
    regions_b: tuple[int, ...]
    na: FloatArray
    nb: FloatArray
    rms: float
    support: int
    seed_labels: tuple[int, int] | None = None  # a candidate proposed by two coarse masks



def _mask_pair_candidates(
    centroids: FloatArray,
    voxel_labels: NDArray[np.int32],
    pairs: dict[tuple[int, int], int],
    have: list[_Cand],
    sp: SeamParams,
    viewpoint: FloatArray,
    voxel_m: float,
) -> list[_Cand]:
    """Fillet candidates proposed by the coarse stage: two surface masks meeting in the seam band at a
    concave fold. They catch junctions region growing missed (a face only a few voxels wide, like the
    edge of a lap joint's upper plate); those a region candidate already covers are skipped. Proposed
    on the labelled voxel centroids (cheap); the refinement then works on full-resolution points."""
    from perception.fits import plane_intersection
    from perception.seamfit import classify_junction

    out: list[_Cand] = []
    trees: dict[int, tuple[FloatArray, cKDTree]] = {}

    def tree_of(k: int) -> tuple[FloatArray, cKDTree]:
        if k not in trees:
            p = centroids[voxel_labels == k]
            trees[k] = (p, kdtree(p))
        return trees[k]

    reach = max(0.008, 2.5 * voxel_m)
    for i, j in sorted(pairs):
        pa, ta = tree_of(i)
        pb, tb = tree_of(j)
        if len(pa) < 6 or len(pb) < 6:
            continue
        da, _ = tb.query(pa, distance_upper_bound=reach)
        db, _ = ta.query(pb, distance_upper_bound=reach)
        ba, bb = pa[np.isfinite(da)], pb[np.isfinite(db)]
        if len(ba) < 4 or len(bb) < 4:
            continue
        joint, na, nb, rms = classify_junction(ba, bb, sp, viewpoint)
        if joint != "fillet":
            continue
        border = np.vstack([ba, bb])
        p0, d = plane_intersection(ba.mean(axis=0), na, bb.mean(axis=0), nb, border.mean(axis=0))
        t = (border - p0) @ d
        line = np.array([p0 + t.min() * d, p0 + t.max() * d])
        if any(_covers(c.line, line) for c in have):
            continue
        out.append(_Cand("linear", line, (), (), na, nb, rms, len(border), seed_labels=(i, j)))
    return out



def _covers(a: FloatArray, b: FloatArray, *, tol_m: float = 0.004) -> bool:
    """True when line b lies along line a (both ends within ``tol_m`` of a's line) and they overlap."""
    d = a[-1] - a[0]
    la = float(np.linalg.norm(d))
    if la < 1e-9:
        return False
    d = d / la
    rel = b[[0, -1]] - a[0]
    t = rel @ d
    if np.linalg.norm(rel - np.outer(t, d), axis=1).max() > tol_m:
        return False
    return bool(t.max() > 0 and t.min() < la)



def _majority(
    voxel_labels: NDArray[np.int32], regions: NDArray[np.int32], ids: tuple[int, ...], *, avoid: int | None = None
) -> int:
    """The mask label most of these regions' voxels carry (-1: background); with ``avoid``, the most common
    other workpiece label when that one wins (and ``avoid`` itself when there is none)."""
    lab = voxel_labels[np.isin(regions, ids)]
    if not lab.size:
        return -1
    counts = np.bincount(lab + 1)
    best = int(counts.argmax()) - 1
    if avoid is not None and best == avoid >= 0:
        counts[avoid + 1] = 0
        counts[0] = 0
        if counts.any():
            return int(counts.argmax()) - 1
    return best



def _group_collinear(
    cands: list[_Cand], *, voxel_m: float, max_angle_deg: float = 15.0, max_gap_m: float = 0.06
) -> list[_Cand]:
    """Join linear candidates that are pieces of one junction (a face split into several regions, or
    edge points interrupted by dropouts): same line within a voxel or so, gaps under ``max_gap_m``.
    Joining is generous on purpose: the refinement splits the line again wherever the full-resolution
    points show a real interruption."""
    lin = [c for c in cands if c.kind == "linear"]
    rest = [c for c in cands if c.kind != "linear"]
    cos_t = np.cos(np.radians(max_angle_deg))
    used = [False] * len(lin)
    out: list[_Cand] = []
    for i, ci in enumerate(lin):
        if used[i]:
            continue
        used[i] = True
        group = [ci]
        changed = True
        while changed:
            changed = False
            for j, cj in enumerate(lin):
                if used[j]:
                    continue
                if any(_same_line(g, cj, cos_t, 1.5 * voxel_m, max_gap_m) for g in group):
                    used[j] = True
                    group.append(cj)
                    changed = True
        out.append(_merge(group))
    return out + rest



def _same_line(a: _Cand, b: _Cand, cos_t: float, max_dist: float, max_gap: float) -> bool:
    """b continues a: both of b's ends lie on a's line (short pieces have poor directions of their own,
    so the test uses the longer piece's line), the gap between them is short, and the surfaces agree."""
    if np.linalg.norm(a.line[-1] - a.line[0]) < np.linalg.norm(b.line[-1] - b.line[0]):
        a, b = b, a
    da = a.line[-1] - a.line[0]
    la = float(np.linalg.norm(da))
    da = da / la
    rel = b.line[[0, -1]] - a.line[0]
    t = rel @ da
    if np.linalg.norm(rel - np.outer(t, da), axis=1).max() > max_dist:
        return False
    gap = max(t.min() - la, -t.max(), 0.0)
    if gap > max_gap:
        return False
    # the same two surfaces: the normals on each side must agree (in some pairing)
    return bool(min(a.na @ b.na, a.nb @ b.nb) > cos_t or min(a.na @ b.nb, a.nb @ b.na) > cos_t)



def _merge(group: list[_Cand]) -> _Cand:
    if len(group) == 1:
        return group[0]
    ref = max(group, key=lambda c: c.support)
    d = ref.line[-1] - ref.line[0]
    d /= np.linalg.norm(d)
    regions_a: list[int] = []
    regions_b: list[int] = []
    ts = []
    for c in group:
        same = min(ref.na @ c.na, ref.nb @ c.nb) >= min(ref.na @ c.nb, ref.nb @ c.na)
        regions_a += list(c.regions_a if same else c.regions_b)
        regions_b += list(c.regions_b if same else c.regions_a)
        ts += [(p - ref.line[0]) @ d for p in c.line]
    line = np.array([ref.line[0] + min(ts) * d, ref.line[0] + max(ts) * d])
    return _Cand(
        "linear",
        line,
        tuple(sorted(set(regions_a))),
        tuple(sorted(set(regions_b))),
        ref.na,
        ref.nb,
        max(c.rms for c in group),
        sum(c.support for c in group),
    )



def _finish(
    full: FullRes,
    c: _Cand,
    labs: tuple[int, int],
    params: DetectParams,
    viewpoint: FloatArray,
    *,
    curved_first: bool = False,
) -> list[SeamGeometry]:
    sp = params.seams
    ra, rb = c.regions_a, c.regions_b
    line = c.line
    if params.method == "paper" or not sp.refine:
        seg = np.linalg.norm(np.diff(line, axis=0), axis=1).sum()
        if seg < sp.min_length_m:
            return []
        nn = len(line)
        kind: Literal["linear", "curved"] = "curved" if c.kind == "curved" else "linear"
        return [
            SeamGeometry(
                kind,
                "fillet",
                line,
                np.tile(c.na, (nn, 1)),
                np.tile(c.nb, (nn, 1)),
                (ra[0] if ra else -1, rb[0] if rb else -1),
                labs,
                c.support,
                c.rms,
            )
        ]
    if c.kind == "linear" and curved_first and ra and rb:
        # a straight-looking piece next to a curved surface: a plane pair would fit a short chord
        curved = _curve_fallback(full, c, labs, params, viewpoint)
        if curved and curved[0].kind == "curved":
            return curved
    if c.kind == "linear":
        res_l = refine_linear(full, ra, rb, line, c.na, c.nb, sp, viewpoint, seed_labels=c.seed_labels)
        if res_l is None:
            # short pieces of a curved junction look straight to the coarse fit; the plane pair then
            # fails, but cross-section tracking follows the curve from the piece
            return _curve_fallback(full, c, labs, params, viewpoint) if ra and rb else []
        return [
            SeamGeometry(
                "linear",
                "fillet",
                ends,
                np.tile(n_a, (2, 1)),
                np.tile(n_b, (2, 1)),
                (ra[0] if ra else -1, rb[0] if rb else -1),
                labs,
                c.support,
                r,
            )
            for ends, n_a, n_b, r in res_l
        ]
    res_c = refine_curve(full, ra, rb, line, sp, viewpoint)
    if res_c is None:
        return []
    pts, n_a, n_b, r = res_c
    return [
        SeamGeometry("curved", "fillet", pts, n_a, n_b, (ra[0] if ra else -1, rb[0] if rb else -1), labs, c.support, r)
    ]



def _curve_fallback(
    full: FullRes, c: _Cand, labs: tuple[int, int], params: DetectParams, viewpoint: FloatArray
) -> list[SeamGeometry]:
    sp = params.seams
    res_c = refine_curve(full, c.regions_a, c.regions_b, c.line, sp, viewpoint)
    if res_c is None:
        return []
    pts, n_a, n_b, r = res_c
    chord = pts[-1] - pts[0]
    length = float(np.linalg.norm(chord))
    if length < sp.min_length_m:
        return []
    rel = pts - pts[0]
    d = chord / length
    sagitta = float(np.linalg.norm(rel - np.outer(rel @ d, d), axis=1).max())
    kind: Literal["linear", "curved"] = "curved" if sagitta > sp.curved_sagitta_m else "linear"
    return [SeamGeometry(kind, "fillet", pts, n_a, n_b, (c.regions_a[0], c.regions_b[0]), labs, c.support, r)]



def _dedupe(geoms: list[SeamGeometry], *, max_dist_m: float = 0.001) -> list[SeamGeometry]:
    """Drop a seam that lies on another one (two candidates tracked onto the same junction); of two
    overlapping copies the longer is kept, extended to cover both."""
    kept: list[SeamGeometry] = []
    for g in sorted(geoms, key=lambda g: -float(np.linalg.norm(np.diff(g.points, axis=0), axis=1).sum())):
        dup = False
        for i, k in enumerate(kept):
            if g.joint != k.joint:
                continue
            from perception.evaluate import point_to_polyline_distance

            # across kinds (a straight chord found along a curved seam) allow a little more
            tol = max_dist_m if g.kind == k.kind else 1.5 * max_dist_m
            if point_to_polyline_distance(g.points, _extended(k.points, 0.02)).max() > tol:
                continue
            dup = True
            if k.kind == "linear" and g.kind == "linear":
                d = k.points[-1] - k.points[0]
                d /= np.linalg.norm(d)
                t = np.concatenate([(k.points - k.points[0]) @ d, (g.points - k.points[0]) @ d])
                own = (k.points - k.points[0]) @ d
                if t.min() < own.min() - 1e-9 or t.max() > own.max() + 1e-9:
                    # the copies overlap only partly: cover both
                    ends = np.array([k.points[0] + t.min() * d, k.points[0] + t.max() * d])
                    kept[i] = replace(
                        k, points=ends, normals_a=_two_rows(k.normals_a), normals_b=_two_rows(k.normals_b)
                    )
            break
        if not dup:
            kept.append(g)
    return kept



def _two_rows(normals: FloatArray) -> FloatArray:
    """A linear seam's normals for its two end points: the mean unit normal, twice (a linear seam traced
    as a curve carries one per traced point)."""
    n = normals.mean(axis=0)
    return np.tile(n / np.linalg.norm(n), (2, 1))



def _extended(line: FloatArray, by: float) -> FloatArray:
    if len(line) != 2:
        return line
    d = (line[1] - line[0]) / np.linalg.norm(line[1] - line[0])
    return np.array([line[0] - by * d, line[1] + by * d])
