"""Concave folds between two fitted surfaces: the seam is their intersection, clipped to where both have support.

For two planes the intersection is a line; for a plane and a cylinder standing on it, a ring (an ellipse
where the axis is tilted). The curve is kept only where both surfaces have points within reach of it, bin by
bin along it, so that a rib's fillet ends where the rib does and a hole or an occluder splits it. A fold is
a seam only when it is concave: each surface's points near the fold lie on the camera side of the other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from perception.fine.cylinder import axis_basis
from perception.fine.runs import covered_runs
from perception.fine.types import FloatArray, Joint, NoiseModel, Pair, SeamCurve, Surface, SurfaceSet
from perception.fits import cross3, mean_rows, median, percentile


@dataclass(frozen=True)
class FoldParams:
    min_turn_rad: float = np.radians(20.0)  # two planes closer to parallel than this do not fold
    bin_m: float = 0.002
    max_hole_m: float = 0.008
    min_length_m: float = 0.012
    near_m: float = 0.004  # support within this of the curve (plus noise and spacing) counts
    concave_sigma: float = 2.0
    lap_height_m: float = 0.014  # a standing face this narrow across the seam is a lap edge
    crease_window_px: float = 12.0  # the local turn is measured on both faces this many work pixels either side


SHALLOW_TURN_RAD = np.radians(80.0)
CAMERA_DOWN = np.array([0.0, 0.0, -1.0])  # "up" with no support: as though the camera looked straight down
MIN_TEE_POINTS = 20  # a face goes on past another plane when this many of its points lie beyond it
# a "plate" whose points lie on a cylinder (this share of them within three sigma) is a strip of the cylinder's
# own surface (see _plane_cylinder); a plate reaches out from a pipe's foot, off the cylinder
ON_CYLINDER_SHARE = 0.8
PLATE_SAMPLE = 2000  # a plate's points are judged on about this many of them


def rays_onto(x: FloatArray, s: Surface) -> FloatArray:
    """Where the camera's rays through the (N, 3) points or directions ``x`` meet plane ``s``."""
    return np.asarray(x * (-s.offset / (x @ s.normal))[:, None])


def plane_line(a: Surface, b: Surface, near: FloatArray,
               along: FloatArray | None = None) -> tuple[FloatArray, FloatArray] | None:  # fmt: skip
    """Point (nearest ``near``) and unit direction of the intersection of two planes, the direction turned
    to agree with ``along`` when given; None for parallel planes."""
    u = cross3(a.normal, b.normal)
    norm = float(np.linalg.norm(u))
    if norm < 1e-6:
        return None
    u /= norm
    if along is not None and float(u @ along) < 0:
        u = -u
    A = np.vstack([a.normal, b.normal, u])
    rhs = np.array([-a.offset, -b.offset, float(u @ near)])
    return np.asarray(np.linalg.solve(A, rhs), dtype=np.float64), u


def contact_points(p: FloatArray, labels: NDArray[np.int32], pair: Pair) -> tuple[FloatArray, FloatArray]:
    """The (N, 3) points of surface ``pair.a`` and of ``pair.b`` among the pair's contact pixels."""
    pa, pb, _, _ = contact_points_px(p, labels, pair)
    return pa, pb


def contact_points_px(p: FloatArray, labels: NDArray[np.int32],
                      pair: Pair) -> tuple[FloatArray, FloatArray, NDArray[np.int64], NDArray[np.int64]]:  # fmt: skip
    """:func:`contact_points` with each point's (row, col) pixel: (pa, pb, px_a, px_b)."""
    la = labels[pair.contact_px[:, 0], pair.contact_px[:, 1]]
    px_a, px_b = pair.contact_px[la == pair.a], pair.contact_px[la == pair.b]
    pa, pb = p[px_a[:, 0], px_a[:, 1]], p[px_b[:, 0], px_b[:, 1]]
    fa, fb = np.isfinite(pa[:, 2]), np.isfinite(pb[:, 2])
    return pa[fa], pb[fb], px_a[fa], px_b[fb]


