"""Seams refitted on full-resolution points: both surfaces refitted near the seam, intersected again.

Near a seam each full-resolution point goes to the surface it lies on (within the noise, on that surface's
side of the seam); each surface is refitted on its points within ``band_m`` of the seam, and the seam is
their new intersection. Where neither surface reaches the intersection (an open root: a V-groove's root gap
seen from above), the seam is the middle of the two surfaces' facing edges instead.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.fine.folds import plane_line, ring_points
from perception.fine.runs import covered_runs
from perception.fine.surfaces import _fit_plane, axis_basis, circle_across
from perception.fine.types import FloatArray, NoiseModel, SeamCurve, Surface, SurfaceSet


@dataclass(frozen=True)
class RefineParams:
    band_m: float = 0.020
    inlier_sigma: float = 3.5
    corner_sigma: float = 3.0  # the fits leave out points this many sigma (plus a spacing) from the corner
    open_root_m: float = 0.0006  # both faces stop this far short of their intersection: an open root
    iterations: int = 3
    end_near_m: float = 0.0015  # support for the ends: points this close to the seam (plus noise, spacing)
    end_bin_m: float = 0.001
    end_hole_m: float = 0.006
    end_slack_m: float = 0.006  # the ends may move this far beyond the coarse ones


def near_points(full: NDArray[np.float32], intr: CameraIntrinsics, curve: FloatArray, band_m: float) -> FloatArray:
    """Full-resolution points (N, 3) in the image box of ``curve`` grown by ``band_m`` at its range."""
    uv = intr.project(curve)
    z = float(np.median(curve[:, 2]))
    m = int(np.ceil(band_m * intr.fx / max(z, 1e-3))) + 2
    H, W = full.shape[:2]
    u0, u1 = int(max(np.floor(uv[:, 0].min()) - m, 0)), int(min(np.ceil(uv[:, 0].max()) + m + 1, W))
    v0, v1 = int(max(np.floor(uv[:, 1].min()) - m, 0)), int(min(np.ceil(uv[:, 1].max()) + m + 1, H))
    if u0 >= u1 or v0 >= v1:
        return np.zeros((0, 3))
    q = full[v0:v1, u0:u1].reshape(-1, 3)
    return np.asarray(q[np.isfinite(q[:, 2])], dtype=np.float64)


def _side(surface: Surface, other: Surface, p0: FloatArray, u: FloatArray, ref: FloatArray) -> FloatArray:
    """Unit direction in ``surface``'s plane, across the line, towards ``ref`` (a point on that surface)."""
    v = np.cross(u, surface.normal)
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
) -> tuple[list[SeamCurve], int]:
    """Refined seams, and how many full-resolution points the refinement read (the fine stage's crop)."""
    rp = params or RefineParams()
    out: list[SeamCurve] = []
    used = 0
    for s in seams:
        q = near_points(full, intr, s.points, rp.band_m)
        used += len(q)
        A, B = surfaces.surfaces[s.surfaces[0]], surfaces.surfaces[s.surfaces[1]]
        if s.joint == "butt" or (A.kind == B.kind == "plane" and abs(float(A.normal @ B.normal)) > np.cos(0.17)):
            out.append(s)  # gaps and steps are placed at full resolution by their own steps
        elif s.kind == "linear" and A.kind == "plane" and B.kind == "plane":
            out.append(_refine_line(s, q, A, B, noise_full, rp))
        elif s.kind == "curved":
            out.append(_refine_ring(s, q, A, B, noise_full, rp))
        else:
            out.append(s)
    return out, used


