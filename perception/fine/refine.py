"""Seams refitted on full-resolution points: both surfaces refitted near the seam, intersected again.

Near a seam each full-resolution point goes to the surface it lies on (within the noise, on that surface's
side of the seam); each plane is refitted on its points within ``band_m`` of the seam and, beyond the band,
on its own segmented work-resolution points out to ``face_reach_m`` (weighted by the area each stands
for), and the seam is their new intersection. A depth sensor's low-frequency error (a stereo camera's
correlated disparity noise) tilts a plane fitted on a narrow band; the whole face averages it out.
Where neither surface reaches the intersection (an open root: a V-groove's root gap
seen from above), the seam is the middle of the two surfaces' facing edges instead.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.fine.biweight import biweight_plane
from perception.fine.cylinder import axis_basis, circle_fit_across
from perception.fine.folds import line_coords, plane_line, rays_onto, ring_points
from perception.fine.root import open_root
from perception.fine.seam_ends import supported_ends
from perception.fine.types import FloatArray, NoiseModel, SeamCurve, Surface, SurfaceSet
from perception.fits import cross3, median, percentile
from perception.organized import points_at

COPY_SIGMA = 1.5  # see _others_residual
ROOT_RADIUS_M = 0.008  # a V-groove's root profile is traced this far from the bevels' intersection at most
# a straight seam's planes are refitted on every k-th of the points near it, and of those beyond the band, to about
# this many of each: with more the seams move by hundredths of a millimetre at most (dev zoo: RMSE 0.138 mm with all
# of them, 0.137 with 16 000, 0.146 with 8 000), and a close capture's bands hold 100 000 and more
FIT_POINTS = 16_000


@dataclass(frozen=True)
class RefineParams:
    band_m: float = 0.020
    face_reach_m: float = 0.100  # beyond the band, a plane's fit takes its own surface's points this far
    inlier_sigma: float = 3.5
    corner_sigma: float = 3.0  # the fits leave out points this many sigma (plus a spacing) from the corner
    iterations: int = 3
    end_near_m: float = 0.0015  # support for the ends: points this close to the seam (plus noise, spacing)
    end_bin_m: float = 0.001
    end_hole_m: float = 0.006
    end_slack_m: float = 0.006  # the ends may move this far beyond the coarse ones
    min_piece_m: float = 0.012  # a stretch apart from the longest is a seam of its own from this long (a fold's)


def near_points(full: NDArray[np.float32], intr: CameraIntrinsics, curve: FloatArray, band_m: float, *,
                read: NDArray[np.bool_] | None = None) -> FloatArray:  # fmt: skip
    """Full-resolution points (N, 3) in the image band around ``curve``: the pixels within ``band_m`` of its
    projection, at its nearest range (plus two pixels). ``read``, when given, (H, W): the pixels read are
    marked in it (the fine stage's crop is what all its steps read)."""
    return _near_box(full, intr, curve, band_m, read=read)[0]


def _near_box(full: NDArray[np.float32], intr: CameraIntrinsics, curve: FloatArray, band_m: float, *,
              read: NDArray[np.bool_] | None = None) -> tuple[FloatArray, NDArray[np.int64]]:  # fmt: skip
    """:func:`near_points`, and each point's pixel (row, column) in ``full``."""
    import cv2

    box = _pixel_box(intr, curve, band_m, full.shape[:2])
    if box is None:
        return np.zeros((0, 3)), np.zeros((0, 2), dtype=np.int64)
    v0, v1, u0, u1 = box
    # the band: the curve's projection drawn as wide as band_m at the curve's nearest point (a superset of
    # the points within band_m of it in space; the box alone holds far more beside a diagonal seam)
    half_px = int(np.ceil(band_m * intr.fx / max(float(np.min(curve[:, 2])), 1e-3))) + 2
    uv = intr.project(curve) - np.array([u0, v0])
    mask = np.zeros((v1 - v0, u1 - u0), np.uint8)
    cv2.polylines(mask, [np.round(uv).astype(np.int32).reshape(-1, 1, 2)], False, 1, thickness=2 * half_px + 1)
    vv, uu = np.nonzero(mask)
    q = full[vv + v0, uu + u0]
    ok = np.isfinite(q[:, 2])
    px = np.stack([vv[ok] + v0, uu[ok] + u0], axis=1)
    if read is not None:
        read[px[:, 0], px[:, 1]] = True
    return np.asarray(q[ok], dtype=np.float64), px


def _pixel_box(intr: CameraIntrinsics, curve: FloatArray, margin_m: float, shape: tuple[int, ...], *,
               factor: int = 1) -> tuple[int, int, int, int] | None:  # fmt: skip
    """(row0, row1, col0, col1) of the image box around ``curve``'s pixels grown by ``margin_m`` at its range
    (plus two pixels), in an image of ``shape`` subsampled by ``factor``; None when it is empty."""
    uv = intr.project(curve) / factor
    z = float(median(curve[:, 2]))
    m = int(np.ceil(margin_m * intr.fx / factor / max(z, 1e-3))) + 2
    h, w = shape[:2]
    c0, c1 = int(max(np.floor(uv[:, 0].min()) - m, 0)), int(min(np.ceil(uv[:, 0].max()) + m + 1, w))
    r0, r1 = int(max(np.floor(uv[:, 1].min()) - m, 0)), int(min(np.ceil(uv[:, 1].max()) + m + 1, h))
    return None if c0 >= c1 or r0 >= r1 else (r0, r1, c0, c1)


def _others_residual(q: FloatArray, px: NDArray[np.int64], surfaces: SurfaceSet, pair: tuple[int, int],
                     noise: NoiseModel) -> FloatArray:  # fmt: skip
    """Per point, the smallest |residual| to any other segmented surface present in the points' box (inf where
    there is none): a point another surface explains better than either of the pair's (the plate's top face
    beyond a bevel's convex edge, the floor seen through a root gap) does not belong in their fits. A surface
    whose own points here lie within the noise of one of the pair's faces (median |residual| under
    COPY_SIGMA) is a fragment of that face the segmentation left apart, not another surface, and is not
    counted: choosing between two near-copies of a face would bias its fit. (A fragment's own plane, fitted
    on a few noisy pixels, can be tilted far from the face's; its points are not.)"""
    f = surfaces.factor
    h, w = surfaces.labels.shape
    lab = surfaces.labels[np.minimum(px[:, 0] // f, h - 1), np.minimum(px[:, 1] // f, w - 1)]
    ra, rb = (np.abs(surfaces.surfaces[i].residual(q)) for i in pair)
    sig = noise.sigma_m(q[:, 2])
    best = np.full(len(q), np.inf)
    for k in np.unique(lab):
        if k < 0 or k in pair or k >= len(surfaces.surfaces):
            continue
        mine = lab == k
        if min(float(median(ra[mine] / sig[mine])), float(median(rb[mine] / sig[mine]))) < COPY_SIGMA:
            continue
        best = np.minimum(best, np.abs(surfaces.surfaces[int(k)].residual(q)))
    return best


def _side(surface: Surface, other: Surface, p0: FloatArray, u: FloatArray, ref: FloatArray) -> FloatArray:
    """Unit direction in ``surface``'s plane, across the line, towards ``ref`` (a point on that surface)."""
    v = cross3(u, surface.normal)
    v /= np.linalg.norm(v)
    return v if float((ref - p0) @ v) >= 0 else -v


def refine_seams(
    seams: list[SeamCurve],
    full: NDArray[np.float32],
    intr: CameraIntrinsics,
    surfaces: SurfaceSet,
    noise_full: NoiseModel,
    *,
    params: RefineParams | None = None,
    read: NDArray[np.bool_] | None = None,
) -> tuple[list[SeamCurve], int]:
    """Refined seams, and how many full-resolution points the refinement read in the seams' bands, each
    counted once (the fine stage's crop). ``read``, when given, (H, W): those pixels are marked in it. Each
    seam's refinement is its own (:func:`refine_one`: a caller may share them out among processes)."""
    rp = params or RefineParams()
    if read is None:
        read = np.zeros(full.shape[:2], dtype=bool)
    out: list[SeamCurve] = []
    for s in seams:
        out += refine_one(s, full, intr, surfaces, noise_full, rp, read)
    return out, int(read.sum())


def refine_one(s: SeamCurve, full: NDArray[np.float32], intr: CameraIntrinsics, surfaces: SurfaceSet,
               noise_full: NoiseModel, rp: RefineParams, read: NDArray[np.bool_]) -> list[SeamCurve]:  # fmt: skip
    """One seam of :func:`refine_seams`: its refined pieces (none when the full resolution does not hold it);
    the pixels it read are marked in ``read``."""
    q, px = _near_box(full, intr, s.points, rp.band_m, read=read)
    A, B = surfaces.surfaces[s.surfaces[0]], surfaces.surfaces[s.surfaces[1]]
    if s.joint == "butt" or (A.kind == B.kind == "plane" and abs(float(A.normal @ B.normal)) > np.cos(0.17)):
        return [s]  # gaps and steps are placed at full resolution by their own steps
    if s.kind == "linear" and A.kind == "plane" and B.kind == "plane":
        others = _others_residual(q, px, surfaces, s.surfaces, noise_full)
        beyond = _face_points(full, intr, surfaces, s.points, rp.face_reach_m)
        pieces = _refine_line(s, q, others, A, B, noise_full, rp, beyond=beyond,
                              weight_beyond=float(surfaces.factor**2))  # fmt: skip
        if pieces:
            segmented = _labelled_points(full, intr, surfaces, s.points, rp.end_slack_m + rp.band_m)
            pieces = [_within_segmentation(r, segmented, noise_full, surfaces.factor, rp) for r in pieces]
        return pieces
    if s.kind == "curved" and "plane" in (A.kind, B.kind):
        plane = A if A.kind == "plane" else B
        far, lab = _face_points(full, intr, surfaces, s.points, rp.face_reach_m)
        return [_refine_ring(s, q, A, B, noise_full, rp, beyond=far[lab == plane.label],
                             weight_beyond=float(surfaces.factor**2))]  # fmt: skip
    return [s]


def _face_points(full: NDArray[np.float32], intr: CameraIntrinsics, surfaces: SurfaceSet, curve: FloatArray,
                 reach_m: float) -> tuple[FloatArray, NDArray[np.int32]]:  # fmt: skip
    """The full-resolution points at the work-resolution pixels of any segmented surface beside ``curve``
    (within its image box grown by ``reach_m``, between its ends), less a pixel along each surface's
    boundary (a face is rounded or blurred at its edges), and their labels. Fragments of one face that the
    segmentation left apart are all among them."""
    window = _work_window(intr, surfaces, curve, reach_m)
    if window is None:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int32)
    corner, inner = window
    lab = np.pad(inner, 1, mode="edge")
    interior = (inner >= 0) & (lab[:-2, 1:-1] == inner) & (lab[2:, 1:-1] == inner)
    interior &= (lab[1:-1, :-2] == inner) & (lab[1:-1, 2:] == inner)
    q = _window_points(full, surfaces.factor, corner, interior)
    chord = curve[-1] - curve[0]
    length = float(np.linalg.norm(chord))
    along = (q - curve[0]) @ (chord / max(length, 1e-9))
    ok = np.isfinite(q[:, 2]) & (along >= 0.0) & (along <= length)  # beside the seam, not past its ends
    return q[ok], inner[interior][ok]


def _labelled_points(full: NDArray[np.float32], intr: CameraIntrinsics, surfaces: SurfaceSet, curve: FloatArray,
                     margin_m: float) -> tuple[FloatArray, NDArray[np.int32]]:  # fmt: skip
    """The full-resolution points at the work-resolution pixels of every segmented surface in ``curve``'s
    image box grown by ``margin_m``, and their labels."""
    window = _work_window(intr, surfaces, curve, margin_m)
    if window is None:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int32)
    corner, lab = window
    mask = lab >= 0
    q = _window_points(full, surfaces.factor, corner, mask)
    ok = np.isfinite(q[:, 2])
    return q[ok], lab[mask][ok]


def _work_window(intr: CameraIntrinsics, surfaces: SurfaceSet, curve: FloatArray,
                 margin_m: float) -> tuple[tuple[int, int], NDArray[np.int32]] | None:  # fmt: skip
    """The work-resolution window around ``curve``'s pixels grown by ``margin_m``: its first row and column,
    and its pixels' labels; None when the window is empty."""
    box = _pixel_box(intr, curve, margin_m, surfaces.labels.shape, factor=surfaces.factor)
    if box is None:
        return None
    r0, r1, c0, c1 = box
    return (r0, c0), surfaces.labels[r0:r1, c0:c1]


def _window_points(full: NDArray[np.float32], factor: int, corner: tuple[int, int],
                   mask: NDArray[np.bool_]) -> FloatArray:  # fmt: skip
    """The full-resolution points (float64, in raster order) of the work-resolution pixels ``mask`` of a
    window whose first row and column are ``corner``."""
    ys, xs = np.nonzero(mask)
    return points_at(full, (ys + corner[0]) * factor, (xs + corner[1]) * factor)


def _within_segmentation(s: SeamCurve, segmented: tuple[FloatArray, NDArray[np.int32]], noise: NoiseModel,
                         factor: int, rp: RefineParams) -> SeamCurve:  # fmt: skip
    """Straight seam ``s`` with its ends kept within half a sample spacing (where a face's edge lies on average
    past its last sample) of where each face's segmented pixels (its surface and its fragments, at the work
    resolution) reach along it. Full-resolution support runs on past a face's end where its edge is blurred:
    at a grazing angle the mixed pixels beside a face's silhouette lie within the noise of its plane; the
    segmentation, which takes only pixels whose neighbourhood is smooth and grows within the noise, stops
    at the face's edge."""
    q, lab = segmented
    if len(q) == 0:
        return s
    line0, u = s.points[0], s.points[-1] - s.points[0]
    length = float(np.linalg.norm(u))
    u = u / length
    z = float(median(s.points[:, 2]))
    sig, spacing = float(noise.sigma_m(z)), float(noise.spacing_m(z)) * factor
    reach = rp.end_near_m + 4.0 * sig + 3.0 * spacing
    sig_q = noise.sigma_m(q[:, 2])
    groups = [(int(k), np.flatnonzero(lab == k)) for k in np.unique(lab)]
    lo, hi = 0.0, length
    for normal, label in ((s.normals_a[0], s.surfaces[0]), (s.normals_b[0], s.surfaces[1])):
        mine = _fragments(groups, np.abs((q - line0) @ normal), sig_q, label)  # the face's plane through the seam
        t, d = line_coords(q[mine], line0, u)
        t = t[d <= reach]
        if len(t) < 2:
            return s
        lo, hi = max(lo, float(t.min()) - 0.5 * spacing), min(hi, float(t.max()) + 0.5 * spacing)
    if hi - lo < 0.005 or (lo, hi) == (0.0, length):
        return s
    return replace(s, points=np.array([line0 + lo * u, line0 + hi * u]))


def _refine_line(s: SeamCurve, q: FloatArray, others: FloatArray, A: Surface, B: Surface, noise: NoiseModel,
                 rp: RefineParams, *, beyond: tuple[FloatArray, NDArray[np.int32]] | None = None,
                 weight_beyond: float = 1.0) -> list[SeamCurve]:  # fmt: skip
    """The seam of planes A and B refitted on the points ``q`` near it and on ``beyond`` (labelled, weighted):
    one seam for each stretch where both faces are there (a gusset standing across a fold parts it), the
    longest first; none when the full-resolution points do not hold both faces beside it (ten points of
    each, clear of the corner and within the noise) or no stretch of it has both (a fold between two
    warped plates' pieces that lie on each other's planes only along a strip, not a seam)."""
    p0, p1 = s.points[0], s.points[-1]
    length = float(np.linalg.norm(p1 - p0))
    u = (p1 - p0) / length
    if len(q) < 20:
        return []
    d = q - p0
    t = d @ u
    inside = (t >= -0.002) & (t <= length + 0.002)
    q, t, others = q[inside], t[inside], others[inside]
    if len(q) < 20:
        return []
    far = (np.zeros((0, 3)), np.zeros(0, dtype=np.int32)) if beyond is None else beyond
    sig = noise.sigma_m(q[:, 2])
    margin = rp.corner_sigma * sig + noise.spacing_m(q[:, 2])  # per point: the corner's and a far edge's rounding
    by_ray = s.joint == "v_groove"
    fitted = _fit_faces(s, (q, others, sig, margin), (A, B), far, weight_beyond, noise, rp)
    if fitted is None:
        return []
    a, b, line0, u, va, vb = fitted
    on_a, on_b = _fit_sets(q, others, (a, b), line0, u, (va, vb), sig, margin, rp, by_ray=by_ray)  # every point's
    # a V-groove's open root: the two bevels stop short of their intersection and the camera sees through
    # between them; the seam is the middle of their lower edges (the other folds' seam is the intersection)
    ra_s, rb_s = q @ a.normal + a.offset, q @ b.normal + b.offset  # signed: in front of a face is positive
    ra, rb = np.abs(ra_s), np.abs(rb_s)
    dl = q - line0
    da, db = dl @ va, dl @ vb
    all_a = (ra <= rb) & (ra <= others) & (da > -0.0005) & (da <= rp.band_m) & (ra <= rp.inlier_sigma * sig)
    all_b = (rb < ra) & (rb <= others) & (db > -0.0005) & (db <= rp.band_m) & (rb <= rp.inlier_sigma * sig)
    if all_a.sum() < 10 or all_b.sum() < 10:
        return []
    gap = 0.0
    if s.joint == "v_groove":
        reach = min(float(median(da[all_a])), float(median(db[all_b])))
        line0, gap = _root_line(q, sig, line0, u, (va, vb), (a, b), (p0, p1), reach)
    # something standing in a fold (a gusset across it): points in front of both faces, beyond the corner's
    # rounding; the seam is not carried across it as across a hole in the data, and goes on past it as a seam
    # of its own. A V-groove's extent is its trace's (perception.fine.trace): its longest stretch only
    t_standing = None
    if s.joint != "v_groove":
        standing = (ra_s > 2.0 * margin) & (rb_s > 2.0 * margin) & (np.maximum(da, db) <= rp.band_m)
        t_standing = (q[standing] - line0) @ u
    pieces = supported_ends(q[all_a], q[all_b], a, b, line0, u, float((p0 - line0) @ u), float((p1 - line0) @ u),
                            noise, rp, standing=t_standing, boundary=s.joint != "v_groove")  # fmt: skip
    if not pieces:
        return []
    if s.joint == "v_groove":
        pieces = pieces[:1]
    return _seams_of(s, pieces, q, (on_a, on_b), (a, b), line0, u, gap)


_Faces = tuple[Surface, Surface, FloatArray, FloatArray, FloatArray, FloatArray]  # planes, line (point, along), sides


def _fit_faces(s: SeamCurve, near: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
               faces: tuple[Surface, Surface], beyond: tuple[FloatArray, NDArray[np.int32]], weight_beyond: float,
               noise: NoiseModel, rp: RefineParams) -> _Faces | None:  # fmt: skip
    """Seam ``s``'s faces refitted (:func:`_refine_line`): ``near`` holds the points near it with, per point,
    the nearest other surface's residual, the noise and the corner margin; ``beyond`` the labelled points
    beyond the band (each weighing ``weight_beyond``). The planes, the line (a point and its direction) and
    the directions across it into each face; None when a face keeps fewer than ten points or the planes no
    longer meet. The planes are fitted on every k-th point near the seam and beyond it (FIT_POINTS), weighted
    for the points left out."""
    (q, others, sig, margin), (A, B) = near, faces
    far, far_lab = beyond
    k_far = max(1, -(-len(far) // FIT_POINTS))
    far, far_lab, weight_beyond = far[::k_far], far_lab[::k_far], weight_beyond * k_far
    sig_far = noise.sigma_m(far[:, 2])
    far_groups = [(int(k), np.flatnonzero(far_lab == k)) for k in np.unique(far_lab)]  # per surface, found once
    k_near = max(1, -(-len(q) // FIT_POINTS))
    q, others, sig, margin = q[::k_near], others[::k_near], sig[::k_near], margin[::k_near]
    weight_beyond /= k_near  # the near points stand for k_near each as well
    p0, p1 = s.points[0], s.points[-1]
    u = (p1 - p0) / float(np.linalg.norm(p1 - p0))
    a, b = A, B
    va = _side(a, b, p0, u, _towards(A, u, s))
    vb = _side(b, a, p0, u, _towards(B, u, s))
    line0 = p0
    last: tuple[NDArray[np.bool_], NDArray[np.bool_], FloatArray, FloatArray] | None = None
    for _ in range(rp.iterations):
        on_a, on_b = _fit_sets(q, others, (a, b), line0, u, (va, vb), sig, margin, rp, by_ray=s.joint == "v_groove")
        if on_a.sum() < 10 or on_b.sum() < 10:
            return None
        fa, fb = _beyond_band(far, far_groups, sig_far, (a, b), (A.label, B.label), line0, (va, vb), rp)
        chosen = (on_a, on_b, fa, fb)
        if last is not None and all(np.array_equal(x, y) for x, y in zip(chosen, last, strict=True)):
            break  # the same points as the last refit: it would give the same planes, line and sides again
        last = chosen
        a = _refit(a, A, q[on_a], fa, weight_beyond, noise)
        b = _refit(b, B, q[on_b], fb, weight_beyond, noise)
        line = plane_line(a, b, 0.5 * (p0 + p1), along=u)
        if line is None:
            return None
        line0, u = line
        va = _side(a, b, line0, u, line0 + va)
        vb = _side(b, a, line0, u, line0 + vb)
    return a, b, line0, u, va, vb


def _seams_of(s: SeamCurve, pieces: list[FloatArray], q: FloatArray,
              fitted: tuple[NDArray[np.bool_], NDArray[np.bool_]], planes: tuple[Surface, Surface],
              line0: FloatArray, u: FloatArray, gap: float) -> list[SeamCurve]:  # fmt: skip
    """Seam ``s`` refitted: one seam per stretch of ``pieces`` (their ends), on the refitted ``planes`` and
    their fitted points (masks of ``q``)."""
    (on_a, on_b), (a, b) = fitted, planes
    rms = float(np.sqrt(np.mean(np.concatenate([(q[on_a] @ a.normal + a.offset) ** 2,
                                                (q[on_b] @ b.normal + b.offset) ** 2]))))  # fmt: skip
    t_on = (q - line0) @ u
    out = []
    for ends in pieces:
        lo, hi = sorted(float((e - line0) @ u) for e in ends)
        # the fit's points; those along its own stretch where the fold is parted
        fit = (on_a | on_b) if len(pieces) == 1 else (on_a | on_b) & (t_on >= lo) & (t_on <= hi)
        out.append(replace(s, points=ends, normals_a=np.tile(a.normal, (2, 1)), normals_b=np.tile(b.normal, (2, 1)),
                           support=int(fit.sum()), rms_m=rms, gap_m=gap))  # fmt: skip
    return out


def _fit_sets(q: FloatArray, others: FloatArray, planes: tuple[Surface, Surface], line0: FloatArray, u: FloatArray,
              across: tuple[FloatArray, FloatArray], sig: FloatArray, margin: FloatArray,
              rp: RefineParams, *, by_ray: bool = False) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:  # fmt: skip
    """Per point of ``q``: whether it goes into face A's refit and into face B's, for the current planes, line
    (``line0``, ``u``) and directions ``across`` it into each face. ``by_ray``: which face a point is on is
    read from its pixel's ray (:func:`_seen_faces`), else from the nearer plane."""
    a, b = planes
    va, vb = across
    ra, rb = np.abs(q @ a.normal + a.offset), np.abs(q @ b.normal + b.offset)
    dl = q - line0
    da, db = dl @ va, dl @ vb
    if by_ray:
        first_a, first_b = _seen_faces(q, planes, line0, across, (_reach(da, ra, sig, rp), _reach(db, rb, sig, rp)))
    else:
        first_a, first_b = (ra <= rb) & (da > -0.0005), (rb < ra) & (db > -0.0005)
    # near the corner a point lies within the noise of both faces: those points would pull each plane
    # towards the other, so the fits use what lies beyond a few sigma of the current line
    tl = dl @ u
    sq = dl * dl
    dist = np.sqrt(np.maximum(sq[:, 0] + sq[:, 1] + sq[:, 2] - tl * tl, 0.0))  # the row sums' own order
    clear = dist > margin
    # a point another surface explains better is not this pair's (fragments of the pair's own faces are
    # not among the others: choosing between two near-copies of a face would bias its fit)
    mine = np.minimum(ra, rb) <= others
    side_a = first_a & mine & (da <= rp.band_m) & clear
    side_b = first_b & mine & (db <= rp.band_m) & clear
    # each face's own noise (a face seen obliquely is noisier): gating it at the capture's typical
    # sigma would cut one tail of its residuals and tilt the plane
    on_a = side_a & (ra <= rp.inlier_sigma * _face_sigma(ra[side_a], sig, side_a))
    on_b = side_b & (rb <= rp.inlier_sigma * _face_sigma(rb[side_b], sig, side_b))
    # a face that ends inside the band (a bevel's convex edge with the plate's top) is rounded there as
    # at the corner: its last few sigma would tilt the plane too
    on_a &= _short_of_far_edge(da, on_a, margin, rp.band_m)
    on_b &= _short_of_far_edge(db, on_b, margin, rp.band_m)
    return on_a, on_b


def _reach(d: FloatArray, res: FloatArray, sig: FloatArray, rp: RefineParams) -> float:
    """How far from the line (along its direction into the face, ``d`` per point) a face reaches: the 99th
    percentile of the points within its noise (``res`` their distances to its plane) on its side, within the
    band; the band where fewer than ten are."""
    own = (d > 0.0) & (d <= rp.band_m) & (res <= rp.inlier_sigma * sig)
    return float(percentile(d[own], 99.0)) if own.sum() >= 10 else rp.band_m


def _seen_faces(q: FloatArray, planes: tuple[Surface, Surface], line0: FloatArray,
                across: tuple[FloatArray, FloatArray],
                reaches: tuple[float, float]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:  # fmt: skip
    """Per point of ``q``: whether its pixel's ray (from the camera at the origin) meets face A first (A's
    plane on A's side of the line ``line0``, ``across[0]`` into A and at most ``reaches[0]`` from it, nearer
    than B's plane on B's), and whether it meets face B first. A face's plane beyond its reach is not the
    face: a ray that crosses a bevel's plane above the plate's top goes on to the other bevel.

    The noise moves a point along its ray. Near a V-groove's root every ray passes within the noise of both
    bevels, and the nearer plane to the measured point is the one the noise pushed it towards: the bevel
    seen obliquely gained the other's points and tilted (dev v_groove 26, OAK-D at 0.89 m: 4.3 degrees, the
    root 1.1 mm off; by the ray 0.3 degrees and 0.2 mm). Where the ray meets a plane does not depend on the
    noise. Dev, 480 V-grooves: captures passing 398 -> 419, RMSE 0.322 -> 0.256 mm, p95 0.668 -> 0.441 mm.
    Applied to the folds of every joint it moved their seams by hundredths of a millimetre, the ribs' more
    often away from the truth than towards it (dev 480: 444 passing against 445 with grooves alone), so only
    grooves read faces by the ray for now."""
    rng = np.sqrt(np.einsum("ij,ij->i", q, q))
    hit_range, on_side = [], []
    for S, v, reach in zip(planes, across, reaches, strict=True):
        with np.errstate(divide="ignore", invalid="ignore"):
            hit = rays_onto(q, S)
        # in front of the camera, and not a ray along the plane
        ok = (np.abs(q @ S.normal) > 1e-9 * rng) & np.isfinite(hit[:, 0]) & (np.einsum("ij,ij->i", hit, q) > 0.0)
        hit[~ok] = 0.0
        hit_range.append(np.where(ok, np.sqrt(np.einsum("ij,ij->i", hit, hit)), np.inf))
        d_hit = (hit - line0) @ v
        on_side.append(ok & (d_hit > 0.0) & (d_hit <= reach))
    first_a = on_side[0] & (~on_side[1] | (hit_range[0] <= hit_range[1]))
    return first_a, on_side[1] & ~first_a


def _root_line(q: FloatArray, sig: FloatArray, line0: FloatArray, u: FloatArray,
               across: tuple[FloatArray, FloatArray], faces: tuple[Surface, Surface],
               ends: tuple[FloatArray, FloatArray], reach_m: float) -> tuple[FloatArray, float]:  # fmt: skip
    """A V-groove's seam: the middle of its bevels' lower edges and the gap between them when its root is open
    (:mod:`perception.fine.root`), else the bevels' intersection ``line0`` and no gap."""
    span = (float((ends[0] - line0) @ u), float((ends[1] - line0) @ u))
    edges = open_root(q, sig, line0, u, across, faces, span, radius_m=min(0.6 * reach_m, ROOT_RADIUS_M))
    if edges is None:
        return line0, 0.0
    edge_a, edge_b = line0 + edges[0] * across[0], line0 + edges[1] * across[1]
    return 0.5 * (edge_a + edge_b), float(np.linalg.norm(edge_b - edge_a))


def _beyond_band(far: FloatArray, groups: list[tuple[int, NDArray[np.intp]]], sig: FloatArray,
                 planes: tuple[Surface, Surface], own: tuple[int, int], line0: FloatArray,
                 across: tuple[FloatArray, FloatArray], rp: RefineParams) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """Beyond the band, each face's points: those of the face and of its fragments, on its side of the line,
    within the noise of its current plane and nearer it than the other face's. ``groups``: each surface
    label among the points with their indices."""
    ra, rb = (np.abs(S.residual(far)) for S in planes)
    d = far - line0
    out = []
    for r_own, r_other, label, v in ((ra, rb, own[0], across[0]), (rb, ra, own[1], across[1])):
        keep = _fragments(groups, r_own, sig, label) & (d @ v > rp.band_m)
        out.append(far[keep & (r_own <= rp.inlier_sigma * sig) & (r_own <= r_other)])
    return out[0], out[1]


def _fragments(groups: list[tuple[int, NDArray[np.intp]]], res: FloatArray, sig: FloatArray,
               own: int) -> NDArray[np.bool_]:  # fmt: skip
    """Per point: whether its surface is ``own`` or a fragment of the same face (most of its points lie
    within the noise of the face's current plane: median |residual| under COPY_SIGMA, the rule of
    :func:`_others_residual`). ``groups``: each surface label among the points with their indices."""
    out = np.zeros(len(res), bool)
    for k, idx in groups:
        if k == own or float(median(res[idx] / sig[idx], overwrite_input=True)) < COPY_SIGMA:
            out[idx] = True
    return out


def _refit(S: Surface, S0: Surface, near: FloatArray, far: FloatArray, weight_far: float,
           noise: NoiseModel | None = None) -> Surface:  # fmt: skip
    """``S`` refitted (Tukey's biweight) on ``near`` (weight 1) and ``far`` (weight ``weight_far``), normal on
    ``S0``'s side. With the ``noise`` model: refitted on the points of the plane most of ``near`` lie on instead,
    when the fit leaves too many of them outside the noise across it, and that plane holds more and leaves out
    points on one side of it only (:mod:`perception.fine.dominant_plane`: another surface close beside a narrow
    face)."""
    from perception.fine.dominant_plane import dominant_plane, one_sided, within_noise

    def fit(a: FloatArray, b: FloatArray) -> tuple[FloatArray, float]:
        return biweight_plane(np.concatenate([a, b]), np.concatenate([np.ones(len(a)), np.full(len(b), weight_far)]))

    n, off = fit(near, far)
    if noise is not None and (start := dominant_plane(near, n, off, noise)) is not None:
        n2, off2 = fit(near[within_noise(near, *start, noise)], far[within_noise(far, *start, noise)])
        more = within_noise(near, n2, off2, noise).sum() > within_noise(near, n, off, noise).sum()
        if more and one_sided(near, n2, off2, noise):
            n, off = n2, off2
    if n @ S0.normal < 0:
        n, off = -n, -off
    return replace(S, normal=n, offset=off)


def _short_of_far_edge(d: FloatArray, on: NDArray[np.bool_], margin: FloatArray, band_m: float) -> NDArray[np.bool_]:
    """Per point: not within ``margin`` of where the face's support ends, when it ends inside the band."""
    if on.sum() < 10:
        return on
    far = float(percentile(d[on], 99.0))
    if far >= band_m - float(median(margin[on])):
        return np.ones_like(on)
    return d < far - margin


def _face_sigma(res: FloatArray, sig: FloatArray, side: NDArray[np.bool_]) -> FloatArray:
    """Per point: the larger of the capture's sigma at its range and the face's own robust residual scale
    (from the points nearest the face within the noise), at most five times the capture's."""
    if res.size < 10:
        return sig
    core = res[res <= percentile(res, 80)]
    own = 1.4826 * float(median(core)) / 0.7  # the median of |r| over the inner 80% of a normal: 0.7 MAD
    typical = float(median(sig[side]))
    return np.maximum(sig, np.clip(own, typical, 5.0 * typical))


def _towards(S: Surface, u: FloatArray, s: SeamCurve) -> FloatArray:
    """A point on S beside the seam: the seam's midpoint moved into S (along S's plane, away from the other
    surface's normal side)."""
    other_n = s.normals_b[0] if S.label == s.surfaces[0] else s.normals_a[0]
    v = cross3(u, S.normal)
    v /= np.linalg.norm(v)
    # S extends from the fold towards the side the other face's normal points to
    v = v if float(v @ other_n) > 0 else -v
    return np.asarray(0.5 * (s.points[0] + s.points[-1]) + 0.01 * v, dtype=np.float64)


def _refine_ring(s: SeamCurve, q: FloatArray, A: Surface, B: Surface, noise: NoiseModel, rp: RefineParams, *,
                 beyond: FloatArray | None = None, weight_beyond: float = 1.0) -> SeamCurve:  # fmt: skip
    """A plane-cylinder seam (a ring) refitted on the points ``q`` near it: the plane on its points there
    clear of the corner and on its own segmented points ``beyond`` the band (weighted, as a straight seam's
    faces), the cylinder's centre and radius across its axis (kept from the whole surface) on its points
    there clear of the corner (:func:`perception.fine.cylinder.circle_fit_across`)."""
    P, C = (A, B) if A.kind == "plane" else (B, A)
    if len(q) < 50:
        return s
    from scipy.spatial import cKDTree

    d, _ = cKDTree(s.points).query(q)
    near = d <= rp.band_m
    q, d = q[near], d[near]
    if len(q) < 50:
        return s
    sig = noise.sigma_m(q[:, 2])
    clear = d > rp.corner_sigma * sig + noise.spacing_m(q[:, 2])  # the corner's rounding, as a straight seam's
    far = np.zeros((0, 3)) if beyond is None else beyond
    if len(far):
        far = far[cKDTree(s.points).query(far)[0] > rp.band_m]
    sig_far = noise.sigma_m(far[:, 2])
    for _ in range(rp.iterations):
        rp_, rc = np.abs(P.residual(q)), np.abs(C.residual(q))
        on_p = (rp_ <= rp.inlier_sigma * sig) & (rp_ <= rc) & (C.residual(q) > -0.0005) & clear
        on_c = (rc <= rp.inlier_sigma * sig) & (rc < rp_) & (P.residual(q) > -0.0005) & clear
        if on_p.sum() < 20 or on_c.sum() < 20:
            return s
        P = _refit(P, P, q[on_p], far[np.abs(P.residual(far)) <= rp.inlier_sigma * sig_far], weight_beyond)
        qc = q[on_c]
        circle = circle_fit_across(qc, C.axis)
        if circle is None:
            return s
        centre, radius = circle
        C = replace(C, centre=centre + float(np.mean(qc @ C.axis)) * C.axis, radius=radius)
    # the same arc, on the refined surfaces
    e1, e2 = axis_basis(C.axis)
    rel = s.points - C.centre
    theta = np.unwrap(np.arctan2(rel @ e2, rel @ e1))
    ring, radial = ring_points(P, C, theta)
    normals_p = np.tile(P.normal, (len(ring), 1))
    rms = float(np.sqrt(np.mean(np.concatenate([P.residual(q[on_p]) ** 2, C.residual(q[on_c]) ** 2]))))
    if A.kind == "plane":
        return replace(s, points=ring, normals_a=normals_p, normals_b=radial, rms_m=rms)
    return replace(s, points=ring, normals_a=radial, normals_b=normals_p, rms_m=rms)