def joint_type(na: FloatArray, nb: FloatArray, up: FloatArray | None, standing_height_m: float,
               lap_height_m: float) -> Joint:  # fmt: skip
    """Name a fold by how its faces stand relative to ``up`` (the support's normal). With no support (a
    cloud of the part alone) nothing says which way is up: a shallow valley (faces turning by under
    :data:`SHALLOW_TURN_RAD`, an included angle over 100 degrees) is a groove however it lies, and the
    others are named as though the camera looked down."""
    if up is None:
        if float(na @ nb) > np.cos(SHALLOW_TURN_RAD):
            return "v_groove"
        up = CAMERA_DOWN
    ca, cb = abs(float(na @ up)), abs(float(nb @ up))
    if ca < 0.3 and cb < 0.3:  # both faces stand within about 17 degrees of vertical
        return "inside_corner"
    if 0.3 < ca < 0.97 and 0.3 < cb < 0.97:
        return "v_groove"
    if min(ca, cb) < 0.5 < max(ca, cb) and standing_height_m <= lap_height_m:
        return "lap"
    return "fillet"


def fold_seams(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    pairs: tuple[Pair, ...],
    noise: NoiseModel,
    *,
    support: frozenset[int],
    params: FoldParams | None = None,
) -> list[SeamCurve]:
    """Every concave fold between adjacent surfaces (neither the support), clipped to both supports."""
    fp = params or FoldParams()
    p = np.asarray(points, dtype=np.float64)
    lab = surfaces.labels
    up = surfaces.surfaces[min(support)].normal if support else None
    out: list[SeamCurve] = []
    for pair in pairs:
        if pair.a in support or pair.b in support:
            continue
        A, B = surfaces.surfaces[pair.a], surfaces.surfaces[pair.b]
        pa, pb = contact_points(p, lab, pair)
        if len(pa) < 5 or len(pb) < 5:
            continue
        if A.kind == "plane" and B.kind == "plane":
            found = _plane_pair(p, lab, A, B, pa, pb, noise, fp, up, pair.contact_px)
            if any(c.joint == "lap" for c in found) and not _upper_plate(p, lab, pairs, A, B, up, support):
                found = [c for c in found if c.joint != "lap"]
            out += found
        elif A.kind != B.kind:
            P, C = (A, B) if A.kind == "plane" else (B, A)
            pp, pc = (pa, pb) if A.kind == "plane" else (pb, pa)
            plate = p.reshape(-1, 3)[np.flatnonzero(lab.reshape(-1) == P.label)]
            plate = plate[:: max(1, len(plate) // PLATE_SAMPLE)]
            out += _plane_cylinder(P, C, pp, pc, plate, noise, fp)
        else:
            out += _cylinder_pair(A, B, pa, pb, noise, fp)
    return out


def _plane_pair(p: FloatArray, lab: NDArray[np.int32], A: Surface, B: Surface, pa: FloatArray, pb: FloatArray,
                noise: NoiseModel, fp: FoldParams, up: FloatArray | None,
                contact_px: NDArray[np.int64]) -> list[SeamCurve]:  # fmt: skip
    if abs(float(A.normal @ B.normal)) > np.cos(fp.min_turn_rad):
        return []
    near = np.vstack([pa, pb]).mean(axis=0)
    line = plane_line(A, B, near)
    if line is None:
        return []
    p0, u = line
    z = float(near[2])
    sig = float(noise.sigma_m(z))
    reach = fp.near_m + 3.0 * sig + 3.0 * float(noise.spacing_m(z))
    out: list[SeamCurve] = []
    ta, da = line_coords(pa, p0, u)
    tb, db = line_coords(pb, p0, u)
    near_a, near_b = da <= reach, db <= reach
    ta, tb = ta[near_a], tb[near_b]
    if len(ta) < 3 or len(tb) < 3:
        return []
    lo, hi = max(ta.min(), tb.min()), min(ta.max(), tb.max())
    if hi - lo < fp.min_length_m:
        return []
    # concave: each side's points along the fold lie on the camera side of the other plane (a convex edge
    # has both behind), at least one of them clearly. Only the stretch both sides share counts: beside a
    # narrow face (a bar's end) the other surface's contact points also run past the face's own edges
    qa, qb = pa[near_a][(ta >= lo) & (ta <= hi)], pb[near_b][(tb >= lo) & (tb <= hi)]
    if len(qa) < 3 or len(qb) < 3:
        return []
    ra, rb = B.residual(qa), A.residual(qb)
    sa, sb = float(median(ra)), float(median(rb))
    if min(sa, sb) <= 0.0 or max(percentile(ra, 75), percentile(rb, 75)) < fp.concave_sigma * sig:
        return []
    # the fold is where the faces turn, not only where two fitted facets of a bent panel meet
    wa, wb = _window_points(p, lab, (A.label, B.label), contact_px, fp.crease_window_px)
    turn = local_turn(wa, wb, p0, u, A.normal + B.normal, (lo, hi), fp.crease_window_px * float(noise.spacing_m(z)))
    if turn is not None and turn < fp.min_turn_rad:
        return []
    nb_ = int(np.ceil((hi - lo) / fp.bin_m))
    ca = np.bincount(np.clip(((ta - lo) / fp.bin_m).astype(int), 0, nb_ - 1)[(ta >= lo) & (ta <= hi)], minlength=nb_)
    cb = np.bincount(np.clip(((tb - lo) / fp.bin_m).astype(int), 0, nb_ - 1)[(tb >= lo) & (tb <= hi)], minlength=nb_)
    for s0, s1 in covered_runs((ca > 0) & (cb > 0), int(fp.max_hole_m / fp.bin_m)):
        t0, t1 = lo + s0 * fp.bin_m, lo + s1 * fp.bin_m
        if t1 - t0 < fp.min_length_m:
            continue
        pts = np.array([p0 + t0 * u, p0 + t1 * u])
        height = _standing_height(p, lab, A, B, p0, u, CAMERA_DOWN if up is None else up)
        joint = joint_type(A.normal, B.normal, up, height, fp.lap_height_m)
        if joint == "inside_corner" and _tee(p, lab, A, B, (p0, u), (t0, t1), reach):
            joint = "fillet"  # a plate's edge on another's face (a gusset on a wall): a T, not a corner
        support = int(ca[s0:s1].sum() + cb[s0:s1].sum())
        out.append(SeamCurve("linear", joint, pts, np.tile(A.normal, (2, 1)), np.tile(B.normal, (2, 1)),
                             (A.label, B.label), support, max(A.rms_m, B.rms_m)))  # fmt: skip
    return out


def _upper_plate(p: FloatArray, lab: NDArray[np.int32], pairs: tuple[Pair, ...], A: Surface, B: Surface,
                 up: FloatArray | None, support: frozenset[int]) -> bool:  # fmt: skip
    """Whether the standing face of a lap fold between ``A`` and ``B`` is an edge face: beside it lies another
    surface whose points there stand off the lying face by at least half the standing face's height, on its
    side (the upper plate's top). A narrow face at a part's free edge (a lip, a rolled rim, the sensor's
    curl where the part ends) has nothing beyond it: no plate lies on the lower one there."""
    S, L = _standing_lying(A, B, CAMERA_DOWN if up is None else up)
    q = p[lab == S.label]
    q = q[np.isfinite(q[:, 2])]
    if len(q) == 0:
        return False
    height = float(percentile(L.residual(q), 98))
    for pair in pairs:
        if S.label not in (pair.a, pair.b) or L.label in (pair.a, pair.b):
            continue
        other = pair.b if pair.a == S.label else pair.a
        pa, pb = contact_points(p, lab, pair)
        top = pb if pair.a == S.label else pa
        if other not in support and len(top) >= 5 and float(median(L.residual(top))) >= 0.5 * height:
            return True
    return False


def _tee(p: FloatArray, lab: NDArray[np.int32], A: Surface, B: Surface, line: tuple[FloatArray, FloatArray],
         span: tuple[float, float], margin_m: float) -> bool:  # fmt: skip
    """Whether, beside the seam (its points' projections on the ``line`` (p0, u) within ``span``), one face goes
    on past the other's plane, beyond ``margin_m`` on both sides of it (twenty points or more each side): the
    other plate stands on it with its edge, a T-joint (a gusset near a wall's end has a strip of the wall beyond
    it). At a corner joint both plates end at the fold, each face on one side of the other's plane (a wall
    rising above the one butted against it shows its face past that one's plane only above the seam's end)."""
    for face, other in ((A, B), (B, A)):
        q = p[lab == face.label]
        t = (q - line[0]) @ line[1]
        r = other.residual(q[(t >= span[0]) & (t <= span[1])])
        if (r > margin_m).sum() >= MIN_TEE_POINTS and (r < -margin_m).sum() >= MIN_TEE_POINTS:
            return True
    return False


def _window_points(p: FloatArray, lab: NDArray[np.int32], labels: tuple[int, int], contact_px: NDArray[np.int64],
                   margin_px: float) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """The (N, 3) points of each of the two surfaces ``labels`` in the box of the contact pixels grown by
    ``margin_px``."""
    h, w = lab.shape
    m = int(np.ceil(margin_px))
    y0, x0 = np.maximum(contact_px.min(axis=0) - m, 0)
    y1, x1 = np.minimum(contact_px.max(axis=0) + m + 1, (h, w))
    sub_l, sub_p = lab[y0:y1, x0:x1], p[y0:y1, x0:x1]
    out = []
    for k in labels:
        q = sub_p[sub_l == k]
        out.append(q[np.isfinite(q[:, 2])])
    return out[0], out[1]


def local_turn(qa: FloatArray, qb: FloatArray, p0: FloatArray, u: FloatArray, m: FloatArray,
               span: tuple[float, float], half_width_m: float, *, min_points: int = 10) -> float | None:
    """The angle (radians) between planes fitted to each side's points ``qa``, ``qb`` within ``half_width_m``
    of the line ``p0 + t u`` (along ``span`` of it; across it, square to ``u`` and to ``m``, the faces'
    bisecting normal): how far the surfaces turn at the line itself. Two fitted facets of a smoothly bent
    panel turn by the angle between their far-apart middles, but at the line where they meet the panel hardly
    turns; a fold, however blurred, turns there by its whole angle. None when either side has fewer than
    ``min_points`` there."""
    across = cross3(u, m)
    across /= max(float(np.linalg.norm(across)), 1e-12)
    normals = []
    for q in (qa, qb):
        d = q - p0
        t, s = d @ u, d @ across
        k = (np.abs(s) <= half_width_m) & (t >= span[0]) & (t <= span[1])
        if k.sum() < min_points:
            return None
        r = q[k] - mean_rows(q[k])
        normals.append(np.linalg.eigh(r.T @ r)[1][:, 0])
    return float(np.arccos(min(abs(float(normals[0] @ normals[1])), 1.0)))


def _standing_height(p: FloatArray, lab: NDArray[np.int32], A: Surface, B: Surface, p0: FloatArray, u: FloatArray,
                     up: FloatArray) -> float:  # fmt: skip
    """How far the more upright of the two faces reaches from the fold (98th percentile of its points)."""
    S, _ = _standing_lying(A, B, up)
    mine = lab == S.label
    q = p[mine]
    q = q[np.isfinite(q[:, 2])][:: max(1, int(np.count_nonzero(mine)) // 3000)]
    if len(q) == 0:
        return 0.0
    _, d = line_coords(q, p0, u)
    return float(percentile(d, 98))


def _standing_lying(A: Surface, B: Surface, up: FloatArray) -> tuple[Surface, Surface]:
    """The more upright of the two faces (relative to ``up``) and the other."""
    return (A, B) if abs(float(A.normal @ up)) < abs(float(B.normal @ up)) else (B, A)


def line_coords(q: FloatArray, p0: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Position along and distance from the line p0 + t u of (N, 3) points."""
    d = q - p0
    t = d @ u
    return t, np.sqrt(np.maximum((d * d).sum(axis=1) - t * t, 0.0))


def ring_points(P: Surface, C: Surface, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Points where the cylinder's rulings at angles ``theta`` meet the plane, and the radial unit normals."""
    a = C.axis
    e1, e2 = axis_basis(a)
    radial = np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2
    q = C.centre + C.radius * radial
    t = -(q @ P.normal + P.offset) / float(P.normal @ a)
    return q + t[:, None] * a, radial


def _plane_cylinder(P: Surface, C: Surface, pp: FloatArray, pc: FloatArray, plate: FloatArray, noise: NoiseModel,
                    fp: FoldParams) -> list[SeamCurve]:  # fmt: skip
    """The ring where cylinder ``C`` stands on plane ``P`` (``pp``, ``pc``: their points at the contact;
    ``plate``: the plane's points, or a sample of them), clipped to where both have points along it; none
    unless the fold is concave, the cylinder stands square to the plane, and the plane is not a strip of the
    cylinder's own surface."""
    if abs(float(P.normal @ C.axis)) < np.cos(np.radians(30.0)):
        return []  # only a cylinder standing on the plane (a pipe on a plate) makes a ring
    z = float(median(np.vstack([pp, pc])[:, 2]))
    sig = float(noise.sigma_m(z))
    reach = fp.near_m + 3.0 * sig + 3.0 * float(noise.spacing_m(z))
    # concave: the plate's points are not inside the cylinder (at its foot they lie on it, within the noise
    # and the radius's own error: a pipe fitted on a few hundred pixels at 0.8 m reads a millimetre wide; a cap
    # on a pipe lies a radius inside), and the cylinder's stand above the plate
    if median(C.residual(pp)) <= -fp.concave_sigma * sig or median(P.residual(pc)) < fp.concave_sigma * sig:
        return []
    # nor a strip of the cylinder itself: near a rim seen at a slant (a wheel, a ring, a tube's end) the local
    # normals bend and the fold cuts part a band of the cylinder off, a planar arc square to its axis, which the
    # cylinder then stands "on" (all of its points lie on the cylinder; a plate's reach out from the foot)
    if float(np.mean(np.abs(C.residual(plate)) <= 3.0 * sig)) > ON_CYLINDER_SHARE:
        return []
    n_bins = max(36, int(np.ceil(2 * np.pi * C.radius / fp.bin_m)))
    theta = (np.arange(n_bins) + 0.5) * 2 * np.pi / n_bins
    ring, radial = ring_points(P, C, theta)
    from scipy.spatial import cKDTree

    tree = cKDTree(ring)
    cover = []
    for q in (pp, pc):
        d, k = tree.query(q)
        cover.append(np.bincount(k[d <= reach], minlength=n_bins))
    out: list[SeamCurve] = []
    for s0, s1 in covered_runs((cover[0] > 0) & (cover[1] > 0), int(fp.max_hole_m / fp.bin_m), closed=True):
        idx = np.arange(s0, s1 + (1 if s1 - s0 == n_bins else 0)) % n_bins
        if len(idx) * 2 * np.pi * C.radius / n_bins < fp.min_length_m:
            continue
        pts = ring[idx]
        nrm_c = radial[idx]
        out.append(SeamCurve("curved", "fillet", pts, np.tile(P.normal, (len(idx), 1)), nrm_c, (P.label, C.label),
                             int(cover[0][idx].sum() + cover[1][idx].sum()), max(P.rms_m, C.rms_m)))  # fmt: skip
    return out


def radial_normals(C: Surface, x: FloatArray) -> FloatArray:
    """(N, 3) outward unit normals of cylinder ``C`` at the (N, 3) points ``x`` (square to its axis)."""
    d = x - C.centre
    w = d - np.outer(d @ C.axis, C.axis)
    return np.asarray(w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12))


def saddle_points(S: Surface, L: Surface, theta: FloatArray) -> list[FloatArray]:
    """Where the rulings of cylinder ``S`` at angles ``theta`` (round its axis, from
    :func:`perception.fine.cylinder.axis_basis`) meet cylinder ``L``: the two curves in which a branch pipe
    meets a main pipe (it enters on one side and may leave on the other), each (len(theta), 3) with NaN where
    the ruling misses ``L``. Empty when the axes are parallel (the pipes lie side by side, or one within
    the other: no branch joint)."""
    e1, e2 = axis_basis(S.axis)
    base = S.centre + S.radius * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2)
    v = S.axis - float(S.axis @ L.axis) * L.axis  # the ruling's direction square to L's axis
    vv = float(v @ v)
    if vv < 1e-6:
        return []
    d = base - L.centre
    w0 = d - np.outer(d @ L.axis, L.axis)
    b = w0 @ v
    disc = b * b - vv * ((w0 * w0).sum(axis=1) - L.radius**2)
    root = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
    return [base + ((-b + sign * root) / vv)[:, None] * S.axis for sign in (-1.0, 1.0)]


def _cylinder_pair(A: Surface, B: Surface, pa: FloatArray, pb: FloatArray, noise: NoiseModel,
                   fp: FoldParams) -> list[SeamCurve]:  # fmt: skip
    """The concave saddle curves where two pipes meet (a branch on a main pipe), clipped to both supports:
    traced round the narrower pipe, whose every ruling crosses the wider one once on each curve."""
    z = float(median(np.vstack([pa, pb])[:, 2]))
    sig = float(noise.sigma_m(z))
    reach = fp.near_m + 3.0 * sig + 3.0 * float(noise.spacing_m(z))
    # concave: each pipe's points beside the joint lie outside the other (a ridge has them inside)
    ra, rb = B.residual(pa), A.residual(pb)
    if min(float(median(ra)), float(median(rb))) <= 0.0:
        return []
    if max(percentile(ra, 75), percentile(rb, 75)) < fp.concave_sigma * sig:
        return []
    S, L = (A, B) if A.radius <= B.radius else (B, A)
    n_bins = max(36, int(np.ceil(2 * np.pi * S.radius / fp.bin_m)))
    theta = (np.arange(n_bins) + 0.5) * 2 * np.pi / n_bins
    from scipy.spatial import cKDTree

    out: list[SeamCurve] = []
    for curve in saddle_points(S, L, theta):
        ok = np.flatnonzero(np.isfinite(curve[:, 0]))
        if len(ok) < 2:
            continue
        tree = cKDTree(curve[ok])
        cover = []
        for q in (pa, pb):
            d, k = tree.query(q)
            cover.append(np.bincount(ok[k[d <= reach]], minlength=n_bins))
        for s0, s1 in covered_runs((cover[0] > 0) & (cover[1] > 0), int(fp.max_hole_m / fp.bin_m), closed=True):
            idx = np.arange(s0, s1 + (1 if s1 - s0 == n_bins else 0)) % n_bins
            pts = curve[idx]
            if not np.isfinite(pts).all() or np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() < fp.min_length_m:
                continue
            na, nb = radial_normals(A, pts), radial_normals(B, pts)
            if float(median(np.arccos(np.clip(np.abs((na * nb).sum(axis=1)), 0.0, 1.0)))) < fp.min_turn_rad:
                continue  # the pipes barely turn from each other there: no fold to weld
            out.append(SeamCurve("curved", "fillet", pts, na, nb, (A.label, B.label),
                                 int(cover[0][idx].sum() + cover[1][idx].sum()), max(A.rms_m, B.rms_m)))  # fmt: skip
    return out
