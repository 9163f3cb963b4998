"""Coarse-to-fine multi-seam detection (after Wei et al.), as a short sequence of timed, pure steps.

    Capture -> prompts (given or automatic) -> segment -> seam ROI (bands where two masks meet)
            -> organized cloud cropped to the ROI -> pass-through -> voxel grid -> KD-tree
            -> normals + curvature -> region growing -> edge points between regions
            -> seam candidates (concave junction or narrow gap) -> fit (line | curve)
            -> refine from full-resolution points -> path points -> torch poses -> base frame

Usable on its own: ``detect(load_capture(path), DetectParams())``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from perception.butt import butt_from_surfaces
from perception.capture import Capture, PointCloud
from perception.cloud import (
    RegionParams,
    grow_regions,
    kdtree,
    merge_coplanar_regions,
    neighbourhoods,
    normals_and_curvature,
    pass_through,
    surface_spacing,
    voxel_downsample,
)
from perception.curve_refine import refine_curve
from perception.errors import NoSeamFound, PerceptionError
from perception.fits import fit_plane
from perception.organized import veil_mask
from perception.path import TorchParams, interpolate_rows, sample_uniform, torch_poses
from perception.seamfit import (
    FullRes,
    SeamGeometry,
    SeamParams,
    classify_junction_local,
    fit_edge_path,
    indices_near_polyline,
    refine_linear,
    region_edges,
)
from perception.seams import DetectionResult, Seam
from perception.segment_default import AutoPromptParams, GraphSegmenter, GraphSegmenterParams, auto_prompts, seam_roi
from perception.segmentation import Segmenter, SurfaceMasks

FloatArray = NDArray[np.float64]
logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DetectParams:
    """Everything that tunes detection. Lengths in metres, angles in degrees."""

    crop: bool = True
    roi_band_m: float = 0.010  # half-width of the seam band around where two masks meet
    z_range_m: tuple[float, float] = (0.1, 3.0)
    workspace_min_m: tuple[float, float, float] | None = None  # optional box, camera frame
    workspace_max_m: tuple[float, float, float] | None = None
    voxel_m: float = 0.003
    veil_jump_m: float = 0.003
    knn: int = 16
    normal_radius_voxels: float = 2.5
    method: Literal["surfaces", "refined", "paper"] = "refined"
    regions: RegionParams = field(default_factory=RegionParams)
    seams: SeamParams = field(default_factory=SeamParams)
    torch: TorchParams = field(default_factory=TorchParams)
    segmenter: GraphSegmenterParams = field(default_factory=GraphSegmenterParams)
    auto_prompts: AutoPromptParams = field(default_factory=AutoPromptParams)


class StepLog:
    """Records the time and point count of each step."""

    def __init__(self) -> None:
        self.timing_s: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self.voxel_planes: dict[int, tuple[FloatArray, FloatArray, float]] = {}  # per coarse label

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timing_s[name] = self.timing_s.get(name, 0.0) + time.perf_counter() - t0


@dataclass(frozen=True)
class CoarseResult:
    prompts_px: FloatArray
    prompts_source: str
    masks: SurfaceMasks
    roi_mask: NDArray[np.bool_]
    pairs: dict[tuple[int, int], int]


def coarse_stage(
    capture: Capture, points: NDArray[np.float32], params: DetectParams, segmenter: Segmenter, log: StepLog
) -> CoarseResult:
    with log.step("prompts"):
        if capture.prompts_px is not None and len(capture.prompts_px):
            prompts, source = capture.prompts_px, "prompts.json"
        else:
            prompts, source = (
                auto_prompts(points, params=params.auto_prompts, segmenter_params=params.segmenter),
                "auto",
            )
    if len(prompts) < 2:
        raise NoSeamFound(f"only {len(prompts)} workpiece surface(s) prompted ({source}); a seam needs two")
    with log.step("segment"):
        masks = segmenter.segment(capture.color_rgb, capture.depth_m, prompts, points_camera=points)
    with log.step("roi"):
        z_med = float(np.nanmedian(capture.depth_m))
        band_px = max(2, round(params.roi_band_m * capture.intrinsics.fx / max(z_med, 1e-3)))
        roi = seam_roi(masks.labels, band_px=band_px)
    return CoarseResult(prompts, source, masks, roi.mask, roi.pairs)


def _regions_to_seams(
    pts: FloatArray,
    labels: NDArray[np.int32] | None,
    params: DetectParams,
    log: StepLog,
    viewpoint: FloatArray,
    pairs: dict[tuple[int, int], int] | None = None,
    spacing_m: float = 0.0,
) -> list[SeamGeometry]:
    """The fine stage on an unorganized cloud (camera frame); ``spacing_m``: a sparse scan's sample
    spacing (0: dense)."""
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
        edges = region_edges(
            regions,
            nbh,
            min_points=sp.min_edge_points,
            link_m=2.5 * params.voxel_m,
            bridge=params.voxel_m > REFERENCE_VOXEL_M and params.method != "paper",
        )
        n_reg = int(regions.max(initial=-1)) + 1
        ok_r = regions >= 0
        region_normals = (
            np.column_stack([np.bincount(regions[ok_r], weights=normals[ok_r, k], minlength=n_reg) for k in range(3)])
            .astype(np.float64)
            .reshape(n_reg, 3)
        )
        counts_r = np.bincount(regions[ok_r], minlength=n_reg).astype(np.float64)
        resultant = np.linalg.norm(region_normals, axis=1) / np.maximum(counts_r, 1.0)
        # a region whose normals fan out (mean resultant below cos 12 deg) is a curved surface
        curved_regions = frozenset(int(r) for r in np.flatnonzero(resultant < np.cos(np.radians(12.0))))
        region_normals /= np.maximum(np.linalg.norm(region_normals, axis=1, keepdims=True), 1e-12)
        full = FullRes(pts, regions[grid.point_voxel], kdtree(pts), region_normals, normals[grid.point_voxel], lab)
        cands = []
        trees: dict[int, cKDTree] = {}

        def tree_of(r: int) -> cKDTree:
            if r not in trees:
                trees[r] = kdtree(grid.centroids[regions == r])
            return trees[r]

        for e in edges:
            center_pts = np.vstack([grid.centroids[e.points_a], grid.centroids[e.points_b]])
            joint, na, nb, rms = classify_junction_local(center_pts, tree_of(e.a), tree_of(e.b), sp, viewpoint)
            if joint != "fillet":
                continue  # convex edges are outer edges; coplanar neighbours are one surface
            cands.append((e, joint, center_pts, na, nb, rms))
    log.counts["candidates"] = len(cands)
    out: list[SeamGeometry] = []
    with log.step("fit"):
        fitted = []
        for e, _joint, center_pts, na, nb, rms in cands:
            kind, line = fit_edge_path(center_pts, sp, params.voxel_m)
            fitted.append(_Cand(kind, line, (e.a,), (e.b,), na, nb, rms, len(center_pts)))
        fitted = _group_collinear(fitted, voxel_m=params.voxel_m)
        if lab is not None and pairs and params.method != "paper":
            fitted += _mask_pair_candidates(grid.centroids, grid.labels, pairs, fitted, sp, viewpoint, params.voxel_m)
    log.counts["seam_groups"] = len(fitted)
    with log.step("refine"):
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
            if labels is not None and min(labs) < 0:
                # one side is mostly background (table, fixture): a workpiece edge standing on the
                # table is a concave junction, but not a seam of the workpiece
                continue
            curved_first = bool(curved_regions & set(c.regions_a + c.regions_b))
            out.extend(_finish(full, c, labs, params, viewpoint, curved_first=curved_first))
        out = _dedupe(out)
    return out


REFERENCE_VOXEL_M = 0.003  # the lengths in SeamParams are tuned for this voxel (the paper's)
AUTO_VOXEL_FACTOR = 1.5  # clouds: voxel >= this times the sample spacing
MAX_AUTO_VOXEL_M = 0.010


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


def _butt_seams(
    organized: NDArray[np.float32],
    band: NDArray[np.bool_],
    label_image: NDArray[np.int32],
    pairs: dict[tuple[int, int], int],
    voxel_planes: dict[int, tuple[FloatArray, FloatArray, float]],
    params: DetectParams,
    viewpoint: FloatArray,
) -> list[SeamGeometry]:
    """Butt joints come from the coarse stage: two surfaces (masks) that meet in the seam band, lie on
    one plane and are separated by a narrow gap (the voxel grid would bridge a gap this narrow).

    The cheap test runs on each mask's plane from the voxel grid; only coplanar neighbours get the
    full-resolution edge tracing, on every valid pixel of the band (no veil filter: the gap itself is a
    depth jump, and the filter would trim one plate's edge more than the other's)."""
    out: list[SeamGeometry] = []
    if params.method == "paper":
        return out  # the paper's fine stage has no butt-joint step
    from scipy import ndimage

    cos_max = np.cos(2 * params.seams.max_coplanar_rad)
    boxes: list[Any] | None = None
    for i, j in sorted(pairs):
        pi, pj = voxel_planes.get(i), voxel_planes.get(j)
        if pi is None or pj is None or abs(pi[1] @ pj[1]) < cos_max:
            continue
        if abs((pj[0] - pi[0]) @ pi[1]) > 0.004 + pi[2] + pj[2]:
            continue
        if boxes is None:
            boxes = ndimage.find_objects(label_image + 1)  # label k: object k + 1, index k
        if i >= len(boxes) or j >= len(boxes) or boxes[i] is None or boxes[j] is None:
            continue
        # the joint lies where the two masks meet: work inside their joint bounding box only
        bi, bj = boxes[i], boxes[j]
        crop = (
            slice(min(bi[0].start, bj[0].start), max(bi[0].stop, bj[0].stop)),
            slice(min(bi[1].start, bj[1].start), max(bi[1].stop, bj[1].stop)),
        )
        org_c, band_c, lab_c = organized[crop], band[crop], label_image[crop]
        pa = org_c[band_c & (lab_c == i)].astype(np.float64)
        pb = org_c[band_c & (lab_c == j)].astype(np.float64)
        scanlines = partial(_scanlines, org_c, band_c, lab_c, (i, j))
        res = butt_from_surfaces(pa, pb, scanlines, params.seams, viewpoint)
        if res is None:
            continue
        ends, n, rms, _gap = res
        nn = np.tile(n, (2, 1))
        out.append(SeamGeometry("linear", "butt", ends, nn, nn, (-1, -1), (i, j), min(len(pa), len(pb)), rms))
    return out


def _scanlines(
    organized: NDArray[np.float32], band: NDArray[np.bool_], label_image: NDArray[np.int32], pair: tuple[int, int]
) -> list[FloatArray]:
    """Valid band points of each image row (or column, whichever crosses the joint more squarely) that
    holds both surfaces of ``pair``, in pixel order."""
    m_a = band & (label_image == pair[0])
    m_b = band & (label_image == pair[1])
    ya, xa = np.nonzero(m_a)
    yb, xb = np.nonzero(m_b)
    if len(ya) == 0 or len(yb) == 0:
        return []
    # the joint runs roughly perpendicular to the line joining the two masks' centres
    dy, dx = yb.mean() - ya.mean(), xb.mean() - xa.mean()
    use_rows = abs(dx) >= abs(dy)
    grid = organized if use_rows else organized.transpose(1, 0, 2)
    sel = band if use_rows else band.T
    has_a = (m_a if use_rows else m_a.T).any(axis=1)
    has_b = (m_b if use_rows else m_b.T).any(axis=1)
    out = []
    for r in np.flatnonzero(has_a & has_b):
        row = grid[r][sel[r]]
        out.append(row[np.isfinite(row[:, 2])].astype(np.float64))
    return out


def support_plane(
    organized: NDArray[np.float32], labels: NDArray[np.int32], *, inlier_m: float = 0.003, seed: int = 0
) -> tuple[FloatArray, FloatArray] | None:
    """The table or fixture plate the workpiece stands on: the dominant plane of the background pixels
    (RANSAC on a sample), when it holds at least a third of them. (centroid, unit normal) or None."""
    # every 4th pixel each way is plenty for a plane, and 16 times cheaper to gather and sample
    pts, lab = organized[::4, ::4], labels[::4, ::4]
    bg = pts[(lab < 0) & np.isfinite(pts[..., 2])].astype(np.float64)
    if len(bg) < 100:
        return None
    rng = np.random.default_rng(seed)
    sample = bg[rng.choice(len(bg), 3000, replace=False)] if len(bg) > 3000 else bg
    best_n, best = 0, None
    for _ in range(60):
        a, b, c = sample[rng.choice(len(sample), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-9:
            continue
        n /= norm
        inl = np.abs((sample - a) @ n) < inlier_m
        if inl.sum() > best_n:
            best_n, best = int(inl.sum()), inl
    if best is None or best_n < len(sample) / 3:
        return None
    c0, n0, _ = fit_plane(sample[best])
    return c0, n0


def _on_support(g: SeamGeometry, support: tuple[FloatArray, FloatArray], *, tol_m: float = 0.004) -> bool:
    """A seam one of whose faces is the support plane (a plate edge standing on the table)."""
    c, n = support
    near = np.abs((g.points - c) @ n).max() < tol_m
    parallel = max(abs(float(g.normals_a.mean(axis=0) @ n)), abs(float(g.normals_b.mean(axis=0) @ n)))
    return bool(near and parallel > np.cos(np.radians(10.0)))


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


def _to_seams(geoms: list[SeamGeometry], params: DetectParams, frame_X: FloatArray | None) -> list[Seam]:
    """Sample paths, build torch poses, order deterministically and express in the output frame."""
    seams: list[Seam] = []
    for g in geoms:
        line = g.points
        seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
        s_src = np.concatenate([[0.0], np.cumsum(seg)])
        pts, s_new = sample_uniform(line, params.torch.step_m)
        na = interpolate_rows(s_src, g.normals_a, s_new, unit=True)
        nb = interpolate_rows(s_src, g.normals_b, s_new, unit=True)
        poses = torch_poses(pts, na, nb, params=params.torch)
        conf = float(np.clip(min(1.0, g.support / 60.0) * np.exp(-g.rms_m / 0.001), 0.0, 1.0))
        seams.append(
            Seam(
                id=0,
                kind=g.kind,
                points=pts,
                poses=poses,
                length_m=float(s_new[-1]),
                confidence=conf,
                surfaces=(min(g.labels), max(g.labels)),
                joint=g.joint,
            )
        )
    frame: Literal["camera", "base"] = "camera"
    if frame_X is not None:
        seams = [s.transformed(frame_X, "base") for s in seams]
        frame = "base"
    seams = [_orient(s, frame) for s in seams]
    seams.sort(key=lambda s: (round(float(s.points.mean(axis=0)[0]), 3), round(float(s.points.mean(axis=0)[1]), 3)))
    return [replace(s, id=i) for i, s in enumerate(seams)]


def _orient(seam: Seam, frame: str) -> Seam:
    """Deterministic travel direction: vertical seams (in the base frame) upwards, others towards +x
    (then +y) of the output frame."""
    d = seam.points[-1] - seam.points[0]
    d = d / max(np.linalg.norm(d), 1e-12)
    if frame == "base" and abs(d[2]) > 0.7:
        flip = d[2] < 0
    elif abs(d[0]) >= 0.3:
        flip = d[0] < 0
    else:
        flip = d[1] < 0
    if not flip:
        return seam
    pts = seam.points[::-1].copy()
    poses = seam.poses[::-1].copy()
    poses[:, :3, 0] *= -1  # travel direction reverses: x -> -x, y -> -y keeps z and a right-handed frame
    poses[:, :3, 1] *= -1
    return replace(seam, points=pts, poses=poses)


def detect(
    capture: Capture, params: DetectParams | None = None, *, segmenter: Segmenter | None = None
) -> DetectionResult:
    """Detect every seam in ``capture``. Raises NoSeamFound (with the step that emptied it)."""
    p = params or DetectParams()
    if p.method == "surfaces":
        from perception.detect_surfaces import detect_surfaces

        return detect_surfaces(capture, p, segmenter=segmenter)
    seg = segmenter or GraphSegmenter(p.segmenter)
    log = StepLog()
    t0 = time.perf_counter()
    with log.step("backproject"):
        organized = capture.points_camera()
    valid = np.isfinite(organized[..., 2])
    log.counts["raw"] = int(valid.sum())
    coarse = coarse_stage(capture, organized, p, seg, log)
    t_coarse = time.perf_counter() - t0
    with log.step("veil"):
        # flying ("veil") pixels at occlusion edges hang between foreground and background; they would
        # join surfaces that do not touch. Concave seams have no depth jump, so they lose nothing.
        f = 2 if organized.shape[1] >= 960 else 1  # half resolution is plenty to find depth jumps
        small = veil_mask(np.ascontiguousarray(organized[::f, ::f]), jump_m=p.veil_jump_m, dilate_px=1)
        H, W = valid.shape
        veil = np.repeat(np.repeat(small, f, axis=0), f, axis=1)[:H, :W] & valid
    log.counts["veil"] = int(veil.sum())
    with log.step("crop"):
        keep = valid & ~veil
        if p.crop:
            keep &= coarse.roi_mask
        pts = organized[keep].astype(np.float64)
        labels = coarse.masks.labels[keep]
    log.counts["cropped"] = len(pts)
    t1 = time.perf_counter()
    geoms = _regions_to_seams(pts, labels, p, log, viewpoint=np.zeros(3), pairs=coarse.pairs)
    with log.step("butt"):
        band = valid & (coarse.roi_mask if p.crop else True)
        geoms += _butt_seams(
            organized, band, coarse.masks.labels, coarse.pairs, log.voxel_planes, p, viewpoint=np.zeros(3)
        )
    with log.step("support"):
        table = support_plane(organized, coarse.masks.labels)
        if table is not None:
            geoms = [g for g in geoms if not _on_support(g, table)]
    t_fine = time.perf_counter() - t1
    if not geoms:
        raise NoSeamFound(
            f"{log.counts.get('candidates', 0)} junction(s) between surfaces were examined but none is a concave "
            "seam or a narrow gap",
            artifacts={"masks": coarse.masks, "roi": coarse.roi_mask},
        )
    t2 = time.perf_counter()
    seams = _to_seams(geoms, p, capture.X_base_camera)
    t_path = time.perf_counter() - t2
    total = time.perf_counter() - t0
    timing = {"coarse": t_coarse, "fine": t_fine, "path": t_path, "total": total}
    timing.update({f"step_{k}": v for k, v in log.timing_s.items()})
    info: dict[str, Any] = {
        "prompts": coarse.prompts_px.round(1).tolist(),
        "prompts_source": coarse.prompts_source,
        "segmenter": getattr(seg, "name", type(seg).__name__),
        "method": p.method,
        "voxel_m": p.voxel_m,
        "crop": p.crop,
        "removed_share": round(1.0 - log.counts["cropped"] / max(log.counts["raw"], 1), 4),
        "counts": dict(log.counts),
    }
    counts = {
        "raw": log.counts["raw"],
        "cropped": log.counts["cropped"],
        "downsampled": log.counts.get("downsampled", 0),
    }
    return DetectionResult(
        frame="base" if capture.X_base_camera is not None else "camera",
        seams=tuple(seams),
        point_counts=counts,
        timing_s=timing,
        info=info,
        artifacts={"masks": coarse.masks, "roi": coarse.roi_mask},
    )


def detect_cloud(cloud: PointCloud, params: DetectParams | None = None, *, auto_voxel: bool = True) -> DetectionResult:
    """Fine stage only, on an unorganized cloud (PLY/PCD): no segmentation, no crop. With ``auto_voxel``
    a sparse cloud (a LiDAR scan) gets a voxel of 1.5 times its sample spacing when that is coarser than
    ``params.voxel_m``, so that every voxel holds a point or two."""
    p = params or DetectParams()
    if len(cloud.points) < 50:
        raise PerceptionError(f"{cloud.source}: only {len(cloud.points)} points")
    spacing = surface_spacing(cloud.points)
    if auto_voxel and AUTO_VOXEL_FACTOR * spacing > p.voxel_m:
        p = replace(p, voxel_m=min(AUTO_VOXEL_FACTOR * spacing, MAX_AUTO_VOXEL_M))
    log = StepLog()
    t0 = time.perf_counter()
    log.counts["raw"] = len(cloud.points)
    log.counts["cropped"] = len(cloud.points)
    # the viewpoint: clouds in a robot or world frame are not seen from their origin; use a point
    # above the cloud's centroid along the axis of least spread, on the side of most normals
    viewpoint = _guess_viewpoint(cloud.points, cloud.normals)
    if p.method == "surfaces":
        return _detect_cloud_surfaces(cloud, p, spacing)
    if p.z_range_m == DetectParams().z_range_m:
        # the default working range is for camera-frame depth; a cloud may be in a robot frame
        p = replace(p, z_range_m=(-np.inf, np.inf))
    geoms = _regions_to_seams(cloud.points, None, p, log, viewpoint=viewpoint, spacing_m=spacing)
    if not geoms:
        raise NoSeamFound(f"{log.counts.get('candidates', 0)} junction(s) examined, none is a concave seam")
    seams = _to_seams(geoms, p, None)
    total = time.perf_counter() - t0
    timing = {"coarse": 0.0, "fine": total, "total": total} | {f"step_{k}": v for k, v in log.timing_s.items()}
    return DetectionResult(
        frame="camera",
        seams=tuple(seams),
        point_counts={
            "raw": log.counts["raw"],
            "cropped": log.counts["cropped"],
            "downsampled": log.counts.get("downsampled", 0),
        },
        timing_s=timing,
        info={
            "method": p.method,
            "voxel_m": p.voxel_m,
            "spacing_m": round(spacing, 5),
            "viewpoint": viewpoint.round(4).tolist(),
            "counts": dict(log.counts),
        },
    )


def _detect_cloud_surfaces(cloud: PointCloud, p: DetectParams, spacing: float) -> DetectionResult:
    """The surfaces-first stage on the cloud's range image seen from its sensor's side
    (:func:`perception.cloud_view.sensor_side`); seams in the cloud's frame."""
    from perception.cloud_view import sensor_side, view_cloud
    from perception.detect_surfaces import detect_surfaces

    viewpoint = sensor_side(cloud.points, cloud.normals)
    view = view_cloud(cloud.points, viewpoint)
    h, w = view.organized.shape[:2]
    cap = Capture(np.zeros((h, w, 3), np.uint8), view.organized[..., 2].copy(), view.intrinsics,
                  X_base_tool=view.X_cloud_camera, X_tool_camera=np.eye(4), source=cloud.source)  # fmt: skip
    p = replace(p, z_range_m=(0.0, np.inf), workspace_min_m=None, workspace_max_m=None)
    res = detect_surfaces(cap, p, organized=view.organized)
    info = res.info | {"spacing_m": round(spacing, 5), "viewpoint": viewpoint.round(4).tolist(),
                       "view_px": [w, h]}  # fmt: skip
    return replace(res, frame="camera", info=info)


def _guess_viewpoint(points: FloatArray, normals: FloatArray | None = None) -> FloatArray:
    c = points.mean(axis=0)
    extent = max(float(np.ptp(points, axis=0).max()), 0.3)
    if normals is not None:
        # the file's normals face the sensor that saw the surfaces: their mean points towards it
        mean = normals.mean(axis=0)
        if np.linalg.norm(mean) > 0.2:
            return np.asarray(c + mean / np.linalg.norm(mean) * extent)
    if np.linalg.norm(c) > 0.05 and c[2] > 0.05 and np.all(np.abs(c[:2]) < 0.6 * c[2]):
        # looks like a camera-frame cloud (in front of the origin): the camera is the viewpoint
        return np.zeros(3)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    up = vt[2]
    if up[2] < 0:
        up = -up  # robot/world frames: z up, the sensor looks down
    return np.asarray(c + up * extent)


# --------------------------------------------------------------------------------------------------
# The fine stage rebuilt on fitted surfaces (perception/fine/): the steps, in order
