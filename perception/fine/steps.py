"""Steps and laps: an upper plate lying on a lower one, its edge face too narrow to be a surface of its own.

Two parallel planes, the upper one a plate thickness (``min_step_m`` to ``max_step_m``) nearer the camera,
meet in the image along the upper plate's edge. The edge face of a cut plate is square to it, so the seam is
the upper plate's edge dropped onto the lower plate along its normal. The upper plate's contact is split
into its straight edges (a pad has four), each a step of its own. At full resolution the edge is placed by the
points on the edge face itself (between the two planes); where the plates lie so near that their noise bands
overlap (three to seven sigma apart), by where the points turn from the upper plate's side of the middle to
the lower's, and only as a clean step. The seam is kept only where the edge face is seen (the camera on its
outer side, at under 75 degrees), as for every other joint, and where the lower plate is seen beside the edge
as densely as the upper plate inside it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.fine.adjacency import REACH_M
from perception.fine.folds import contact_points
from perception.fine.lines import best_line
from perception.fine.parallel import COHERENT_APART
from perception.fine.runs import covered_runs
from perception.fine.types import FloatArray, Joint, NoiseModel, Pair, SeamCurve, Surface, SurfaceSet
from perception.fits import cross3, median, outer_boundary, percentile, trimmed_line


@dataclass(frozen=True)
class StepParams:
    max_angle_rad: float = np.radians(3.0)
    min_step_m: float = 0.0025
    max_step_m: float = 0.030
    bin_m: float = 0.002
    min_length_m: float = 0.020
    band_m: float = 0.012
    max_incidence_rad: float = np.radians(75.0)
    on_plane_sigma: float = 3.5  # a full-resolution point is on a plate within this many sigma of its plane


def step_seams(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    pairs: tuple[Pair, ...],
    noise: NoiseModel,
    full: NDArray[np.float32],
    intr: CameraIntrinsics,
    noise_full: NoiseModel,
    *,
    support: frozenset[int],
    params: StepParams | None = None,
    read: NDArray[np.bool_] | None = None,
) -> list[SeamCurve]:
    """Laps and steps between nearly parallel plates at a plate's thickness apart (neither in ``support``).
    ``read``, when given, (H, W): the full-resolution pixels read are marked in it."""
    sp = params or StepParams()
    p = np.asarray(points, dtype=np.float64)
    lab = surfaces.labels
    out: list[SeamCurve] = []
    for pair in pairs:
        A, B = surfaces.surfaces[pair.a], surfaces.surfaces[pair.b]
        if A.kind != "plane" or B.kind != "plane" or float(A.normal @ B.normal) < np.cos(sp.max_angle_rad):
            continue
        pa, pb = contact_points(p, lab, pair)
        if len(pa) < 10 or len(pb) < 10:
            continue
        # upper: the plane on the camera side of the other by a plate's thickness
        h_ab = float(median(B.residual(pa)))  # A's points above B
        if sp.min_step_m <= h_ab <= sp.max_step_m:
            up, low, pu, h = A, B, pa, h_ab
        elif sp.min_step_m <= -h_ab <= sp.max_step_m:
            up, low, pu, h = B, A, pb, -h_ab
        else:
            continue
        if up.label in support or low.label in support:
            continue  # a plate lying on the table is not lapped onto it
        # the points are told apart as on the upper or the lower plate within on_plane_sigma of each plane, at
        # most half the step: planes under three sigma apart cannot be told apart (a ghost layer of mixed
        # pixels along an edge; two plates split from one surface only when they lie three sigma apart)
        z = float(median(pu[:, 2]))
        if h < COHERENT_APART * float(noise.sigma_m(z)):
            continue
        runs = _edge_runs(pu, low.normal, 3.0 * float(noise.spacing_m(z)))
        for run in runs:
            # the upper plate lies inside each of its edges (a lap's one, a pad's sides). Not the lower plate's
            # contact: it lies under the edge, a plate's thickness down, and beside it by the noise alone
            outward = 2.0 * pu[run].mean(axis=0) - up.centroid
            seam = _step_along(pu[run], outward, up, low, h, full, intr, noise_full, sp, read)
            if seam is not None and not any(_same_line(seam, o) for o in out):
                out.append(seam)
    return out


def _step_along(pu: FloatArray, outward: FloatArray, up: Surface, low: Surface, h: float,
                full: NDArray[np.float32], intr: CameraIntrinsics, noise_full: NoiseModel, sp: StepParams,
                read: NDArray[np.bool_] | None) -> SeamCurve | None:  # fmt: skip
    """The step's seam along one straight edge of the upper plate, from its contact points ``pu`` (``outward``:
    a point on the lower plate's side of the edge); None where the edge face is not seen or the plates are not
    both there along it."""
    n = low.normal
    c, u = _edge_axis(pu, n)
    across = cross3(n, u)
    if float((outward - c) @ across) < 0:
        across = -across  # from the upper plate towards the lower one
    # the edge face is seen when the camera is on its outer side at under 75 degrees (somewhere along it: the
    # view turns along a long edge; the view clip keeps the stretch where it is seen); where it is not (a lap
    # seen from above, or from the upper plate's side), the upper plate's boundary places the edge
    view = -pu / np.linalg.norm(pu, axis=1, keepdims=True)
    face_seen = float(np.max(view @ across)) >= np.cos(sp.max_incidence_rad)
    if not face_seen:
        # the seam is the edge face's foot: seen from the upper plate's side, the face hides it and a strip of
        # the lower plate beside it (an occluding edge, a plate's rim over what lies beyond); it is placed by
        # the boundary only where that strip is under a sample spacing wide (the face seen edge-on)
        hidden = h * np.maximum(-(view @ across), 0.0) / np.maximum(view @ n, 1e-6)
        if float(median(hidden)) > float(noise_full.spacing_m(float(median(pu[:, 2])))):
            return None
    tu = (pu - c) @ u
    edge = _edge_offset(full, intr, noise_full, up, low, c, u, across, h, sp,
                        span=(float(tu.min()) - 0.01, float(tu.max()) + 0.01), read=read,
                        boundary=not face_seen)  # fmt: skip
    if edge is None:
        return None
    off, slope, t_lo, t_hi, n_pts, low_offset = edge
    if t_hi - t_lo < sp.min_length_m:
        return None
    pts = np.array([c + t * u + (off + slope * t) * across for t in (t_lo, t_hi)])
    pts = pts - np.outer(pts @ n + low_offset, n)  # dropped onto the lower plate
    joint: Joint = "lap" if h <= 0.014 else "fillet"
    return SeamCurve("linear", joint, pts, np.tile(low.normal, (2, 1)), np.tile(across, (2, 1)),
                     (low.label, up.label), n_pts, max(up.rms_m, low.rms_m),
                     from_boundary=not face_seen)  # fmt: skip


def _same_line(a: SeamCurve, b: SeamCurve, *, within_m: float = 0.002) -> bool:
    """Whether straight seam ``a``'s ends and middle lie within ``within_m`` of straight seam ``b``'s line (two
    runs of one edge's contact place the same step)."""
    p0, p1 = b.points[0], b.points[-1]
    u = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-12)
    probe = np.vstack([a.points[0], 0.5 * (a.points[0] + a.points[-1]), a.points[-1]]) - p0
    return bool(np.all(np.linalg.norm(probe - np.outer(probe @ u, u), axis=1) <= within_m))


