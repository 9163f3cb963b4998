"""Butt gaps: two coplanar surfaces whose facing boundaries run parallel across a narrow strip with nothing on
their plane in it. The seam is the gap's centre line on the plates' top surface, with its width.

A gap too narrow to split its plates at the work resolution is a line of holes inside one plane at full
resolution: pixels with no depth or depth behind the plane, or, in the colour image, on a thin line of
shadow (a gap narrower than the depth sensor resolves still shows as one)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numba import njit
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.fine.folds import contact_points, rays_onto
from perception.fine.gap_profile import gap_edges
from perception.fine.lines import best_line, best_trial
from perception.fine.runs import covered_runs
from perception.fine.types import FloatArray, NoiseModel, Pair, SeamCurve, Surface, SurfaceSet
from perception.fits import cross3, median, percentile
from perception.organized import points_at


@dataclass(frozen=True)
class GapParams:
    max_angle_rad: float = np.radians(4.0)
    max_step_m: float = 0.002  # the two plates' planes may be offset by this much
    max_gap_m: float = 0.006
    min_gap_m: float = 0.0002
    min_length_m: float = 0.015
    bin_m: float = 0.002
    far_m: float = 0.008  # each plate reaches this far beyond its edge (as :class:`InnerGapParams`)
    min_far_share: float = 0.6  # ... along this share of the seam


def gap_seams(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    pairs: tuple[Pair, ...],
    noise: NoiseModel,
    *,
    support: frozenset[int],
    params: GapParams | None = None,
) -> list[SeamCurve]:
    from scipy.spatial import cKDTree

    gp = params or GapParams()
    p = np.asarray(points, dtype=np.float64)
    lab = surfaces.labels
    out: list[SeamCurve] = []
    for pair in pairs:
        if pair.a in support or pair.b in support:
            continue
        A, B = surfaces.surfaces[pair.a], surfaces.surfaces[pair.b]
        if A.kind != "plane" or B.kind != "plane" or float(A.normal @ B.normal) < np.cos(gp.max_angle_rad):
            continue
        ys, xs = pair.contact_px[:, 0], pair.contact_px[:, 1]
        pa, pb = contact_points(p, lab, pair)
        if len(pa) < 10 or len(pb) < 10:
            continue
        if abs(float(median(A.residual(pb)))) > gp.max_step_m:
            continue
        # facing boundaries: each side's points within the widest gap of the other side
        da, _ = cKDTree(pb).query(pa)
        db, _ = cKDTree(pa).query(pb)
        reach = gp.max_gap_m + 3.0 * float(noise.spacing_m(A.z_m))
        ea, eb = pa[da <= reach], pb[db <= reach]
        if len(ea) < 8 or len(eb) < 8:
            continue
        both = np.vstack([ea, eb])
        c = both.mean(axis=0)
        n = A.normal + B.normal
        n /= np.linalg.norm(n)
        _, v = np.linalg.eigh(np.cov((both - c).T))
        u = v[:, 2] - (v[:, 2] @ n) * n
        u /= np.linalg.norm(u)
        across = cross3(n, u)
        if float((eb.mean(axis=0) - ea.mean(axis=0)) @ across) < 0:
            across = -across
        edge_a = float(percentile((ea - c) @ across, 90))
        edge_b = float(percentile((eb - c) @ across, 10))
        width = edge_b - edge_a
        if not (gp.min_gap_m <= width <= gp.max_gap_m):
            continue
        # nothing on the plane inside the strip (else it is one plate split by the segmentation), and nothing
        # stands in it (a wall between two stretches of one floor, its top seen in the strip)
        strip = p[ys, xs]
        strip = strip[np.isfinite(strip[:, 2])]
        off = (strip - c) @ across
        inside = strip[(off > edge_a + 0.25 * width) & (off < edge_b - 0.25 * width)]
        sig, top = float(noise.sigma_m(A.z_m)), 0.5 * (A.offset + B.offset)
        if (len(inside) and np.mean(np.abs(inside @ n + top) <= 3.0 * sig) > 0.3) or _stands_in(inside, n, top, sig):
            continue
        mid = 0.5 * (edge_a + edge_b)
        ta, tb = (ea - c) @ u, (eb - c) @ u
        lo, hi = max(ta.min(), tb.min()), min(ta.max(), tb.max())
        if hi - lo < gp.min_length_m:
            continue
        nbins = int(np.ceil((hi - lo) / gp.bin_m))
        ca = np.bincount(np.clip(((ta - lo) / gp.bin_m).astype(int), 0, nbins - 1), minlength=nbins)
        cb = np.bincount(np.clip(((tb - lo) / gp.bin_m).astype(int), 0, nbins - 1), minlength=nbins)
        for s0, s1 in covered_runs((ca > 0) & (cb > 0), 4):
            # the ends where both plates' facing points still are (the bins round them out by up to one)
            t0, t1 = _shared_span(ta, tb, lo + s0 * gp.bin_m, lo + s1 * gp.bin_m)
            if t1 - t0 < gp.min_length_m or not _plates_reach(p, lab, (pair.a, pair.b), c, u, across,
                                                              (edge_a, edge_b), (t0, t1), gp):  # fmt: skip
                continue
            base = c + mid * across
            # the top surface: the plates' mean plane through the centre line
            base = base - (base @ n + 0.5 * (A.offset + B.offset)) * n
            pts = np.array([base + t0 * u, base + t1 * u])
            out.append(SeamCurve("linear", "butt", pts, np.tile(A.normal, (2, 1)), np.tile(B.normal, (2, 1)),
                                 (A.label, B.label), int(ca[s0:s1].sum() + cb[s0:s1].sum()), max(A.rms_m, B.rms_m),
                                 gap_m=width))  # fmt: skip
    return out


def _plates_reach(p: FloatArray, lab: NDArray[np.int32], labels: tuple[int, int], c: FloatArray, u: FloatArray,
                  across: FloatArray, edges: tuple[float, float], span: tuple[float, float],
                  gp: GapParams) -> bool:  # fmt: skip
    """Whether each of the two surfaces ``labels`` reaches ``far_m`` beyond its edge (``edges``: A's and B's,
    across from A to B), in ``min_far_share`` of the 2 mm bins of ``span`` along the gap. A butt joint parts
    two plates; a sliver of valid pixels inside a blob of specular holes, on the plate's own plane, is no
    plate (zoo dev v_groove 170: a 16 mm "gap" between a plate and a 51-point sliver)."""
    t0, t1 = span
    nbins = max(1, int(np.ceil((t1 - t0) / gp.bin_m)))
    for label, sign, edge in ((labels[0], -1.0, edges[0]), (labels[1], 1.0, edges[1])):
        q = p[lab == label]
        d = q - c
        t, off = d @ u, sign * (d @ across - edge)
        far = (t >= t0) & (t <= t1) & (off >= gp.far_m)
        hit = np.bincount(np.clip(((t[far] - t0) / gp.bin_m).astype(int), 0, nbins - 1), minlength=nbins) > 0
        if float(hit.mean()) < gp.min_far_share:
            return False
    return True


def over_groove(butt: SeamCurve, grooves: list[SeamCurve], *, margin_m: float = 0.003) -> bool:
    """Whether ``butt`` is a V-groove's opening: seen along its plates' normal, its centre line lies on one of
    ``grooves``' (within half its width plus ``margin_m`` across, and along it, over most of its length).
    Between the two plates' tops a groove's bevels leave a strip like a gap's, but the seam is the root."""
    n = butt.normals_a[0] / np.linalg.norm(butt.normals_a[0])

    def flat(q: FloatArray) -> FloatArray:
        return q - np.outer(q @ n, n)

    probe = flat(butt.points[0] + np.linspace(0.0, 1.0, 11)[:, None] * (butt.points[-1] - butt.points[0]))
    for g in grooves:
        g0, g1 = flat(g.points[[0, -1]])
        length = float(np.linalg.norm(g1 - g0))
        if length < 1e-6:
            continue
        u = (g1 - g0) / length
        d = probe - g0
        t = d @ u
        lateral = np.linalg.norm(d - np.outer(t, u), axis=1)
        on = (lateral <= 0.5 * butt.gap_m + margin_m) & (t >= -margin_m) & (t <= length + margin_m)
        if on.mean() >= 0.8:
            return True
    return False


