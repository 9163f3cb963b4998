"""V-grooves whose bevels the segmentation did not keep as surfaces.

Two plates prepared for a butt weld with bevelled edges leave a trough between their top faces. Seen from
far or steeply, each bevel is a strip a few pixels wide, too thin to survive as a surface. Here the trough is
found from the plates: two (nearly) coplanar plates whose facing edges run parallel a groove's width apart,
with the points between them below the plates' plane. Each bevel is fitted at full resolution from the
trough's cross-section (depth below the plates against the distance across), and the two bevels become
surfaces: the refinement then places the root (their intersection, or the middle of their lower edges
where the root is open) and the ends, as for any fold.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.fine.adjacency import adjacent_pairs, plane_partners
from perception.fine.folds import contact_points, plane_line
from perception.fine.refine import near_points
from perception.fine.runs import covered_runs
from perception.fine.surfaces import _fit_plane
from perception.fine.types import FloatArray, NoiseModel, SeamCurve, Surface, SurfaceSet
from perception.fits import median, percentile


@dataclass(frozen=True)
class GrooveParams:
    max_angle_rad: float = np.radians(4.0)  # the two plates' tops are this close to parallel
    max_step_m: float = 0.003  # ... and offset by at most this much
    min_width_m: float = 0.004  # narrower than this is a butt gap (see :mod:`perception.fine.gaps`)
    max_width_m: float = 0.050
    min_slope: float = np.tan(np.radians(12.0))  # a bevel sinks at least this steeply towards the root
    min_depth_sigma: float = 4.0  # trough points lie this many sigma below the plates
    min_points: int = 30  # per bevel, full resolution
    min_length_m: float = 0.020
    bin_m: float = 0.002
    max_hole_m: float = 0.010


def groove_seams(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    noise: NoiseModel,
    full: NDArray[np.floating],
    intr: CameraIntrinsics,
    noise_full: NoiseModel,
    *,
    support: frozenset[int],
    params: GrooveParams | None = None,
) -> tuple[list[SeamCurve], SurfaceSet]:
    """Coarse V-groove seams between plates, and the surfaces with the fitted bevels appended (labels after
    the segmented ones; they have no pixels in ``labels``)."""
    gp = params or GrooveParams()
    p = np.asarray(points, dtype=np.float64)
    # only nearly parallel plates are looked at: the other surfaces are not dilated by the groove's wide reach
    among = plane_partners(surfaces, min_cos=float(np.cos(gp.max_angle_rad)), exclude=support)
    pairs = adjacent_pairs(surfaces, noise, reach_m=0.5 * gp.max_width_m + 0.004, among=among)
    out: list[SeamCurve] = []
    extra: list[Surface] = []
    for pair in pairs:
        if pair.a in support or pair.b in support:
            continue
        A, B = surfaces.surfaces[pair.a], surfaces.surfaces[pair.b]
        if A.kind != "plane" or B.kind != "plane" or float(A.normal @ B.normal) < np.cos(gp.max_angle_rad):
            continue
        pa, pb = contact_points(p, surfaces.labels, pair)
        if len(pa) < 10 or len(pb) < 10 or abs(float(median(A.residual(pb)))) > gp.max_step_m:
            continue
        frame = _facing_edges(pa, pb, A, B, noise, gp)
        if frame is None:
            continue
        c, u, across, n, edge_a, edge_b, t_lo, t_hi = frame
        mid = c + 0.5 * (edge_a + edge_b) * across
        line = np.array([mid + t_lo * u, mid + t_hi * u])
        q = near_points(np.asarray(full, dtype=np.float32), intr, line, 0.5 * (edge_b - edge_a) + 0.004)
        found = _bevels(q, c, u, across, n, 0.5 * (A.offset + B.offset), edge_a, edge_b, t_lo, t_hi,
                        noise_full, gp)  # fmt: skip
        if found is None:
            continue
        qa, qb = found
        la, lb = len(surfaces.surfaces) + len(extra), len(surfaces.surfaces) + len(extra) + 1
        bevel_a, bevel_b = _surface(la, qa), _surface(lb, qb)
        seam = _root_line(bevel_a, bevel_b, qa, qb, u, mid, gp)
        if seam is None:
            continue
        extra += [bevel_a, bevel_b]
        out.append(seam)
    if not extra:
        return out, surfaces
    return out, replace(surfaces, surfaces=surfaces.surfaces + tuple(extra))


_Edges = tuple[FloatArray, FloatArray, FloatArray, FloatArray, float, float, float, float]


def _facing_edges(pa: FloatArray, pb: FloatArray, A: Surface, B: Surface, noise: NoiseModel,
                  gp: GrooveParams) -> _Edges | None:  # fmt: skip
    """The plates' facing edges: a centre point, the direction along them, across (from A to B), the mean
    normal, the two edges' offsets across and the stretch along where both have points."""
    from scipy.spatial import cKDTree

    da, _ = cKDTree(pb).query(pa)
    db, _ = cKDTree(pa).query(pb)
    reach = gp.max_width_m + 3.0 * float(noise.spacing_m(A.z_m))
    ea, eb = pa[da <= reach], pb[db <= reach]
    if len(ea) < 8 or len(eb) < 8:
        return None
    n = A.normal + B.normal
    n /= np.linalg.norm(n)
    both = np.vstack([ea, eb])
    c = both.mean(axis=0)
    # along the edges: the direction in the plates' plane across which the two sides separate best
    flat = both - c - np.outer((both - c) @ n, n)
    _, v = np.linalg.eigh(flat.T @ flat)
    u = v[:, 2] - (v[:, 2] @ n) * n
    u /= np.linalg.norm(u)
    across = np.cross(n, u)
    if float((eb.mean(axis=0) - ea.mean(axis=0)) @ across) < 0:
        across = -across
    sa, sb = (ea - c) @ across, (eb - c) @ across
    edge_a, edge_b = float(percentile(sa, 95)), float(percentile(sb, 5))
    width = edge_b - edge_a
    if not (gp.min_width_m <= width <= gp.max_width_m):
        return None
    ta, tb = (ea - c) @ u, (eb - c) @ u
    lo, hi = max(float(ta.min()), float(tb.min())), min(float(ta.max()), float(tb.max()))
    if hi - lo < gp.min_length_m:
        return None
    return c, u, across, n, edge_a, edge_b, lo, hi