def _edge_runs(pu: FloatArray, n: FloatArray, tol_m: float, *, min_points: int = 10, max_runs: int = 4,
               trials: int = 200) -> list[NDArray[np.intp]]:  # fmt: skip
    """The contact points ``pu`` of an upper plate split into its straight edges (lines in the plane of normal
    ``n``, RANSAC on point pairs, ``tol_m`` wide), at most ``max_runs``: when the best line holds nine in ten
    (a lap's edge), the contact band along it as one run (a blob of contact at a plate's far corner would
    turn and move the edge fitted through it)."""
    rng = np.random.default_rng(0)
    left = np.arange(len(pu))
    runs: list[NDArray[np.intp]] = []
    while len(left) >= min_points and len(runs) < max_runs:
        q = pu[left]
        i = rng.integers(0, len(q), (trials, 2))
        d = q[i[:, 1]] - q[i[:, 0]]
        d -= np.outer(d @ n, n)
        ln = np.linalg.norm(d, axis=1)
        ok = ln > 4.0 * tol_m
        if not ok.any():
            break
        across = np.cross(n, d[ok] / ln[ok, None])
        inl = best_line(across, np.sum(q[i[ok, 0]] * across, axis=1), np.ascontiguousarray(q.T), tol_m)
        if inl.sum() < min_points:
            break
        if not runs and inl.mean() >= 0.9:
            # a lap's edge: the contact band along its line (two adjacency reaches wide), not another contact
            # of the same plates far from it (a blob at a plate's far corner)
            return [left[_within_band(q, n, inl, 2.0 * REACH_M)]]
        runs.append(left[inl])
        left = left[~inl]
    return runs or [np.arange(len(pu))]


