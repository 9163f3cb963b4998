"""Folds between wide planes, for a sensor whose error grows with the scale it is seen at.

A swept LiDAR draws each face in layers of scan lines a few millimetres apart and rounds its corners over
20-40 mm; seen through its range image the faces break into fragments a few dozen pixels wide, and their folds
land inside the rounding, 10-20 mm off the corner, or nowhere. The measured structured error (the noise model's
``structure_1m_m``, :func:`perception.fine.noise.structured_error`) says when a capture is such a one: when it
is twice the noise model's own sigma or more (2.1-2.8 on thillRobot's plate scans; 0.1-0.56 on the zoo's stereo
model) and parts stand on a table, the faces are found again as wide planes, fitted within 4 sigma_wide (the
noise seen at the scale of a face, sqrt(sigma^2 + structure^2)) to the points off the support, one after
another (RANSAC, each plane its largest connected piece). A wide plane that lies on the table around it is the
table where the sensor bent it away from the support's pieces (its folds with what stands on the table are the
table's junctions). Two of them that turn by a fold's angle and meet concavely (each one's points near their
line lie on the camera side of the other, or on it: not behind it, as a convex edge's do) give a seam along
their intersection where both have points within the corner's rounding of it, each reaching well beyond the
rounding (a strip fitted across the rounding itself is no face). Parallel candidates within the rounding of
each other and overlapping are one seam: the strongest's, lengthened over the others' spans (a face standing
on a plate lying on the table meets both planes: the plate's, nearer, is the fold; a face the sensor bends
comes out as pieces, each with its stretch of the one fold).

Between 0.6 and twice the noise (thillRobot's table tees, 0.73-0.96: a LiDAR at a finer pitch, whose corners
the view's surfaces place, but whose few points near a corner come and go from one sampling to the next; and
a structured-light camera's bent panels, 1.1-1.5, which wide planes cut into facets) a wide fold only confirms
a fold the view's surfaces proposed along it (:func:`in_place_of_along`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.fine.folds import FoldParams, joint_type, line_coords
from perception.fine.support import table_around, table_sample
from perception.fine.types import FloatArray, NoiseModel, SeamCurve, SurfaceSet
from perception.fits import connected_components, fit_plane, median, percentile


@dataclass(frozen=True)
class WideFoldParams:
    min_structure: float = 2.0  # wide folds stand alone when the structured error is this many times the noise
    confirm_structure: float = 0.6  # from this many times, they only confirm folds the view's surfaces proposed
    tol_sigma: float = 4.0  # a point within this many sigma_wide of a wide plane lies on it
    reach_spacings: float = 10.0  # the corner's rounding: support within this many sample spacings of the line
    min_points: int = 60  # a wide plane holds at least this many of the sampled points
    max_planes: int = 25
    trials: int = 300
    sample: int = 12_000  # the points off the support are sampled down to this many
    score: int = 2_000  # RANSAC trials are scored on this many of them
    min_length_m: float = 0.020
    parallel_rad: float = float(np.radians(10.0))  # candidates this parallel and within the rounding are one

    def reach_m(self, noise: NoiseModel, z: float) -> float:
        """The corner's rounding at range ``z``: :attr:`reach_spacings` of the work image's sample spacing."""
        return self.reach_spacings * float(noise.spacing_m(z))


def _sigma_wide(noise: NoiseModel, z: float) -> float:
    """The noise at range ``z`` seen at the scale of a face: sqrt(sigma^2 + structure^2)."""
    return float(np.hypot(noise.sigma_m(z), noise.structure_1m_m * z * z))


@dataclass(frozen=True)
class WidePlane:
    """A plane fitted to points within ``tol_m`` of it: unit ``normal`` towards the camera, ``offset``
    (normal . p + offset = 0), its points (indices into the sample) and their centroid."""

    normal: FloatArray
    offset: float
    members: NDArray[np.int64]
    centroid: FloatArray


def wide_fold_seams(points: NDArray[np.floating], surfaces: SurfaceSet, noise: NoiseModel, *, support: frozenset[int],
                    params: WideFoldParams | None = None) -> list[SeamCurve]:  # fmt: skip
    """The folds between the wide planes of the (h, w, 3) work cloud ``points`` off the ``support``; none
    unless parts stand on a support (a table) and the capture's structured error (at 1 m) is at least
    :attr:`WideFoldParams.min_structure` times its noise model's sigma. A cloud of a part alone (a groove
    cropped out of a stereo camera's view, a bent panel, a tube) has no table to find the parts on, and
    its curved faces' own bending counts as structure at the wider planes' scale: wide planes would cut
    them into facets."""
    wp = params or WideFoldParams()
    structure_1m = noise.structure_1m_m
    if not support or structure_1m < wp.confirm_structure * noise.sigma_1m_m:
        return []
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lab = surfaces.labels.reshape(-1)
    idx = np.flatnonzero(np.isfinite(p[:, 2]) & ~np.isin(lab, sorted(support)))
    if len(idx) < 3 * wp.min_points:
        return []
    rng = np.random.default_rng(0)
    pick = idx[np.sort(rng.permutation(len(idx))[: wp.sample])]
    q = p[pick]
    z = float(np.median(q[:, 2]))
    sigma_wide = _sigma_wide(noise, z)
    # the sample's own spacing: the work image's, thinned by the sampling
    spacing = float(noise.spacing_m(z)) * float(np.sqrt(len(idx) / len(pick)))
    tol = wp.tol_sigma * sigma_wide
    planes = wide_planes(q, tol, 4.0 * spacing, wp, rng)
    up = surfaces.surfaces[min(support)].normal
    reach = wp.reach_m(noise, z)
    planes = _off_table(planes, q, table_sample(points, surfaces.labels, support, wp.sample), up, tol, 2.0 * reach,
                        wp)  # fmt: skip
    cands = []
    for i, a in enumerate(planes):
        for b in planes[i + 1 :]:
            found = _fold(q, a, b, reach, tol, wp)
            if found is not None:
                cands.append((len(a.members) + len(b.members), a, b, *found))
    out: list[SeamCurve] = []
    for _, a, b, ends, height in sorted(cands, key=lambda c: -c[0]):
        # a weaker candidate along a stronger one, overlapping it, is the same seam: it only lengthens it
        same = next((i for i, c in enumerate(out) if _along(ends, c.points, reach, wp.parallel_rad)), None)
        if same is not None:
            out[same] = _lengthened(out[same], ends)
            continue
        joint = joint_type(a.normal, b.normal, up, height, FoldParams().lap_height_m)
        labels = (_majority(lab[pick[a.members]]), _majority(lab[pick[b.members]]))
        out.append(SeamCurve("linear", joint, ends, np.tile(a.normal, (2, 1)), np.tile(b.normal, (2, 1)), labels,
                             len(a.members) + len(b.members), sigma_wide))  # fmt: skip
    return out


def wide_planes(q: FloatArray, tol_m: float, join_m: float, wp: WideFoldParams,
                rng: np.random.Generator) -> list[WidePlane]:  # fmt: skip
    """Planes found one after another in the (N, 3) points ``q``: the trial plane through three of them that
    holds the most of a sample within ``tol_m``, its points' largest piece joined at ``join_m``, refitted
    by least squares; until no plane holds :attr:`WideFoldParams.min_points`."""
    out: list[WidePlane] = []
    left = np.arange(len(q))
    while len(left) >= wp.min_points and len(out) < wp.max_planes:
        x = q[left]
        tri = rng.integers(0, len(x), (wp.trials, 3))
        n = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
        norm = np.linalg.norm(n, axis=1)
        ok = norm > 1e-12
        if not ok.any():
            break
        n, o = n[ok] / norm[ok, None], x[tri[ok, 0]]
        d = -np.einsum("tk,tk->t", n, o)
        score = x[rng.choice(len(x), min(wp.score, len(x)), replace=False)]
        best = int(np.argmax((np.abs(score @ n.T + d) <= tol_m).sum(axis=0)))
        on = left[np.abs(x @ n[best] + d[best]) <= tol_m]
        piece = on[_largest(connected_components(q[on], join_m))] if len(on) >= wp.min_points else on
        if len(piece) < wp.min_points:
            left = np.setdiff1d(left, on)  # no face here: these points are spent
            continue
        c, normal, _ = fit_plane(q[piece])
        normal = -normal if float(normal @ c) > 0 else normal
        out.append(WidePlane(normal, -float(normal @ c), piece, c))
        left = np.setdiff1d(left, piece)
    return out


def _off_table(planes: list[WidePlane], q: FloatArray, table: FloatArray, up: FloatArray, tol: float,
               radius: float, wp: WideFoldParams) -> list[WidePlane]:  # fmt: skip
    """``planes`` less those that are the table seen again: parallel to the support (within
    :attr:`WideFoldParams.parallel_rad` of its normal ``up``) and with their points within ``tol`` of the
    plane of the support's points ``table`` around them (within ``radius``,
    :func:`perception.fine.support.table_around`). The sensor bends the table across the scene, so that the
    support's segmented pieces leave out stretches of it, which the wide planes find again; their folds with
    what stands on the table are its junctions with the table. A plate lying on the table is its thickness
    above the table beside it."""
    from scipy.spatial import cKDTree

    if len(table) < wp.min_points:
        return planes
    tree = cKDTree(table)
    out = []
    for pl in planes:
        if abs(float(pl.normal @ up)) >= np.cos(wp.parallel_rad):
            x = q[pl.members[:: max(1, len(pl.members) // 200)]]
            local = table_around(tree, table, x, radius)
            if local is not None and float(median(np.abs((x - local[0]) @ local[1]))) <= tol:
                continue  # the table seen again
        out.append(pl)
    return out


def _largest(labels: NDArray[np.int64]) -> NDArray[np.bool_]:
    return np.asarray(labels == np.argmax(np.bincount(labels)))


def _fold(q: FloatArray, a: WidePlane, b: WidePlane, reach: float, tol: float,
          wp: WideFoldParams) -> tuple[FloatArray, float] | None:  # fmt: skip
    """Planes ``a`` and ``b``'s seam: its two ends and how far the narrower face reaches from it; None unless
    they turn by a fold's angle, meet concavely, both have points within ``reach`` of their line along
    ``min_length_m`` and both reach twice as far beyond it."""
    if abs(float(a.normal @ b.normal)) > np.cos(FoldParams().min_turn_rad):
        return None
    u = np.cross(a.normal, b.normal)
    u /= np.linalg.norm(u)
    mid = float(u @ (a.centroid + b.centroid)) / 2.0
    p0 = np.linalg.solve(np.array([a.normal, b.normal, u]), [-a.offset, -b.offset, mid])
    xa, xb = q[a.members], q[b.members]
    (ta, da), (tb, db) = line_coords(xa, p0, u), line_coords(xb, p0, u)
    na, nb = da <= reach, db <= reach
    if na.sum() < 10 or nb.sum() < 10:
        return None
    # concave: each face's points near the line lie on the camera side of the other's plane or on it (within
    # the planes' tolerance ``tol``: a face the sensor bends leans over its foot); a convex edge's lie behind
    if float(np.median(xb[nb] @ a.normal + a.offset)) < -tol or float(np.median(xa[na] @ b.normal + b.offset)) < -tol:
        return None
    lo = max(float(percentile(ta[na], 2)), float(percentile(tb[nb], 2)))
    hi = min(float(percentile(ta[na], 98)), float(percentile(tb[nb], 98)))
    if hi - lo < wp.min_length_m:
        return None
    span_a, span_b = (ta >= lo) & (ta <= hi), (tb >= lo) & (tb <= hi)
    if span_a.sum() < 5 or span_b.sum() < 5:
        return None
    # each a face: reaching well beyond the rounding (a strip fitted across the rounding itself does not)
    extent = min(float(percentile(da[span_a], 90)), float(percentile(db[span_b], 90)))
    if extent < 2.0 * reach:
        return None
    return np.array([p0 + lo * u, p0 + hi * u]), extent


def _along(ends: FloatArray, other: FloatArray, reach: float, parallel_rad: float) -> bool:
    """Whether segment ``ends`` and segment ``other`` are one seam: either runs along the other, or they are
    parallel, each end of ``ends`` within ``reach`` of ``other``'s line, and their spans along it overlap."""
    if runs_along(ends, other, reach, parallel_rad) or runs_along(other, ends, reach, parallel_rad):
        return True
    u = ends[-1] - ends[0]
    v = other[-1] - other[0]
    lv = float(np.linalg.norm(v))
    if abs(float(u @ v)) < np.cos(parallel_rad) * float(np.linalg.norm(u)) * lv:
        return False
    t, d = line_coords(ends, other[0], v / lv)
    return bool(d.max() < reach and t.max() > 0.0 and t.min() < lv)


