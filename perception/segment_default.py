"""The default segmenter: needs no weights.

Method (seeded graph segmentation on geometry, finished by a watershed):
1. Work at about ``work_width_px`` wide (every f-th pixel of the organized cloud).
2. Edges = depth jumps, invalid depth, and folds where the surface normal turns by more than
   ``max_normal_turn_rad`` across a few pixels.
3. Connected components of the non-edge pixels are surface patches. Each prompt marks the patch it
   lands on; two prompts on one patch mark only a small disc each, so the watershed splits the patch.
   Large patches without a prompt are marked as background (table, fixtures, unprompted faces).
4. ``cv2.watershed`` floods the edge bands from the markers over an image of the normals (plus grey
   level), so neighbouring surfaces meet where the normal flips: at the fold, i.e. at the seam.

It also finds prompts automatically (:func:`auto_prompts`): one per surface patch that is large enough
and does not lie on the support plane (the table the workpiece stands on).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from perception.errors import PerceptionError
from perception.organized import depth_edges, normal_edges, organized_normals
from perception.segmentation import SurfaceMasks

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class GraphSegmenterParams:
    work_width_px: int = 640
    normal_window_px: int = 5
    normal_step_px: int = 2
    max_normal_turn_rad: float = math.radians(25.0)
    depth_jump_m: float = 0.002
    depth_footprint_factor: float = 3.0
    color_edge_threshold: float = 14.0  # gradient of the blurred luminance (0-255) that separates surfaces; 0 = off
    background_min_fraction: float = 0.002
    prompt_search_px: int = 6


def _factor(width: int, work_width_px: int) -> int:
    """Pixel step so that the work image is at least ``work_width_px`` wide (960 px -> step 1, not 2)."""
    return max(1, width // work_width_px)


@dataclass(frozen=True)
class Patches:
    """Work-resolution analysis shared by segmentation and automatic prompts."""

    factor: int
    points: NDArray[np.float32]  # (h, w, 3)
    normals: NDArray[np.float32]  # (h, w, 3)
    edges: NDArray[np.bool_]  # (h, w)
    components: NDArray[np.int32]  # (h, w), 0 = edge
    n_components: int


def color_edges(color_rgb: NDArray[np.uint8], f: int, threshold: float) -> NDArray[np.bool_]:
    """Strong luminance steps (blurred, so texture and sensor noise do not count), at work resolution."""
    import cv2

    gray = cv2.cvtColor(np.ascontiguousarray(color_rgb[::f, ::f]), cv2.COLOR_RGB2GRAY).astype(np.float32)
    gray = np.asarray(cv2.GaussianBlur(gray, (5, 5), 1.2), dtype=np.float32)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3) / 4.0
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3) / 4.0
    return np.asarray(np.hypot(gx, gy) > threshold)


def surface_patches(
    points_camera: NDArray[np.float32], params: GraphSegmenterParams, color_rgb: NDArray[np.uint8] | None = None
) -> Patches:
    import cv2

    f = _factor(points_camera.shape[1], params.work_width_px)
    pts = np.ascontiguousarray(points_camera[::f, ::f])
    normals = organized_normals(pts, window_px=params.normal_window_px, step_px=params.normal_step_px)
    edges = normal_edges(normals, max_angle_rad=params.max_normal_turn_rad, step_px=params.normal_step_px)
    edges |= depth_edges(pts, jump_m=params.depth_jump_m, footprint_factor=params.depth_footprint_factor)
    if color_rgb is not None and params.color_edge_threshold > 0:
        edges |= color_edges(color_rgb, f, params.color_edge_threshold)
    edges |= ~np.isfinite(normals[..., 0])
    n, comp = cv2.connectedComponents((~edges).astype(np.uint8), connectivity=4)
    return Patches(f, pts, normals, edges, comp.astype(np.int32), int(n))


def _component_at(comp: NDArray[np.int32], u: float, v: float, search: int) -> int:
    h, w = comp.shape
    ui, vi = min(max(round(u), 0), w - 1), min(max(round(v), 0), h - 1)
    if comp[vi, ui] > 0:
        return int(comp[vi, ui])
    v0, v1 = max(vi - search, 0), min(vi + search + 1, h)
    u0, u1 = max(ui - search, 0), min(ui + search + 1, w)
    win = comp[v0:v1, u0:u1]
    ys, xs = np.nonzero(win > 0)
    if len(ys) == 0:
        return 0
    d2 = (ys + v0 - vi) ** 2 + (xs + u0 - ui) ** 2
    j = int(np.argmin(d2))
    return int(win[ys[j], xs[j]])


class GraphSegmenter:
    """Default segmenter (no weights). See the module docstring for the method."""

    name = "default"

    def __init__(self, params: GraphSegmenterParams | None = None) -> None:
        self.params = params or GraphSegmenterParams()

    def segment(
        self,
        color_rgb: NDArray[np.uint8],
        depth_m: NDArray[np.float32],
        prompts_px: FloatArray,
        *,
        points_camera: NDArray[np.float32] | None = None,
    ) -> SurfaceMasks:
        import cv2

        if points_camera is None:
            raise PerceptionError("the default segmenter needs the organized cloud (points_camera)")
        H, W = depth_m.shape
        prompts = np.asarray(prompts_px, dtype=np.float64).reshape(-1, 2)
        K = len(prompts)
        patches = surface_patches(points_camera, self.params, color_rgb)
        f = patches.factor
        comp = patches.components
        h, w = comp.shape
        by_comp: dict[int, list[int]] = {}
        scores = [0.0] * K
        for k, (u, v) in enumerate(prompts):
            c = _component_at(comp, u / f, v / f, self.params.prompt_search_px)
            if c > 0:
                by_comp.setdefault(c, []).append(k)
                scores[k] = 1.0
        areas = np.bincount(comp.ravel(), minlength=patches.n_components)
        bg_min = self.params.background_min_fraction * h * w
        background = K + 1
        # marker of each patch: its prompt's, background for large unprompted patches, else none (0)
        lut = np.where(areas >= bg_min, background, 0).astype(np.int32)
        lut[0] = 0
        for c, ks in by_comp.items():
            lut[c] = ks[0] + 1 if len(ks) == 1 else 0
        markers = lut[comp]
        for ks in by_comp.values():
            if len(ks) > 1:
                for k in ks:
                    u, v = prompts[k] / f
                    cv2.circle(markers, (round(u), round(v)), 2, k + 1, -1)
                    scores[k] = 0.8  # shared patch: split by the watershed alone
        n = np.nan_to_num(patches.normals)
        gray = cv2.cvtColor(np.ascontiguousarray(color_rgb[::f, ::f]), cv2.COLOR_RGB2GRAY)
        img = np.dstack([n[..., 0] * 110 + 128, n[..., 1] * 110 + 128, gray * 0.35 + n[..., 2] * 40 + 60])
        img = np.clip(img, 0, 255).astype(np.uint8)
        cv2.watershed(img, markers)
        small = markers - 1
        small[(markers <= 0) | (markers == background)] = -1
        labels = np.repeat(np.repeat(small, f, axis=0), f, axis=1)[:H, :W]
        return SurfaceMasks(labels=np.ascontiguousarray(labels), prompts_px=prompts, scores=tuple(scores))


# --------------------------------------------------------------------------------------------------
# Automatic prompts


@dataclass(frozen=True)
class AutoPromptParams:
    min_area_fraction: float = 0.0015
    support_plane_tol_m: float = 0.004
    max_prompts: int = 40


def _plane_fit(p: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    c = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - c, full_matrices=False)
    return c, vt[2], float(s[2] / np.sqrt(len(p)))


def auto_prompts(
    points_camera: NDArray[np.float32],
    *,
    params: AutoPromptParams | None = None,
    segmenter_params: GraphSegmenterParams | None = None,
    color_rgb: NDArray[np.uint8] | None = None,
) -> FloatArray:
    """(K, 2) pixel prompts, one per workpiece surface patch, found without a human.

    The support plane is the plane of the largest patch touching the image border; patches on it
    (and anything behind it) are not workpiece surfaces. Each remaining patch of at least
    ``min_area_fraction`` of the image gets a prompt at its most interior pixel.
    """
    import cv2

    ap = params or AutoPromptParams()
    patches = surface_patches(points_camera, segmenter_params or GraphSegmenterParams(), color_rgb)
    comp, f = patches.components, patches.factor
    h, w = comp.shape
    areas = np.bincount(comp.ravel(), minlength=patches.n_components)
    areas[0] = 0
    border = np.zeros(patches.n_components, bool)
    m = 8  # normals are undefined right at the image border, so "touching" means within a few pixels
    for edge in (comp[:m], comp[-m:], comp[:, :m], comp[:, -m:]):
        border[np.unique(edge)] = True
    border[0] = False
    rng = np.random.default_rng(0)
    support: tuple[FloatArray, FloatArray] | None = None
    if border.any():
        # the support (table) is the farthest large plane that reaches the image border
        border_areas = np.where(border, areas, 0)
        best = -1.0
        for cid in np.flatnonzero(border_areas >= 0.25 * border_areas.max()):
            pts = patches.points[comp == cid].astype(np.float64)
            pts = pts[np.isfinite(pts).all(axis=1)]
            if len(pts) > 4000:
                pts = pts[rng.choice(len(pts), 4000, replace=False)]
            if len(pts) < 10:
                continue
            c, n, _ = _plane_fit(pts)
            if n @ c > 0:
                n = -n  # normal towards the camera
            if -(n @ c) > best:
                best = float(-(n @ c))
                support = (c, n)
    min_area = ap.min_area_fraction * h * w
    big = np.flatnonzero(areas >= min_area)
    if support is not None:
        # a table is only a table if something stands on it: when no large patch rises in front of
        # the plane, the workpiece fills the view and that plane is one of its surfaces
        c, n = support
        in_front = False
        for cid in big:
            pts = patches.points[comp == cid].astype(np.float64)
            pts = pts[np.isfinite(pts).all(axis=1)]
            if len(pts) and np.median((pts - c) @ n) >= ap.support_plane_tol_m:
                in_front = True
                break
        if not in_front:
            support = None
    out: list[tuple[float, float, float]] = []
    for cid in big:
        mask = comp == cid
        pts = patches.points[mask].astype(np.float64)
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts) < 10:
            continue
        if support is not None:
            c, n = support
            height = (pts - c) @ n  # > 0: in front of the support plane (towards the camera)
            if np.median(height) < ap.support_plane_tol_m:
                continue
        dist = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
        v, u = np.unravel_index(int(np.argmax(dist)), dist.shape)
        out.append((float(areas[cid]), float(u * f), float(v * f)))
    out.sort(key=lambda t: -t[0])
    prompts = np.array([(u, v) for _, u, v in out[: ap.max_prompts]], dtype=np.float64).reshape(-1, 2)
    # deterministic order: top to bottom, then left to right
    order = np.lexsort((prompts[:, 0], prompts[:, 1]))
    return prompts[order]


# --------------------------------------------------------------------------------------------------
# Seam region of interest


@dataclass(frozen=True)
class SeamROI:
    """mask: (H, W) bool, pixels within ``band_px`` of two different surfaces.
    pairs: surface pairs (i < j) that meet, with the number of band pixels they share (work resolution)."""

    mask: NDArray[np.bool_]
    pairs: dict[tuple[int, int], int]
    band_px: int


def seam_roi(labels: NDArray[np.int32], *, band_px: int, work_factor: int = 2, min_pair_px: int = 20) -> SeamROI:
    """The bands where two surface masks meet (computed at 1/``work_factor`` resolution)."""
    import cv2
    from scipy import ndimage

    H, W = labels.shape
    f = max(1, work_factor)
    small = np.ascontiguousarray(labels[::f, ::f])
    r = max(1, round(band_px / f))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    h, w = small.shape
    count = np.zeros((h, w), np.uint8)
    # each mask is dilated inside its own padded bounding box (find_objects: one pass for all labels)
    dil: dict[int, tuple[tuple[int, int, int, int], NDArray[np.bool_]]] = {}
    for k, sl in enumerate(ndimage.find_objects(small + 1)):  # label k is object k + 1 (-1 is background)
        if sl is None:
            continue
        y0, y1 = max(sl[0].start - r - 1, 0), min(sl[0].stop + r + 1, h)
        x0, x1 = max(sl[1].start - r - 1, 0), min(sl[1].stop + r + 1, w)
        m = (small[y0:y1, x0:x1] == k).astype(np.uint8)
        d = cv2.dilate(m, kernel).astype(bool)
        dil[k] = ((y0, y1, x0, x1), d)
        count[y0:y1, x0:x1] += d
    pairs: dict[tuple[int, int], int] = {}
    keys = sorted(dil)
    for a_i, a in enumerate(keys):
        (ya0, ya1, xa0, xa1), da = dil[a]
        for b in keys[a_i + 1 :]:
            (yb0, yb1, xb0, xb1), db = dil[b]
            y0, y1, x0, x1 = max(ya0, yb0), min(ya1, yb1), max(xa0, xb0), min(xa1, xb1)
            if y0 >= y1 or x0 >= x1:
                continue
            both = da[y0 - ya0 : y1 - ya0, x0 - xa0 : x1 - xa0] & db[y0 - yb0 : y1 - yb0, x0 - xb0 : x1 - xb0]
            n = int(both.sum())
            if n >= min_pair_px:
                pairs[(a, b)] = n
    band_small = count >= 2
    mask = np.repeat(np.repeat(band_small, f, axis=0), f, axis=1)[:H, :W]
    return SeamROI(mask=np.ascontiguousarray(mask), pairs=pairs, band_px=band_px)