def _refine_line(s: SeamCurve, q: FloatArray, A: Surface, B: Surface, noise: NoiseModel,
                 rp: RefineParams) -> SeamCurve:  # fmt: skip
    p0, p1 = s.points[0], s.points[-1]
    length = float(np.linalg.norm(p1 - p0))
    u = (p1 - p0) / length
    if len(q) < 20:
        return s
    d = q - p0
    t = d @ u
    inside = (t >= -0.002) & (t <= length + 0.002)
    q, t = q[inside], t[inside]
    if len(q) < 20:
        return s
    sig = noise.sigma_m(q[:, 2])
    spacing = noise.spacing_m(q[:, 2])
    a, b = A, B
    va = _side(a, b, p0, u, _towards(A, u, s))
    vb = _side(b, a, p0, u, _towards(B, u, s))
    line0 = p0
    for _ in range(rp.iterations):
        ra, rb = np.abs(q @ a.normal + a.offset), np.abs(q @ b.normal + b.offset)
        da, db = (q - line0) @ va, (q - line0) @ vb
        # near the corner a point lies within the noise of both faces: those points would pull each plane
        # towards the other, so the fits use what lies beyond a few sigma of the current line
        dl = q - line0
        tl = dl @ u
        dist = np.sqrt(np.maximum((dl * dl).sum(axis=1) - tl * tl, 0.0))
        clear = dist > rp.corner_sigma * sig + spacing
        side_a = (ra <= rb) & (da > -0.0005) & (da <= rp.band_m) & clear
        side_b = (rb < ra) & (db > -0.0005) & (db <= rp.band_m) & clear
        # each face's own noise (a face seen obliquely is noisier): gating it at the capture's typical
        # sigma would cut one tail of its residuals and tilt the plane
        on_a = side_a & (ra <= rp.inlier_sigma * _face_sigma(ra[side_a], sig, side_a))
        on_b = side_b & (rb <= rp.inlier_sigma * _face_sigma(rb[side_b], sig, side_b))
        if on_a.sum() < 10 or on_b.sum() < 10:
            return s
        na, _, _ = _fit_plane(q[on_a])
        nb, _, _ = _fit_plane(q[on_b])
        na = na if na @ A.normal > 0 else -na
        nb = nb if nb @ B.normal > 0 else -nb
        a = replace(a, normal=na, offset=-float(na @ q[on_a].mean(axis=0)))
        b = replace(b, normal=nb, offset=-float(nb @ q[on_b].mean(axis=0)))
        line = plane_line(a, b, 0.5 * (p0 + p1), along=u)
        if line is None:
            return s
        line0, u = line
        va = _side(a, b, line0, u, line0 + va)
        vb = _side(b, a, line0, u, line0 + vb)
    # open root: neither face reaches the intersection; the seam is the middle of their facing edges (each
    # face's points on it, the corner zone included)
    ra, rb = np.abs(q @ a.normal + a.offset), np.abs(q @ b.normal + b.offset)
    da, db = (q - line0) @ va, (q - line0) @ vb
    all_a = (ra <= rb) & (da > -0.0005) & (da <= rp.band_m) & (ra <= rp.inlier_sigma * sig)
    all_b = (rb < ra) & (db > -0.0005) & (db <= rp.band_m) & (rb <= rp.inlier_sigma * sig)
    if all_a.sum() < 10 or all_b.sum() < 10:
        return s
    ea = float(np.percentile(da[all_a], 2))
    eb = float(np.percentile(db[all_b], 2))
    gap = 0.0
    if _open_root(q, line0, u, va, vb, a, b, ea, eb, sig, spacing, (p0, p1), rp):
        edge_a, edge_b = line0 + ea * va, line0 + eb * vb
        gap = float(np.linalg.norm(edge_b - edge_a))
        line0 = 0.5 * (edge_a + edge_b)
    ends = _supported_ends(q[all_a], q[all_b], a, b, line0, u, float((p0 - line0) @ u), float((p1 - line0) @ u),
                           noise, rp)  # fmt: skip
    if ends is None:
        return s
    rms = float(np.sqrt(np.mean(np.concatenate([(q[on_a] @ a.normal + a.offset) ** 2,
                                                (q[on_b] @ b.normal + b.offset) ** 2]))))  # fmt: skip
    return replace(s, points=ends, normals_a=np.tile(a.normal, (2, 1)), normals_b=np.tile(b.normal, (2, 1)),
                   support=int(on_a.sum() + on_b.sum()), rms_m=rms, gap_m=gap)  # fmt: skip


def _open_root(q: FloatArray, line0: FloatArray, u: FloatArray, va: FloatArray, vb: FloatArray, a: Surface,
               b: Surface, ea: float, eb: float, sig: FloatArray, spacing: FloatArray,
               ends: tuple[FloatArray, FloatArray], rp: RefineParams) -> bool:  # fmt: skip
    """Whether both faces stop short of their intersection because the root is open (a V-groove's root gap).
    Near a closed corner each face's nearest points come within about a sample of it; stopping short alone
    may also be missing data (a stereo shadow, the root hidden by a bevel), so an open root also needs points
    seen through it: between the two faces' edges and behind the chord that joins them, along a good part
    of the seam."""
    s_typ, sp_typ = float(np.median(sig)), float(np.median(spacing))
    if min(ea, eb) <= max(rp.open_root_m, 3.0 * s_typ + 0.5 * sp_typ):
        return False
    edge_a, edge_b = line0 + ea * va, line0 + eb * vb
    chord = edge_b - edge_a
    half = 0.5 * float(np.linalg.norm(chord))
    x = chord / max(2.0 * half, 1e-12)
    out = a.normal + b.normal  # out of the groove, towards the camera side of both faces
    out -= (out @ u) * u
    out /= max(float(np.linalg.norm(out)), 1e-12)
    rel = q - 0.5 * (edge_a + edge_b)
    off_both = (np.abs(a.residual(q)) > 3.0 * sig) & (np.abs(b.residual(q)) > 3.0 * sig)
    through = (np.abs(rel @ x) < half) & off_both & (rel @ out < sig)
    t0, t1 = sorted(float((e - line0) @ u) for e in ends)
    step = 2.0 * rp.end_bin_m
    bins = max(1, int(np.ceil((t1 - t0) / step)))
    k = np.floor(((q[through] - line0) @ u - t0) / step).astype(int)
    hit = np.zeros(bins, bool)
    hit[k[(k >= 0) & (k < bins)]] = True
    return bool(hit.mean() >= 0.3)