def _lengthened(curve: SeamCurve, ends: FloatArray) -> SeamCurve:
    """``curve`` (a segment) lengthened along its line over the projection of segment ``ends``."""
    p0, v = curve.points[0], curve.points[-1] - curve.points[0]
    lv = float(np.linalg.norm(v))
    t = (ends - p0) @ (v / lv)
    lo, hi = min(0.0, float(t.min())), max(lv, float(t.max()))
    return replace(curve, points=np.array([p0 + lo * v / lv, p0 + hi * v / lv]))


def runs_along(curve: FloatArray, other: FloatArray, reach: float, parallel_rad: float) -> bool:
    """Whether the (N, 3) polyline ``curve`` runs along the segment from ``other``'s first point to its last:
    its chord within ``parallel_rad`` of that direction, its middle point within ``reach`` of that line and
    between its ends."""
    u = curve[-1] - curve[0]
    v = other[-1] - other[0]
    lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
    if lu < 1e-9 or lv < 1e-9 or abs(float(u @ v)) < np.cos(parallel_rad) * lu * lv:
        return False
    v = v / lv
    d = _middle(curve) - other[0]
    t = float(d @ v)
    return 0.0 <= t <= lv and float(np.linalg.norm(d - t * v)) < reach


def _middle(curve: FloatArray) -> FloatArray:
    """The point halfway along the (N, 3) polyline ``curve`` (by length: of a segment, its midpoint, not its
    second point)."""
    step = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    along = np.concatenate([[0.0], np.cumsum(step)])
    half = 0.5 * float(along[-1])
    k = min(int(np.searchsorted(along, half, side="right")) - 1, len(curve) - 2)
    f = (half - along[k]) / max(float(step[k]), 1e-12)
    return np.asarray(curve[k] + f * (curve[k + 1] - curve[k]))