def _stands_in(strip: FloatArray, normal: FloatArray, offset: float, sigma_m: float) -> bool:
    """Whether something stands in a gap's strip: more than 5% of its points lie in front of the plates'
    plane (``normal`` towards the camera) by over four sigma and a millimetre. A gap is empty: through it the
    camera sees the plates' edge faces or what lies behind them, never something nearer than their top."""
    if len(strip) == 0:
        return False
    return float(np.mean(strip @ normal + offset > 4.0 * sigma_m + 0.001)) > 0.05


def _shared_span(ta: FloatArray, tb: FloatArray, t0: float, t1: float) -> tuple[float, float]:
    """[t0, t1] narrowed to where both sides' positions ``ta`` and ``tb`` (along a gap) within it reach;
    unchanged when either side has none there."""
    in_a, in_b = ta[(ta >= t0) & (ta <= t1)], tb[(tb >= t0) & (tb <= t1)]
    if not (len(in_a) and len(in_b)):
        return t0, t1
    return max(t0, float(in_a.min()), float(in_b.min())), min(t1, float(in_a.max()), float(in_b.max()))


SIDE_BAND_M = 0.003  # the bands beside a gap its plates' density and holes are counted in
PROFILE_HALF_M = 0.005  # the rays within this of a gap's first centre are fitted with its profile