def _edge_axis(p: FloatArray, n: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The centroid of (N, 3) points ``p`` and the unit direction they spread most along in the plane of
    normal ``n`` (their least-squares line there)."""
    c = p.mean(axis=0)
    d = p - c
    d_in = d - np.outer(d @ n, n)
    _, v = np.linalg.eigh(d_in.T @ d_in / len(d_in))
    return c, v[:, 2]


def _within_band(q: FloatArray, n: FloatArray, on_line: NDArray[np.bool_], width_m: float) -> NDArray[np.bool_]:
    """The points of ``q`` within ``width_m`` of the least-squares line (in the plane of normal ``n``) through
    the points ``on_line``."""
    c, u = _edge_axis(q[on_line], n)
    r = q - c
    r -= np.outer(r @ n, n)
    return np.asarray(np.linalg.norm(r - np.outer(r @ u, u), axis=1) <= width_m)


def _edge_offset(full: NDArray[np.float32], intr: CameraIntrinsics, noise: NoiseModel, up: Surface, low: Surface,
                 c: FloatArray, u: FloatArray, across: FloatArray, h: float, sp: StepParams, *,
                 span: tuple[float, float],
                 read: NDArray[np.bool_] | None = None,
                 boundary: bool = False,
                 ) -> tuple[float, float, float, float, int, float] | None:  # fmt: skip
    """Where the upper plate's edge face stands (offset along ``across`` from ``c``: ``off + slope * t``), the
    stretch along ``u`` over which both plates are there, the count of points that place it, and the lower
    plate's offset beside it (:func:`_low_offset`), from full-resolution points near the edge. ``boundary``:
    the edge face is not seen, and the upper plate's boundary places the edge (:func:`_boundary_line`)."""
    from perception.fine.refine import near_points

    # a box around the contact, grown along the edge: the work image's contact decides the search band
    seg = np.array([c + span[0] * u, c + span[1] * u])
    q = near_points(full, intr, seg, sp.band_m, read=read)
    if len(q) < 30:
        return None
    d = q - c
    a_off, t = d @ across, d @ u
    near = np.abs(a_off) <= sp.band_m
    q, a_off, t = q[near], a_off[near], t[near]
    sig = noise.sigma_m(q[:, 2])
    r_low = q @ low.normal + low.offset
    r_up = q @ up.normal + up.offset
    band = np.minimum(sp.on_plane_sigma * sig, 0.5 * h)
    on_up = np.abs(r_up) <= band
    on_low = np.abs(r_low) <= band
    on_face = (r_low > 0.3 * h) & (r_low < 0.7 * h) & ~on_up
    if on_up.sum() < 10 or on_low.sum() < 10:
        return None
    # along the edge: where the upper plate's points near the edge and the lower plate's beside it both are.
    # Plates nearer than both bands are told apart only on average: the edge is where the points turn from
    # the upper plate's side of the middle to the lower's (a few of the lower plate's points lie within the
    # upper's band, and its outermost points would be theirs)
    close = bool(np.any(band < sp.on_plane_sigma * sig))
    if boundary and close:
        return None  # plates within each other's noise bands, and no edge face: nothing tells the step apart
    edge_up = _crossing(a_off, r_low > 0.5 * h) if close else float(percentile(a_off[on_up], 98))
    near_up = on_up & (a_off > edge_up - 0.004)
    near_low = on_low & (a_off > edge_up) & (a_off < edge_up + 0.008)
    if not near_up.any() or not near_low.any():
        return None  # the lower plate is not seen beside the edge: no step to place
    # parallel plates are sampled alike: the lower one's 8 mm band beside the edge holds at least as many points
    # as the upper one's 4 mm inside it (a far face seen past a near one's edge shows in a sliver)
    if near_low.sum() < near_up.sum():
        return None
    both = _both_plates_along(t, near_up, near_low, sp.bin_m)
    if both is None:
        return None
    t_lo, t_hi = both
    face = on_face & (t >= t_lo) & (t <= t_hi)
    slope = 0.0
    if boundary:
        line = _boundary_edge(a_off, t, on_up, on_low, (t_lo, t_hi), edge_up,
                              float(median(noise.spacing_m(q[:, 2]))), float(median(sig)), sp.bin_m)  # fmt: skip
        if line is None:
            return None
        off, slope = line
    elif close:
        # the face's points are not told from either plate's noise: the crossing, found along the edge in
        # pieces, places and turns it
        off, slope = _crossing_line(a_off, t, r_low > 0.5 * h, (t_lo, t_hi), edge_up, sp.band_m)
        # and only a clean step is taken so: the upper plate all across the band's half on its side and the
        # lower plate on the other (a ghost layer of mixed pixels along a face is a strip, not a plate)
        if not _clean_step(a_off - (off + slope * t), r_low > 0.5 * h, (t >= t_lo) & (t <= t_hi), sp.band_m):
            return None
    elif face.sum() >= 20 and np.ptp(t[face]) > 0.5 * (t_hi - t_lo):
        off, slope = trimmed_line(t[face], a_off[face])  # the edge face's own points place it, and turn it
    elif face.sum() >= 10:
        off = float(median(a_off[face]))
    else:
        # no edge face between the plates: the upper one's edge stands over a depth jump (a near face over a
        # parallel one further off, the top of the near one's edge seen), not on the lower plate
        return None
    beside = on_low & (t >= t_lo) & (t <= t_hi)
    beside &= a_off - (off + slope * t) > 3.0 * sig + noise.spacing_m(q[:, 2])
    return off, slope, t_lo, t_hi, int(near_up.sum() + near_low.sum()), _low_offset(q[beside], low)


def _both_plates_along(t: FloatArray, near_up: NDArray[np.bool_], near_low: NDArray[np.bool_],
                       bin_m: float) -> tuple[float, float] | None:  # fmt: skip
    """The stretch along the edge (positions ``t``) over which the upper plate's points near it
    (``near_up``) and the lower plate's beside it (``near_low``) both are: the longest run of ``bin_m`` bins
    holding two of each, ended at the outermost points of both plates inside it (not its bins' edges, up to a
    bin beyond them); None when no run is four bins long."""
    lo, hi = float(min(t[near_up].min(), t[near_low].min())), float(max(t[near_up].max(), t[near_low].max()))
    nb = max(1, int(np.ceil((hi - lo) / bin_m)))

    def cover(m: NDArray[np.bool_]) -> NDArray[np.bool_]:
        return np.bincount(np.clip(((t[m] - lo) / bin_m).astype(int), 0, nb - 1), minlength=nb) >= 2

    runs = covered_runs(cover(near_up) & cover(near_low), 4)
    if not runs:
        return None
    r0, r1 = max(runs, key=lambda r: r[1] - r[0])
    inside = (t >= lo + r0 * bin_m) & (t <= lo + r1 * bin_m)
    t_lo = max(float(t[near_up & inside].min()), float(t[near_low & inside].min()))
    t_hi = min(float(t[near_up & inside].max()), float(t[near_low & inside].max()))
    return t_lo, t_hi


def _boundary_edge(a_off: FloatArray, t: FloatArray, on_up: NDArray[np.bool_], on_low: NDArray[np.bool_],
                   span: tuple[float, float], edge_up: float, spacing: float, sigma: float,
                   bin_m: float) -> tuple[float, float] | None:  # fmt: skip
    """The edge of an upper plate whose edge face is not seen, as ``(off, slope)`` across it: its boundary
    (:func:`_boundary_line`), taken only where the foot is seen: the lower plate's points come up to the edge
    (within two samples and the noise ``sigma``) along most of it, as beside a plate's cut edge seen edge-on; a
    parallel fragment beyond a ragged rim, or a surface further off under an overhang, starts further out."""
    line = _boundary_line(a_off[on_up], t[on_up], span, edge_up, spacing, bin_m, spacing + sigma)
    if line is None:
        return None
    off, slope = line
    if not _foot_seen(a_off[on_low] - (off + slope * t[on_low]), t[on_low], span, bin_m, 2.0 * spacing + sigma):
        return None
    return off, slope


def _low_offset(q: FloatArray, low: Surface) -> float:
    """The lower plate's offset where the seam lies on it: its plane (fitted on the whole plate, at the work
    resolution) moved to the median of its full-resolution points ``q`` beside the edge (clear of the edge
    face's base by its rounding). Often all that is seen of a lap's lower plate is a strip beside the upper one,
    seen obliquely: the whole plate's fit tilts on it by up to 2 degrees and lies 0.5-1.2 mm off at the seam,
    while the strip's own points place it there within their noise. The normal stays the whole plate's (a
    strip a centimetre wide turns a plane fitted on it alone more than it helps)."""
    if len(q) < 30:
        return low.offset
    return low.offset - float(median(q @ low.normal + low.offset))


def _crossing(a_off: FloatArray, upper: NDArray[np.bool_]) -> float:
    """The offset ``e`` that best parts the points into the upper plate's (``a_off`` < e) and the lower's: the
    fewest points on the wrong side of it."""
    order = np.argsort(a_off)
    up = upper[order].astype(np.int64)
    # wrong if e lies after k points: the lower ones among the first k and the upper ones after them
    wrong = np.concatenate([[0], np.cumsum(1 - up)]) + (int(up.sum()) - np.concatenate([[0], np.cumsum(up)]))
    k = int(np.argmin(wrong))
    a = a_off[order]
    if k == 0:
        return float(a[0])
    if k == len(a):
        return float(a[-1])
    return 0.5 * float(a[k - 1] + a[k])


def _boundary_line(a_up: FloatArray, t_up: FloatArray, span: tuple[float, float], edge: float, spacing_m: float,
                   bin_m: float, tol_m: float) -> tuple[float, float] | None:  # fmt: skip
    """The upper plate's edge as a line ``a_off = off + slope * t`` from its own points (``a_up`` across the
    edge, ``t_up`` along it) when its edge face is not seen: the boundary (:func:`perception.fits.outer_boundary`)
    of its points in the ``span`` within a centimetre of ``edge``, moved out by half the sample spacing (the
    edge lies between the last sample on the plate and the next one, which is off it). None when fewer than
    five bins hold points, or the outermost points scatter about the line by more than ``tol_m``: a ragged rim
    is not a plate's cut edge."""
    near = (np.abs(a_up - edge) <= 0.01) & (t_up >= span[0]) & (t_up <= span[1])
    line = outer_boundary(t_up[near], a_up[near], bin_m, tol_m, origin=span[0])
    if line is None:
        return None
    return line[0] + 0.5 * spacing_m, line[1]


def _foot_seen(a_rel: FloatArray, t_low: FloatArray, span: tuple[float, float], bin_m: float, reach_m: float,
               share: float = 0.6) -> bool:  # fmt: skip
    """Whether in ``share`` of the ``bin_m`` bins of ``span`` that hold lower-plate points beyond the edge
    (``a_rel`` > 0, within a centimetre), the nearest of them lies within ``reach_m`` of it."""
    beyond = (a_rel > 0) & (a_rel <= 0.01) & (t_low >= span[0]) & (t_low <= span[1])
    if beyond.sum() < 10:
        return False
    k = ((t_low[beyond] - span[0]) / bin_m).astype(np.int64)
    nearest = np.full(int(k.max()) + 1, np.inf)
    np.minimum.at(nearest, k, a_rel[beyond])
    held = np.isfinite(nearest)
    return bool(np.mean(nearest[held] <= reach_m) >= share)


def _clean_step(a_rel: FloatArray, upper: NDArray[np.bool_], along: NDArray[np.bool_], band_m: float,
                share: float = 0.8) -> bool:  # fmt: skip
    """Whether the points ``along`` the edge beyond half the band on the upper side of it (``a_rel`` < 0) are
    ``share`` or more on the upper plate, and those beyond half the band on the other side on the lower."""
    up_side, low_side = along & (a_rel < -0.5 * band_m), along & (a_rel > 0.5 * band_m)
    if up_side.sum() < 10 or low_side.sum() < 10:
        return False
    return float(upper[up_side].mean()) >= share and float((~upper[low_side]).mean()) >= share


def _crossing_line(a_off: FloatArray, t: FloatArray, upper: NDArray[np.bool_], span: tuple[float, float],
                   edge: float, band_m: float) -> tuple[float, float]:  # fmt: skip
    """The edge as a line ``a_off = off + slope * t``: the crossing (:func:`_crossing`) in pieces of the
    ``span`` about ``band_m`` long (at least three), each within ``band_m`` of ``edge``; fitted by least squares
    on the pieces' crossings (weighted by their points). ``(edge, 0)`` when fewer than three pieces hold points
    on both sides."""
    pieces = max(3, int((span[1] - span[0]) / band_m))
    bounds = np.linspace(span[0], span[1], pieces + 1)
    near = np.abs(a_off - edge) <= band_m
    tc, ec, wc = [], [], []
    for t0, t1 in itertools.pairwise(bounds):
        m = near & (t >= t0) & (t < t1)
        if upper[m].sum() < 10 or (~upper[m]).sum() < 10:
            continue
        tc.append(0.5 * (t0 + t1))
        ec.append(_crossing(a_off[m], upper[m]))
        wc.append(float(m.sum()))
    if len(tc) < 3:
        return edge, 0.0
    w = np.sqrt(np.asarray(wc))
    sol, *_ = np.linalg.lstsq(np.column_stack([np.ones(len(tc)), tc]) * w[:, None], np.asarray(ec) * w, rcond=None)
    return float(sol[0]), float(sol[1])