def in_place_of_along(curves: list[SeamCurve], wide: list[SeamCurve], noise: NoiseModel, *, points: FloatArray,
                      proposed: list[SeamCurve] | tuple[SeamCurve, ...] = ()) -> list[SeamCurve]:  # fmt: skip
    """``curves`` with the wide planes' folds ``wide``. Where the structured error is
    :attr:`WideFoldParams.min_structure` times the noise or more, each wide fold stands in place of the seams
    that run along it within the corner's rounding (the view's fragments place a rounded corner's fold inside
    the rounding, 10-20 mm off). Below that (from :attr:`WideFoldParams.confirm_structure`: a LiDAR scanning
    at a fine pitch, whose corners the view's surfaces place but whose sparse points near a corner come and go
    from one sampling to the next), a wide fold only confirms a fold the view's surfaces ``proposed`` along it
    (a candidate before the refinement): the longest refined seam along it is lengthened over its span, up to
    the other seams the refinement found along it and only where the work cloud ``points`` show both its faces
    beside it and nothing standing in it (:func:`_open_ends`), and where the refinement held none, the wide
    fold is the seam. A wide fold nothing proposed (facets of a bent panel, which a structured-light camera's bending
    error also lets through) is dropped."""
    if not wide:
        return curves
    wp = WideFoldParams()
    z = float(median(np.concatenate([c.points[:, 2] for c in wide])))
    reach = wp.reach_m(noise, z)
    if noise.structure_1m_m >= wp.min_structure * noise.sigma_1m_m:
        kept = [c for c in curves if not any(runs_along(c.points, w.points, reach, wp.parallel_rad) for w in wide)]
        return kept + wide
    out = list(curves)
    flat = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cloud = flat[np.isfinite(flat[:, 2])]
    for w in wide:
        if not any(_along(p.points[[0, -1]], w.points, reach, wp.parallel_rad) for p in proposed):
            continue
        along = [i for i, c in enumerate(out) if c.kind == "linear" and runs_along(c.points, w.points, reach,
                                                                                   wp.parallel_rad)]  # fmt: skip
        if not along:
            out.append(w)
            continue
        longest = max(along, key=lambda i: float(np.linalg.norm(out[i].points[-1] - out[i].points[0])))
        others = [out[i] for i in along if i != longest]
        out[longest] = _lengthened(out[longest], _open_ends(out[longest], others, w.points, cloud, noise, reach))
    return out