@dataclass(frozen=True)
class InnerGapParams:
    behind_m: float = 0.0  # a pixel this far behind the plate's plane (plus noise) sees through the gap
    close_px: int = 9  # closing that bridges the gap when filling the plate's outline (full resolution)
    min_length_m: float = 0.020
    max_width_rms_m: float = 0.0015
    side_m: float = 0.004  # plate points this close to the gap line give its edges
    min_side_share: float = 0.6
    far_m: float = 0.008  # ... and this far out on both sides


def inner_gap_seams(
    full: NDArray[np.float32],
    intr: CameraIntrinsics,
    surfaces: SurfaceSet,
    noise_full: NoiseModel,
    *,
    support: frozenset[int],
    params: InnerGapParams | None = None,
    color_rgb: NDArray[np.uint8] | None = None,
    pairs: tuple[Pair, ...] = (),
    found: Sequence[SeamCurve] = (),
) -> list[SeamCurve]:
    """Butt gaps too narrow to split a plate at the work resolution: inside one plane's outline, at full
    resolution, a long thin line of pixels with no depth or depth behind the plane, with the plane on both
    sides of it all along. With the (H, W, 3) ``color_rgb`` registered to the depth, a pixel on a dark line
    (:func:`dark_line`) counts as seeing into the gap too: a gap narrower than the depth sensor resolves is
    still a line of shadow in the image.

    Two plates segmented apart across a gap narrower than a work-resolution sample (adjacent ``pairs`` of
    planes, one plane within :class:`GapParams`' angle and step, with no butt seam between them among
    ``found``) are looked in as one outline: the work-resolution test of :func:`gap_seams` cannot tell a gap
    it does not sample from a seam of the segmentation; the full resolution can. Only a gap with one plate on
    each side counts there."""
    gp = params or InnerGapParams()
    dark: list[NDArray[np.int16]] = []  # the image's dark-line response, computed once when first needed
    out: list[SeamCurve] = []
    for outline in gap_outlines(surfaces, noise_full, support=support, params=gp, pairs=pairs, found=found):
        out += outline_gap_seams(full, intr, surfaces, noise_full, outline, params=gp, color_rgb=color_rgb, dark=dark)
    return out


@dataclass(frozen=True)
class Outline:
    """A closed outline :func:`inner_gap_seams` looks in: plane ``plane``'s pixels of the surfaces ``labels``
    (their work-resolution box ``box``, rows and columns); ``parting``, for two plates of one plane, the pair
    a gap there must run between."""

    plane: Surface
    labels: tuple[int, ...]
    box: tuple[slice, ...]
    parting: tuple[int, int] | None = None


def gap_outlines(surfaces: SurfaceSet, noise_full: NoiseModel, *, support: frozenset[int],
                 params: InnerGapParams | None = None, pairs: tuple[Pair, ...] = (),
                 found: Sequence[SeamCurve] = ()) -> list[Outline]:  # fmt: skip
    """The outlines :func:`inner_gap_seams` looks in, each its own search (:func:`outline_gap_seams`): every
    plane's off ``support``, then each pair of coplanar plates with no butt seam between them among ``found``."""
    from scipy import ndimage

    gp = params or InnerGapParams()
    boxes = ndimage.find_objects(surfaces.labels + 1)  # each label's box at the work resolution, found once
    out = [Outline(s, (s.label,), boxes[s.label]) for s in surfaces.surfaces
           if s.kind == "plane" and s.label not in support and s.label < len(boxes) and boxes[s.label] is not None]
    for a, b in _coplanar_pairs(surfaces, pairs, support, found, noise_full, gp):
        box = tuple(slice(min(x.start, y.start), max(x.stop, y.stop)) for x, y in zip(boxes[a], boxes[b], strict=True))
        big = max(surfaces.surfaces[a], surfaces.surfaces[b], key=lambda x: x.n_points)
        out.append(Outline(big, (a, b), box, parting=(a, b)))
    return out


def outline_gap_seams(full: NDArray[np.float32], intr: CameraIntrinsics, surfaces: SurfaceSet,
                      noise_full: NoiseModel, outline: Outline, *, params: InnerGapParams | None = None,
                      color_rgb: NDArray[np.uint8] | None = None,
                      dark: list[NDArray[np.int16]] | None = None) -> list[SeamCurve]:  # fmt: skip
    """The inner gaps of one :class:`Outline` (:func:`inner_gap_seams`). ``dark``: where the colour image's
    dark-line response is kept once computed (appended to on first use), for the outlines of one capture."""
    gp = params or InnerGapParams()
    seams = _outline_gaps(full, intr, surfaces, noise_full, outline.plane, outline.labels, outline.box, gp,
                          color_rgb, [] if dark is None else dark)  # fmt: skip
    if outline.parting is None:
        return seams
    a, b = outline.parting
    return [replace(seam, surfaces=(a, b)) for seam in seams if _parts(seam, surfaces, a, b, intr)]