def _face_sigma(res: FloatArray, sig: FloatArray, side: NDArray[np.bool_]) -> FloatArray:
    """Per point: the larger of the capture's sigma at its range and the face's own robust residual scale
    (from the points nearest the face within the noise), at most five times the capture's."""
    if res.size < 10:
        return sig
    core = res[res <= np.percentile(res, 80)]
    own = 1.4826 * float(np.median(core)) / 0.7  # the median of |r| over the inner 80% of a normal: 0.7 MAD
    typical = float(np.median(sig[side]))
    return np.maximum(sig, np.clip(own, typical, 5.0 * typical))


def _supported_ends(qa: FloatArray, qb: FloatArray, a: Surface, b: Surface, line0: FloatArray, u: FloatArray,
                    t0: float, t1: float, noise: NoiseModel, rp: RefineParams) -> FloatArray | None:  # fmt: skip
    """The seam's ends from full-resolution support: along the line, where both faces have points close to
    it but clearly off the other face (bins of ``end_bin_m``, two points each), the covered stretch that
    overlaps the coarse one; its outermost points. Near the corner each face's points are within the noise
    of the other face too, and where one face ends the other's points there would seem to continue it."""
    spans = []
    for q, other in ((qa, b), (qb, a)):
        d = q - line0
        t = d @ u
        dist = np.sqrt(np.maximum((d * d).sum(axis=1) - t * t, 0.0))
        z = float(np.median(q[:, 2]))
        sig = float(noise.sigma_m(z))
        off = other.residual(q)
        close = (off > 3.0 * sig) & (dist <= rp.end_near_m + 4.0 * sig + 3.0 * float(noise.spacing_m(z)))
        spans.append(t[close])
    ta, tb = spans
    if len(ta) < 3 or len(tb) < 3:
        return None
    lo, hi = min(t0, t1) - rp.end_slack_m, max(t0, t1) + rp.end_slack_m
    nb = max(1, int(np.ceil((hi - lo) / rp.end_bin_m)))

    def cover(t: FloatArray) -> NDArray[np.bool_]:
        k = np.floor((t[(t >= lo) & (t < hi)] - lo) / rp.end_bin_m).astype(int)
        return np.bincount(np.clip(k, 0, nb - 1), minlength=nb) >= 2

    both = cover(ta) & cover(tb)
    runs = covered_runs(both, int(rp.end_hole_m / rp.end_bin_m))
    if not runs:
        return None
    r0, r1 = max(runs, key=lambda r: r[1] - r[0])
    ta_r = ta[(ta >= lo + r0 * rp.end_bin_m) & (ta < lo + r1 * rp.end_bin_m)]
    tb_r = tb[(tb >= lo + r0 * rp.end_bin_m) & (tb < lo + r1 * rp.end_bin_m)]
    s0 = max(float(ta_r.min()), float(tb_r.min()))
    s1 = min(float(ta_r.max()), float(tb_r.max()))
    if s1 - s0 < 0.005:
        return None
    return np.array([line0 + s0 * u, line0 + s1 * u])


def _towards(S: Surface, u: FloatArray, s: SeamCurve) -> FloatArray:
    """A point on S beside the seam: the seam's midpoint moved into S (along S's plane, away from the other
    surface's normal side)."""
    other_n = s.normals_b[0] if S.label == s.surfaces[0] else s.normals_a[0]
    v = np.cross(u, S.normal)
    v /= np.linalg.norm(v)
    # S extends from the fold towards the side the other face's normal points to
    v = v if float(v @ other_n) > 0 else -v
    return np.asarray(0.5 * (s.points[0] + s.points[-1]) + 0.01 * v, dtype=np.float64)


def _refine_ring(s: SeamCurve, q: FloatArray, A: Surface, B: Surface, noise: NoiseModel,
                 rp: RefineParams) -> SeamCurve:  # fmt: skip
    P, C = (A, B) if A.kind == "plane" else (B, A)
    if len(q) < 50:
        return s
    from scipy.spatial import cKDTree

    d, _ = cKDTree(s.points).query(q)
    q = q[d <= rp.band_m]
    if len(q) < 50:
        return s
    sig = noise.sigma_m(q[:, 2])
    for _ in range(rp.iterations):
        rp_, rc = np.abs(P.residual(q)), np.abs(C.residual(q))
        on_p = (rp_ <= rp.inlier_sigma * sig) & (rp_ <= rc) & (C.residual(q) > -0.0005)
        on_c = (rc <= rp.inlier_sigma * sig) & (rc < rp_) & (P.residual(q) > -0.0005)
        if on_p.sum() < 20 or on_c.sum() < 20:
            return s
        n, _, _ = _fit_plane(q[on_p])
        n = n if n @ P.normal > 0 else -n
        P = replace(P, normal=n, offset=-float(n @ q[on_p].mean(axis=0)))
        # the cylinder: axis kept (from the whole surface), centre and radius refitted on the points here
        qc = q[on_c]
        circle = circle_across(qc, C.axis)
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