def _open_ends(curve: SeamCurve, others: list[SeamCurve], ends: FloatArray, cloud: FloatArray, noise: NoiseModel,
               reach: float) -> FloatArray:  # fmt: skip
    """How far segment ``ends`` (a wide fold's) lengthens ``curve`` (a refined seam along it): towards each of
    its ends, up to the wide fold's, unless another refined seam lies along the fold that way (the refinement
    parted the fold there: a gusset stands in it), and only over the stretch next to ``curve`` where the (N, 3)
    points ``cloud`` show both its faces beside it and nothing standing in it (:func:`_clear_run`). The wide
    planes, fitted over 30 mm and more, run across what stands in a fold and round a face's corner."""
    p0, v = curve.points[0], curve.points[-1] - curve.points[0]
    lv = float(np.linalg.norm(v))
    u = v / lv
    t = (ends - p0) @ u
    mids = [float((_middle(c.points) - p0) @ u) for c in others]
    lo = min(0.0, float(t.min())) if not any(m < 0.0 for m in mids) else 0.0
    hi = max(lv, float(t.max())) if not any(m > lv for m in mids) else lv
    if lo < 0.0 or hi > lv:  # the points beside the fold, once for both ends
        tol = WideFoldParams().tol_sigma * _sigma_wide(noise, float(median(curve.points[:, 2])))
        beside = _beside_fold(cloud, curve, (lo - reach, hi + reach), tol, reach)
        lo = _clear_run(beside, 0.0, lo, reach)
        hi = _clear_run(beside, lv, hi, reach)
    return np.array([p0 + lo * u, p0 + hi * u])