def _coplanar_pairs(surfaces: SurfaceSet, pairs: tuple[Pair, ...], support: frozenset[int],
                    found: Sequence[SeamCurve], noise_full: NoiseModel,
                    ip: InnerGapParams) -> list[tuple[int, int]]:  # fmt: skip
    """The adjacent planes (neither in ``support``) that are one plane within :class:`GapParams`' angle and
    step, with no butt seam between them among ``found``, each large enough to flank a gap: a plate beside
    a gap reaches ``far_m`` beyond its edge along ``min_side_share`` of the shortest gap at least
    (:func:`_gap_between`), so its area is at least that rectangle's (the speckle of a face seen at a grazing
    angle, dozens of small pieces of its plane, is not; each of them paired with the face made the face's
    whole outline be searched again, 40 s on one capture)."""
    gp = GapParams()
    parted = {frozenset(c.surfaces) for c in found if c.joint == "butt"}
    flank_m2 = ip.min_side_share * ip.min_length_m * ip.far_m
    out = []
    for pr in pairs:
        A, B = surfaces.surfaces[pr.a], surfaces.surfaces[pr.b]
        if pr.a in support or pr.b in support or A.kind != "plane" or B.kind != "plane":
            continue
        if min(_area_m2(S, noise_full, surfaces.factor) for S in (A, B)) < flank_m2:
            continue
        if float(A.normal @ B.normal) < np.cos(gp.max_angle_rad) or frozenset((pr.a, pr.b)) in parted:
            continue
        big, small = (A, B) if A.n_points >= B.n_points else (B, A)
        if abs(float(big.residual(small.centroid[None])[0])) <= gp.max_step_m:
            out.append((pr.a, pr.b))
    return out


def _area_m2(s: Surface, noise_full: NoiseModel, factor: int) -> float:
    """The area of plane ``s``: its work-resolution samples, each a spacing square seen along the ray to its
    centroid (stretched by the obliquity, at most tenfold)."""
    cos_in = abs(float(s.normal @ s.centroid)) / max(float(np.linalg.norm(s.centroid)), 1e-9)
    return s.n_points * float(noise_full.spacing_m(s.z_m) * factor) ** 2 / max(cos_in, 0.1)


def _parts(seam: SeamCurve, surfaces: SurfaceSet, a: int, b: int, intr: CameraIntrinsics) -> bool:
    """Whether ``seam`` runs between surfaces ``a`` and ``b``: at the work resolution, the pixels a few
    samples to one side of its middle half are mostly ``a``'s and those to the other side ``b``'s."""
    f = surfaces.factor
    p0, p1 = seam.points[0], seam.points[-1]
    mid = p0 + np.linspace(0.25, 0.75, 9)[:, None] * (p1 - p0)
    uv = intr.project(mid) / f
    d = intr.project(p1[None])[0] / f - intr.project(p0[None])[0] / f
    side = np.array([-d[1], d[0]]) / max(float(np.linalg.norm(d)), 1e-9)
    h, w = surfaces.labels.shape
    votes = []
    for sign in (-1.0, 1.0):
        q = np.round(uv + sign * 3.0 * side).astype(int)
        ok = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        lab = surfaces.labels[q[ok, 1], q[ok, 0]]
        votes.append((float(np.mean(lab == a)) if lab.size else 0.0, float(np.mean(lab == b)) if lab.size else 0.0))
    (a0, b0), (a1, b1) = votes
    return (a0 > 0.5 and b1 > 0.5) or (b0 > 0.5 and a1 > 0.5)


def _outline_gaps(full: NDArray[np.float32], intr: CameraIntrinsics, surfaces: SurfaceSet, noise_full: NoiseModel,
                  s: Surface, labels: tuple[int, ...], box: tuple[slice, ...], gp: InnerGapParams,
                  color_rgb: NDArray[np.uint8] | None, dark: list[NDArray[np.int16]]) -> list[SeamCurve]:  # fmt: skip
    """The butt seams in the closed outline of the surfaces ``labels`` (their work-resolution ``box``) on
    plane ``s``: :func:`inner_gap_seams` for one outline. ``dark``: the image's dark-line response once
    computed (appended to on first use)."""
    import cv2

    H, W = full.shape[:2]
    window = _plane_window(surfaces, labels, box, (H, W), gp)
    if window is None:
        return []
    (y0, y1, x0, x1), filled, inner = window
    # the plane's residual at the pixels of its closed outline only (the window's others are never read); its
    # normal contiguous, the one type the kernel is compiled for (a column of an eigenvector matrix is strided)
    normal, noise_at = np.ascontiguousarray(s.normal), (noise_full.sigma_1m_m, noise_full.floor_m)
    fy, fx, hole, on_plane = outline_pixels(full, y0, x0, filled, inner, normal, s.offset, s.z_m, noise_at, gp.behind_m)
    px = (fx + x0, fy + y0)
    area: _Window = (full, (y0, y1, x0, x1), [])  # its points are read once, by the first search with lines
    found = _gaps_from_holes(hole, px, intr, s, on_plane, area, noise_full, gp)
    if not found and color_rgb is not None:
        # the depth shows no gap here: one narrower than the sensor resolves may still show as shadow (the
        # depth places a gap it resolves better: seen obliquely, the shadow takes in the far edge's face)
        if not dark:
            dark.append(dark_response(color_rgb))  # once, and only for a capture with a plane to look in
        # a gap has its plate on both sides: a dark line along the outline (a fold's shadow) is not one
        deep = cv2.erode(filled.astype(np.uint8), np.ones((2 * DARK_MARGIN_PX + 1,) * 2, np.uint8)).astype(bool)
        on_line = deep[fy, fx] & dark_line(dark[0][y0:y1, x0:x1], filled)[fy, fx]
        if (on_line & ~hole).sum() >= 15:
            found = _gaps_from_holes(hole | on_line, px, intr, s, on_plane, area, noise_full, gp)
    return found