def _bevels(q: FloatArray, c: FloatArray, u: FloatArray, across: FloatArray, n: FloatArray, offset: float,
            edge_a: float, edge_b: float, t_lo: float, t_hi: float, noise: NoiseModel,
            gp: GrooveParams) -> tuple[FloatArray, FloatArray] | None:  # fmt: skip
    """The full-resolution points of the two bevels: the trough's points between the edges, below the plates,
    each half fitted as a line in the cross-section (depth against across) and kept within its noise."""
    if len(q) < 2 * gp.min_points:
        return None
    s = (q - c) @ across
    t = (q - c) @ u
    depth = -(q @ n + offset)  # below the plates' plane (their normals face the camera)
    sig = noise.sigma_m(q[:, 2])
    inside = (s > edge_a - 0.002) & (s < edge_b + 0.002) & (t >= t_lo) & (t <= t_hi)
    trough = inside & (depth > gp.min_depth_sigma * sig)
    if trough.sum() < 2 * gp.min_points:
        return None
    mid = 0.5 * (edge_a + edge_b)
    sides = []
    for half, sign in ((s < mid, 1.0), (s >= mid, -1.0)):
        sel = trough & half
        if sel.sum() < gp.min_points:
            return None
        keep = sel.copy()
        slope = 0.0
        for _ in range(4):
            A = np.column_stack([np.ones(int(keep.sum())), s[keep]])
            coef, *_ = np.linalg.lstsq(A, depth[keep], rcond=None)
            slope = float(coef[1])
            r = depth - (coef[0] + coef[1] * s)
            # the residual across the line is the depth residual times the bevel's cosine
            keep = sel & (np.abs(r) * np.cos(np.arctan(abs(slope))) <= 3.0 * sig)
            if keep.sum() < gp.min_points:
                return None
        if sign * slope < gp.min_slope:  # each bevel deepens towards the middle
            return None
        sides.append(q[keep])
    return sides[0], sides[1]


def _surface(label: int, q: FloatArray) -> Surface:
    n, off, rms = _fit_plane(q)
    return Surface(label, "plane", n, off, rms, len(q), q.mean(axis=0), float(np.median(q[:, 2])))


def _root_line(a: Surface, b: Surface, qa: FloatArray, qb: FloatArray, u: FloatArray, mid: FloatArray,
               gp: GrooveParams) -> SeamCurve | None:  # fmt: skip
    """The bevels' intersection over the stretch where both have points (bins along the groove)."""
    line = plane_line(a, b, mid, along=u)
    if line is None:
        return None
    p0, d = line
    ta, tb = (qa - p0) @ d, (qb - p0) @ d
    lo, hi = max(float(ta.min()), float(tb.min())), min(float(ta.max()), float(tb.max()))
    if hi - lo < gp.min_length_m:
        return None
    nbins = int(np.ceil((hi - lo) / gp.bin_m))

    def cover(t: FloatArray) -> NDArray[np.bool_]:
        return np.bincount(np.clip(((t - lo) / gp.bin_m).astype(int), 0, nbins - 1), minlength=nbins) > 0

    runs = covered_runs(cover(ta[(ta >= lo) & (ta <= hi)]) & cover(tb[(tb >= lo) & (tb <= hi)]),
                        int(gp.max_hole_m / gp.bin_m))  # fmt: skip
    if not runs:
        return None
    r0, r1 = max(runs, key=lambda r: r[1] - r[0])
    t0, t1 = lo + r0 * gp.bin_m, lo + r1 * gp.bin_m
    if t1 - t0 < gp.min_length_m:
        return None
    pts = np.array([p0 + t0 * d, p0 + t1 * d])
    rms = max(a.rms_m, b.rms_m)
    return SeamCurve("linear", "v_groove", pts, np.tile(a.normal, (2, 1)), np.tile(b.normal, (2, 1)),
                     (a.label, b.label), len(qa) + len(qb), rms)  # fmt: skip