_Beside = tuple[FloatArray, NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]


def _beside_fold(cloud: FloatArray, curve: SeamCurve, span: tuple[float, float], tol: float, reach: float) -> _Beside:
    """The points of ``cloud`` along ``curve``'s line over ``span`` (positions along it) and beside it within
    twice the corner's rounding ``reach``: their positions along the line, and whether each lies on face A, on
    face B (on its plane within ``tol``, on its side of the line) and stands in the fold (in front of both
    faces by more than 0.3 of the rounding: a rounded corner's points lie within 0.29 of its radius, what
    stands there well beyond)."""
    p0, u = curve.points[0], curve.points[-1] - curve.points[0]
    u = u / float(np.linalg.norm(u))
    na, nb = curve.normals_a[0], curve.normals_b[0]
    va, vb = np.cross(u, na), np.cross(u, nb)  # across the line, in each face's plane, into the face
    va, vb = (va if float(va @ nb) > 0 else -va), (vb if float(vb @ na) > 0 else -vb)
    t, d = line_coords(cloud, p0, u)
    near = (t >= span[0]) & (t <= span[1]) & (d <= 2.0 * reach)
    q, t = cloud[near] - p0, t[near]
    ra, rb = q @ na, q @ nb
    on_a = (np.abs(ra) <= tol) & (q @ va > 0.0)
    on_b = (np.abs(rb) <= tol) & (q @ vb > 0.0)
    return t, on_a, on_b, (ra > 0.3 * reach + tol) & (rb > 0.3 * reach + tol)


def _clear_run(beside: _Beside, start: float, stop: float, reach: float) -> float:
    """How far from ``start`` towards ``stop`` (positions along the seam's line) the fold runs on clear
    (:func:`_beside_fold`'s points): as far as both faces have points beside it (looked for in steps of half
    the corner's rounding ``reach``: sparse scan lines leave gaps) and up to the first point standing in the
    fold. A face that ends (a wall's corner) or a part standing in the fold (a gusset) ends the run."""
    if stop == start:
        return start
    t, on_a, on_b, in_front = beside
    sign = 1.0 if stop > start else -1.0
    s, s_stop = sign * t, sign * stop  # measured outwards from the seam's end
    standing = in_front & (s > sign * start)
    if standing.any():
        s_stop = min(s_stop, float(s[standing].min()))
    at = sign * start
    while at < s_stop:
        nxt = min(at + 0.5 * reach, s_stop)
        inside = (s > at) & (s <= nxt)
        if not (inside & on_a).any() or not (inside & on_b).any():
            break
        at = nxt
    if at == sign * start:
        return start
    run = (s > sign * start) & (s <= at)
    end = min(float(s[run & on_a].max()), float(s[run & on_b].max()), s_stop)  # where the first face ends
    return sign * end


def _majority(labels: NDArray[np.int32]) -> int:
    """The segmented surface most of a wide plane's points belong to (-1: none)."""
    own = labels[labels >= 0]
    return int(np.bincount(own).argmax()) if own.size else -1


__all__ = ["WideFoldParams", "WidePlane", "in_place_of_along", "runs_along", "wide_fold_seams", "wide_planes"]