IntArray = NDArray[np.int64]


@njit(cache=True)
def outline_pixels(full: NDArray[np.float32], y0: int, x0: int, filled: NDArray[np.bool_], inner: NDArray[np.bool_],
                    normal: FloatArray, offset: float, z_m: float, sigma: tuple[float, float],
                    behind_m: float) -> tuple[IntArray, IntArray, NDArray[np.bool_], FloatArray]:  # fmt: skip
    """The ``filled`` pixels of an outline's window (first row and column ``y0``, ``x0`` of ``full``), in raster
    order: their rows and columns in the window, whether each (``inner``) sees through the plane (no depth, or
    depth more than the noise (4 sigma, ``sigma`` = (at 1 m, floor)) and ``behind_m`` behind it), and the points
    within the noise of the plane. Compiled, one pass (as NumPy expressions it gathered every point of a large
    plate's outline first); the values of NumPy's whole-array arithmetic."""
    n = 0
    for y in range(filled.shape[0]):
        for x in range(filled.shape[1]):
            n += filled[y, x]
    fy, fx = np.empty(n, np.int64), np.empty(n, np.int64)
    hole = np.zeros(n, np.bool_)
    keep = np.zeros(n, np.bool_)
    pts = np.empty((n, 3))
    k = 0
    for y in range(filled.shape[0]):
        for x in range(filled.shape[1]):
            if not filled[y, x]:
                continue
            q0, q1, q2 = float(full[y0 + y, x0 + x, 0]), float(full[y0 + y, x0 + x, 1]), float(full[y0 + y, x0 + x, 2])
            fy[k], fx[k] = y, x
            pts[k, 0], pts[k, 1], pts[k, 2] = q0, q1, q2
            seen = np.isfinite(q2)
            res = 0.0  # the residual of the point with NaN taken as 0 (np.nan_to_num)
            for c, q in enumerate((q0, q1, q2)):
                res += (0.0 if np.isnan(q) else q) * normal[c]
            res += offset
            zz = q2 if seen else z_m
            sig = max(sigma[0] * (zz * zz), sigma[1])
            hole[k] = inner[y, x] and (not seen or res < -(behind_m + 4.0 * sig))
            keep[k] = seen and abs(res) <= 4.0 * sig
            k += 1
    return fy, fx, hole, pts[keep]


# the organized cloud, the window (y0, y1, x0, x1) of it an outline lies in, and the window's points once read
_Window = tuple[NDArray[np.float32], tuple[int, int, int, int], list[FloatArray]]


def _gaps_from_holes(hole: NDArray[np.bool_], px: tuple[NDArray[np.int64], NDArray[np.int64]],
                     intr: CameraIntrinsics, s: Surface, on_plane: FloatArray, window: _Window,
                     noise_full: NoiseModel, gp: InnerGapParams) -> list[SeamCurve]:  # fmt: skip
    """The butt seams along the lines of ``hole`` pixels (of the plane's outline, at pixel columns and rows
    ``px``) on plane ``s``; ``on_plane``: its points; ``window``: the organized cloud, the window of it that
    the outline lies in, and its points once read (appended to on first use: the search is run again with
    the colour image's dark lines, on the same window, and a large plate's window holds millions of them)."""
    if hole.sum() < 15:
        return []
    # the hole pixels' rays (only theirs: the whole image's would cost more than the rest of the step)
    uu, vv = px[0][hole].astype(np.float64), px[1][hole].astype(np.float64)
    r = np.stack([(uu - intr.cx) / intr.fx, (vv - intr.cy) / intr.fy, np.ones_like(uu)], axis=1)
    g_all = rays_onto(r, s)  # the hole pixels' rays met with the plate's plane
    lines = _gap_lines(g_all, s.normal, gp, rng=np.random.default_rng(0))
    if not lines:
        return []
    full, (y0, y1, x0, x1), read = window
    if not read:
        ys, xs = np.nonzero(np.isfinite(full[y0:y1, x0:x1, 2]))
        read.append(points_at(full, ys + y0, xs + x0))  # every point in the window, for the strip test
    seen = read[0]
    out = []
    for g, u in lines:
        seam = _gap_between(g, u, s, on_plane, seen, noise_full, gp, all_holes=g_all)
        if seam is not None:
            out.append(seam)
    return out


DARK_SIGMA = 6.0  # a dark line's pixel is darker than both sides by this many sigmas of the plate's own response
DARK_REACH_PX = 2  # the sides are this many pixels away (a line a few pixels wide, blurred by the optics)
DARK_MARGIN_PX = 4  # ... and lies this far inside its plate's outline at least
GREY_FLOOR = 0.5  # grey levels: an 8-bit image's rounding alone spreads the response by about this much


def dark_response(color_rgb: NDArray[np.uint8]) -> NDArray[np.int16]:
    """How much darker (in grey levels of luma) each pixel of (H, W, 3) ``color_rgb`` is than the pixels
    :data:`DARK_REACH_PX` away on both sides, in the direction (row, column or a diagonal) where that is most.
    A thin dark line stands out in the direction across it; a colour edge between two plates is darker on
    one side only."""
    import cv2

    grey = cv2.cvtColor(np.ascontiguousarray(color_rgb, dtype=np.uint8), cv2.COLOR_RGB2GRAY)
    k = DARK_REACH_PX
    resp = np.full(grey.shape, np.iinfo(np.int16).min, dtype=np.int16)
    for dy, dx in ((0, k), (k, 0), (k, k), (k, -k)):
        ker = np.zeros((2 * k + 1, 2 * k + 1), np.uint8)
        ker[k + dy, k + dx] = ker[k - dy, k - dx] = 1
        sides = cv2.erode(grey, ker, borderType=cv2.BORDER_REPLICATE)  # the darker of the two sides
        np.maximum(resp, sides.astype(np.int16) - grey, out=resp)
    return resp


def dark_line(response: NDArray[np.int16], mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The pixels of ``mask`` on a thin dark line: a :func:`dark_response` over :data:`DARK_SIGMA` times its
    robust spread over ``mask`` (the plate's own shading and noise)."""
    r = response[mask].astype(np.float64)  # exactly (grey levels): np.median's values, by fits.median
    if r.size < 100:
        return np.zeros(mask.shape, dtype=bool)
    spread = 1.4826 * float(median(np.abs(r - median(r)), overwrite_input=True))
    return mask & (response > DARK_SIGMA * max(spread, GREY_FLOOR))


def _plane_window(surfaces: SurfaceSet, labels: tuple[int, ...], box: tuple[slice, ...], shape: tuple[int, int],
                  gp: InnerGapParams,
                  ) -> tuple[tuple[int, int, int, int], NDArray[np.bool_], NDArray[np.bool_]] | None:  # fmt: skip
    """The full-resolution window (y0, y1, x0, x1) of the surfaces ``labels`` (a plane, or two plates of one
    plane), their outline there with holes closed, and that outline eroded by a pixel; None for an outline
    too small to hold a gap. ``box``: the labels' bounding box (rows, columns) at the work resolution."""
    import cv2

    f = surfaces.factor
    H, W = shape
    small = np.isin(surfaces.labels[box], labels).astype(np.uint8)
    ys, xs = np.nonzero(small)
    if len(ys) < 50:
        return None
    ys, xs = ys + box[0].start, xs + box[1].start
    y0, y1 = max(ys.min() * f - f, 0), min((ys.max() + 1) * f + f, H)
    x0, x1 = max(xs.min() * f - f, 0), min((xs.max() + 1) * f + f, W)
    mask = cv2.resize(small, None, fx=f, fy=f, interpolation=cv2.INTER_NEAREST)
    region = np.zeros((y1 - y0, x1 - x0), np.uint8)
    oy, ox = ys.min() * f - y0, xs.min() * f - x0
    region[oy : oy + mask.shape[0], ox : ox + mask.shape[1]] = mask[: y1 - y0 - oy, : x1 - x0 - ox]
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (gp.close_px, gp.close_px))
    filled = cv2.morphologyEx(region, cv2.MORPH_CLOSE, k).astype(bool)
    inner = cv2.erode(filled.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return (y0, y1, x0, x1), filled, inner


def _gap_between(g: FloatArray, u: FloatArray, s: Surface, pp: FloatArray, allp: FloatArray, noise_full: NoiseModel,
                 gp: InnerGapParams, *, all_holes: FloatArray) -> SeamCurve | None:  # fmt: skip
    """The butt seam along one line of hole points ``g`` (direction ``u``) on plane ``s``, when the plane's
    points ``pp`` lie on both sides of it all along, nothing of ``allp`` stands in it, the plates reach well
    beyond, and it is empty; None otherwise."""
    c3 = g.mean(axis=0)
    w = np.linalg.eigvalsh(np.cov((g - c3).T))
    u = u - (u @ s.normal) * s.normal
    u /= np.linalg.norm(u)
    across = cross3(s.normal, u)
    gap_half = 2.0 * float(np.sqrt(max(w[1], 0.0))) + 0.5 * float(noise_full.spacing_m(s.z_m))
    # every test below reads points within twice far_m of the line at most: the plate's and the window's
    # points are taken from a strip that wide once (they are a whole plate's, and there are a few lines)
    reach, c_across = 2.0 * gp.far_m + gap_half + gp.side_m + PROFILE_HALF_M, float(c3 @ across)
    pp, allp, all_holes = (x[np.abs(x @ across - c_across) <= reach] for x in (pp, allp, all_holes))
    # the plate on both sides: on-plane points within side_m of the gap line
    d = pp - c3
    a_off, t_along = d @ across, d @ u
    tg = (g - c3) @ u
    lo, hi = float(tg.min()), float(tg.max())
    near = (t_along >= lo) & (t_along <= hi) & (np.abs(a_off) <= gap_half + gp.side_m)
    left, right = near & (a_off < 0), near & (a_off > 0)
    if left.sum() < 10 or right.sum() < 10:
        return None
    # the gap runs on past the plates' ends where the table shows through: it ends where both plates do
    lo, hi = _shared_span(t_along[left], t_along[right], lo, hi)
    if hi - lo < gp.min_length_m:
        return None
    bins = np.linspace(lo, hi, max(2, int((hi - lo) / 0.002)) + 1)
    hl = np.histogram(t_along[left], bins)[0] > 0
    hr = np.histogram(t_along[right], bins)[0] > 0
    if (hl & hr).mean() < gp.min_side_share:
        return None
    # nothing stands in the strip (a wall's base with its stereo shadow beside it is not a gap)
    d_all = allp - c3
    strip = (np.abs(d_all @ across) <= gap_half + 0.002) & (d_all @ u >= lo) & (d_all @ u <= hi)
    if _stands_in(allp[strip], s.normal, s.offset, float(noise_full.sigma_m(s.z_m))):
        return None
    # and the plates reach well beyond: not holes along a narrow face (a plate's edge face)
    far = (t_along >= lo) & (t_along <= hi) & (np.abs(a_off) >= gp.far_m) & (np.abs(a_off) <= 2 * gp.far_m)
    fl = np.histogram(t_along[far & (a_off < 0)], bins)[0] > 0
    fr = np.histogram(t_along[far & (a_off > 0)], bins)[0] > 0
    if (fl & fr).mean() < gp.min_side_share:
        return None
    # each plate's edge lies between its last pixel on the plane and the first pixel that sees
    # through the gap; the seam is midway between the two edges
    h_off = (g - c3) @ across
    last_l, last_r = float(percentile(a_off[left], 97)), float(percentile(a_off[right], 3))
    edge_l = 0.5 * (last_l + float(percentile(h_off, 3)))
    edge_r = 0.5 * (last_r + float(percentile(h_off, 97)))
    width = edge_r - edge_l
    if not (0.0 < width < 0.006):
        return None
    # a gap is empty: inside it, far fewer pixels lie on the plate than beside it; and it stands out from its
    # plates: beside it they hold holes at a tenth of its rate or less (a band of stereo dropouts, a face seen
    # at a grazing angle, holds holes everywhere, and some of them line up). A gap narrower than the sample
    # spacing is seen only in the rows whose pixel centre falls into it, its plates filling the rest of the
    # strip: then it is empty in a fifth of its rows or more, over twice the shortest gap's length (a short line
    # of a few holes in one plate is as well a scanner's seam or a scratch)
    centre = 0.5 * (edge_l + edge_r)
    half = max(0.25 * width, 0.5 * float(noise_full.spacing_m(s.z_m)))
    on_in, on_side = _strip_counts(pp, c3, u, across, (lo, hi), centre, half, width)
    holes_in, holes_side = _strip_counts(all_holes, c3, u, across, (lo, hi), centre, half, width)
    rate_in = holes_in / max(holes_in + on_in, 1.0)
    rate_side = holes_side / max(holes_side + on_side, 1.0)
    empty = on_side > 0 and on_in / half <= 0.5 * on_side / SIDE_BAND_M
    if rate_side > 0.1 * rate_in or not (empty or (rate_in >= 0.2 and hi - lo >= 2.0 * gp.min_length_m)):
        return None
    # seen obliquely, the gap shows the far plate's edge face: the rays that meet it within the noise of
    # the top are taken for the plate, and those that meet it deeper cross the top's plane short of the edge,
    # so both counts place that edge inside the gap. The edges are fitted to the rays' ranges across the gap
    # instead (perception.fine.gap_profile), from the counts' estimates
    edge_l, edge_r = _fitted_edges(allp[(d_all @ u >= lo) & (d_all @ u <= hi)], c3, across, s, noise_full,
                                   (edge_l, edge_r))  # fmt: skip
    centre, width = 0.5 * (edge_l + edge_r), edge_r - edge_l
    mid = c3 + centre * across
    pts_seam = np.array([mid + lo * u, mid + hi * u])
    nrm = np.tile(s.normal, (2, 1))
    return SeamCurve("linear", "butt", pts_seam, nrm, nrm, (s.label, s.label), int(near.sum()), s.rms_m,
                     gap_m=width)  # fmt: skip


def _fitted_edges(q: FloatArray, c3: FloatArray, across: FloatArray, s: Surface, noise_full: NoiseModel,
                  edges: tuple[float, float]) -> tuple[float, float]:  # fmt: skip
    """A gap's edges (offsets along ``across`` from ``c3``) with the far one fitted to the ranges of the points
    ``q`` along it (:func:`perception.fine.gap_profile.gap_edges`) when the gap is seen more than 10 degrees
    across, else (or when no fit is clearly better) ``edges`` as the counts placed them."""
    view_across = float(-c3 @ across) / float(np.linalg.norm(c3))
    if abs(view_across) <= np.sin(np.radians(10.0)):
        return edges
    q = q[np.abs((q - c3) @ across - 0.5 * (edges[0] + edges[1])) <= PROFILE_HALF_M]
    start = edges if view_across > 0 else (edges[1], edges[0])  # (far, near): the rays run to the far plate
    fitted = gap_edges(q, noise_full.sigma_m(q[:, 2]), s, c3, across, start)
    if fitted is None:
        return edges
    return fitted if view_across > 0 else (fitted[1], fitted[0])


def _strip_counts(q: FloatArray, c3: FloatArray, u: FloatArray, across: FloatArray, span: tuple[float, float],
                  centre: float, half_m: float, width_m: float) -> tuple[float, float]:  # fmt: skip
    """How many of the points ``q`` lie along ``span`` within ``half_m`` of a gap's ``centre`` (across it), and
    how many in the two side bands from a millimetre to :data:`SIDE_BAND_M` more beyond its edges."""
    d = q - c3
    t, a = d @ u, np.abs(d @ across - centre)
    along = (t >= span[0]) & (t <= span[1])
    side = (a >= 0.5 * width_m + 0.001) & (a <= 0.5 * width_m + 0.001 + SIDE_BAND_M)
    return float((along & (a <= half_m)).sum()), float((along & side).sum())


SCORE_POINTS = 1000  # RANSAC trials are scored on at most this many hole points (a sample of them)


def _gap_lines(g: FloatArray, normal: FloatArray, gp: InnerGapParams, *, rng: np.random.Generator,
               trials: int = 300, max_lines: int = 3) -> list[tuple[FloatArray, FloatArray]]:  # fmt: skip
    """Straight thin lines through (N, 3) hole points on a plane, RANSAC on point pairs: each line's points
    (within 1 mm) and direction, when it is long and its 2 mm bins are mostly hit (a gap seen in dots)."""
    out: list[tuple[FloatArray, FloatArray]] = []
    left = g
    for _ in range(max_lines):
        if len(left) < 15:
            break
        i = rng.integers(0, len(left), (trials, 2))
        d = left[i[:, 1]] - left[i[:, 0]]
        ln = np.linalg.norm(d, axis=1)
        ok = ln > 0.01
        if not ok.any():
            break
        d = d[ok] / ln[ok, None]
        o = left[i[ok, 0]]
        across = np.cross(normal, d)
        offset = (across * o).sum(axis=1)
        if len(left) > SCORE_POINTS:  # the trials scored on a sample, the best line's points taken from all
            sample = np.ascontiguousarray(left[rng.choice(len(left), SCORE_POINTS, replace=False)].T)
            k = best_trial(across, offset, sample, 0.001)
            across, offset = across[k : k + 1], offset[k : k + 1]
        pts = left[best_line(across, offset, np.ascontiguousarray(left.T), 0.001)]
        if len(pts) < 15:
            break
        # least squares on the inliers, then the points of this gap (within its widest) leave the pool
        c = pts.mean(axis=0)
        _, v = np.linalg.eigh(np.cov((pts - c).T))
        u = v[:, 2] - (v[:, 2] @ normal) * normal
        u /= np.linalg.norm(u)
        t = (pts - c) @ u
        length = float(np.ptp(t))
        bins = max(1, int(length / 0.002))
        hit = np.bincount(np.clip(((t - t.min()) / 0.002).astype(int), 0, bins - 1), minlength=bins) > 0
        off = np.abs((left - c) @ cross3(normal, u))
        left = left[off > 0.0025]
        if length >= gp.min_length_m and hit.mean() >= 0.4:
            out.append((pts, u))
    return out
