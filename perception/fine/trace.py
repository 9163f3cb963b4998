"""A V-groove traced along its cross-sections past where its bevels were segmented.

On a real scan a groove's bevels are rarely planes from end to end: an obtuse groove (110 to 145 degrees) is
shallow, a U-groove is rounded, a plate is bent. The segmentation keeps a bevel as a surface only where it
is flat, so the fold between the bevels covers a stretch of the groove, not all of it. From each end of such
a seam the groove is followed slice by slice: in each slice a few millimetres long, the points across the
groove are fitted with a hinge (two lines meeting at the bottom, their vertex free within a pixel or two of
the prediction). The groove goes on while the slice is a valley whose sides rise like the seam's own bevels
(each at 0.35 to 1 / 0.35 of their half-turn, together at least 15 degrees) and the hinge fits within the
noise, or, where the bottom rounds (a U) and no hinge does, a parabola fits better than the best hinge, its
vertex near the prediction and its sides rising so at the window's edges; it ends at the first two slices in a
row that are neither. The hinge's offset from the root is measured
on the seam's own last slice. A seam that then bends beyond the noise becomes a curved seam through the
slices' vertices.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.evaluate import point_to_polyline_distance, resample_polyline
from perception.fine.folds import SHALLOW_TURN_RAD
from perception.fine.refine import near_points
from perception.fine.types import FloatArray, NoiseModel, SeamCurve
from perception.fits import median

SMOOTH_SLICES = 7  # the traced bottoms are averaged over this many neighbouring slices
MIN_SLICES = 2  # a trace shorter than this many slices is not kept
WIDER_SLICES = (2.0, 3.0)  # a slice that is no valley is looked at again this many times as wide across


@dataclass(frozen=True)
class TraceParams:
    slice_m: float = 0.003  # a cross-section's length along the groove
    half_width_m: float = 0.008  # ... and its reach across, each side of the predicted bottom
    min_turn_rad: float = np.radians(15.0)  # a valley turns by at least this much between its sides
    turn_share: float = 0.35  # each side of a slice rises at this share to its inverse of the seam's bevels
    fit_sigma: float = 3.0  # the hinge's RMS residual is within this many sigma of the noise
    min_side_points: int = 4
    max_misses: int = 2  # the groove ends at this many slices in a row that are not a valley
    max_length_m: float = 0.30  # traced at most this far from each end
    min_length_m: float = 0.010  # what is left of a groove beside a better one is kept from this long
    chunk_m: float = 0.060  # points are read this far ahead at a time


@dataclass(frozen=True)
class _Frame:
    """A cross-section: its centre (the predicted bottom), the direction along the groove, across it, and
    up (out of the groove, towards the camera)."""

    centre: FloatArray
    along: FloatArray
    across: FloatArray
    up: FloatArray


def trace_grooves(seams: list[SeamCurve], full: NDArray[np.float32], intr: CameraIntrinsics, noise_full: NoiseModel,
                  *, params: TraceParams | None = None,
                  read: NDArray[np.bool_] | None = None) -> list[SeamCurve]:  # fmt: skip
    """``seams`` with each straight V-groove traced on past both of its ends (the others unchanged)."""
    tp = params or TraceParams()
    out = [_traced(s, full, intr, noise_full, tp, read) if s.joint == "v_groove" and s.kind == "linear" else s
           for s in seams]  # fmt: skip
    return _join_overlapping(out, noise_full, tp)


def _join_overlapping(seams: list[SeamCurve], noise: NoiseModel, tp: TraceParams) -> list[SeamCurve]:
    """Grooves traced into each other become one. A groove has one bottom across a slice's width: a groove
    lying mostly within that width of a better supported one is the same groove, and is dropped; one that
    meets it within the noise at one of its ends lends it what lies beyond; one whose end runs on beside it
    loses that stretch."""
    # the best supported first: a groove fitted on a few points of a bevel, traced, would displace a better one
    grooves = sorted((s for s in seams if s.joint == "v_groove"), key=lambda s: (-s.support, -_length(s.points)))
    kept: list[SeamCurve] = []
    for b in grooves:
        pb = resample_polyline(b.points, 0.001)
        trimmed = False
        for i, a in enumerate(kept):
            z = float(median(a.points[:, 2]))
            d = point_to_polyline_distance(pb, a.points)
            near = d <= 3.0 * float(noise.sigma_m(z)) + 2.0 * float(noise.spacing_m(z))
            beside = d <= tp.half_width_m
            if beside.mean() >= 0.9:
                break
            if near[0] or near[-1]:
                kept[i] = _extended(a, pb[~beside], noise)
                break
            if beside.mean() >= 0.5:
                break
            if beside[0] or beside[-1]:  # an end runs on beside it: that stretch is welded once, by the better
                pb, trimmed = pb[~beside], True
        else:
            if len(pb) >= 2 and _length(pb) >= tp.min_length_m:
                kept.append(_curved(b, pb) if trimmed else b)
    return [s for s in seams if s.joint != "v_groove"] + kept


def shallow_as_grooves(curves: list[SeamCurve]) -> list[SeamCurve]:
    """With no support (a cloud of the part alone), each fold whose faces, as refined beside the seam, turn by
    under :data:`perception.fine.folds.SHALLOW_TURN_RAD` named a groove: the joint-type rule on the better
    estimate of the faces (a fold named from two segmented fragments of a groove's sides, one of them tilted,
    turns by more). Not one beside a groove (:func:`beside_groove`): that is the groove's own bevel edge."""
    grooves = [c for c in curves if c.joint == "v_groove"]
    out = []
    for c in curves:
        turn = np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", c.normals_a, c.normals_b)), 0.0, 1.0))
        shallow = c.joint in ("fillet", "inside_corner", "lap") and float(median(turn)) < SHALLOW_TURN_RAD
        out.append(replace(c, joint="v_groove") if shallow and not beside_groove(c, grooves) else c)
    return out


def beside_groove(seam: SeamCurve, grooves: list[SeamCurve], *, share: float = 0.8) -> bool:
    """Whether ``seam`` lies along a longer one of ``grooves``, within a groove slice's reach across
    (:class:`TraceParams`' half width) over ``share`` of its length: a fold or step there is the groove's
    own (a bevel's edge, a ledge beside its bottom), and the groove is welded once, along its bottom."""
    reach = TraceParams().half_width_m
    probe = resample_polyline(seam.points, 0.001)
    length = _length(seam.points)
    for g in grooves:
        if _length(g.points) > length and float(np.mean(point_to_polyline_distance(probe, g.points) <= reach)) >= share:
            return True
    return False


def _curved(s: SeamCurve, pts: FloatArray) -> SeamCurve:
    """Seam ``s`` as a curved seam through ``pts``, its bevel normals carried along."""
    pts = pts[:: max(1, len(pts) // 200)] if len(pts) > 400 else pts
    n = len(pts)
    return replace(s, kind="curved", points=pts, normals_a=np.tile(s.normals_a[0], (n, 1)),
                   normals_b=np.tile(s.normals_b[0], (n, 1)))  # fmt: skip


def _extended(a: SeamCurve, extra: FloatArray, noise: NoiseModel) -> SeamCurve:
    """Seam ``a`` with the points ``extra`` (beyond one of its ends, in order) added at that end."""
    pts = resample_polyline(a.points, 0.001)
    first, last = extra[0], extra[-1]
    if min(np.linalg.norm(first - pts[0]), np.linalg.norm(last - pts[0])) < min(
        np.linalg.norm(first - pts[-1]), np.linalg.norm(last - pts[-1])
    ):  # before the start: ordered towards it
        lead = extra if np.linalg.norm(last - pts[0]) <= np.linalg.norm(first - pts[0]) else extra[::-1]
        joined = np.vstack([lead, pts])
    else:
        tail = extra if np.linalg.norm(first - pts[-1]) <= np.linalg.norm(last - pts[-1]) else extra[::-1]
        joined = np.vstack([pts, tail])
    return _curved(a, joined)


def _smoothed(bottoms: FloatArray) -> tuple[FloatArray, float]:
    """The traced ``bottoms`` (in order) averaged across the groove over :data:`SMOOTH_SLICES` neighbouring
    slices (fewer at the ends), and the RMS distance of the raw bottoms from them."""
    n = len(bottoms)
    if n == 0:
        return bottoms, 0.0
    half = SMOOTH_SLICES // 2
    cum = np.vstack([np.zeros((1, 3)), np.cumsum(bottoms, axis=0)])
    lo = np.maximum(np.arange(n) - half, 0)
    hi = np.minimum(np.arange(n) + half + 1, n)
    out = (cum[hi] - cum[lo]) / (hi - lo)[:, None]
    if n >= 2:  # only across the groove: each bottom keeps its place along it (an average would pull the ends in)
        a = np.gradient(out, axis=0)
        a /= np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)
        out += np.sum((bottoms - out) * a, axis=1, keepdims=True) * a
    return out, float(np.sqrt(np.mean(np.sum((bottoms - out) ** 2, axis=1))))


def _length(p: FloatArray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def _traced(s: SeamCurve, full: NDArray[np.float32], intr: CameraIntrinsics, noise: NoiseModel, tp: TraceParams,
            read: NDArray[np.bool_] | None) -> SeamCurve:  # fmt: skip
    p0, p1 = s.points[0], s.points[-1]
    length = float(np.linalg.norm(p1 - p0))
    if length <= 0.0:
        return s
    u = (p1 - p0) / length
    na, nb = s.normals_a[0], s.normals_b[0]
    up = na + nb
    if float(np.linalg.norm(up)) < 1e-6:
        return s
    up /= np.linalg.norm(up)
    turn = float(np.arccos(np.clip(na @ nb, -1.0, 1.0)))  # the bevels' normals turn as much as their planes
    if turn < tp.min_turn_rad:
        return s
    back = _follow(p0, -u, up, full, intr, noise, turn, tp, read)
    ahead = _follow(p1, u, up, full, intr, noise, turn, tp, read)
    if not back and not ahead:
        return s
    return _as_seam(s, np.array(back[::-1]).reshape(-1, 3), np.array(ahead).reshape(-1, 3), noise)


def _follow(start: FloatArray, u: FloatArray, up: FloatArray, full: NDArray[np.float32], intr: CameraIntrinsics,
            noise: NoiseModel, turn: float, tp: TraceParams,
            read: NDArray[np.bool_] | None) -> list[FloatArray]:  # fmt: skip
    """The bottoms of the slices beyond ``start`` along ``u``, in order, up to where the groove ends (the
    bevels turn by ``turn`` at the seam)."""
    out: list[FloatArray] = []
    last, along = start, u
    misses, travelled = 0, 0.0
    widths: list[tuple[TraceParams, int, tuple[float, float]]] = []  # slice parameters, points, bottom's offset
    q = np.zeros((0, 3))
    read_to = 0.0
    while travelled < tp.max_length_m and misses < tp.max_misses:
        if travelled + tp.slice_m > read_to:  # read the band ahead (from the last bottom)
            ahead = np.array([last, last + along * tp.chunk_m])
            q = near_points(full, intr, ahead, tp.half_width_m + tp.slice_m, read=read)
            read_to = travelled + tp.chunk_m - tp.slice_m
        if travelled == 0.0:
            # the seam's own last slice: how many points a slice of this groove holds, and where the hinge's
            # bottom lies from the seam (fitted on whole bevels: an open root, a root face or a rounded
            # bottom put the hinge's vertex off the root by the same amount all along)
            ref = _frame(start - along * 0.5 * tp.slice_m, along, up)
            found = _reference(q, ref, noise, turn, tp)
            if found is None:
                return out
            ref_bottom, tp = found
            widths = [(tp, _slice_points(q, ref, tp), _bias(ref, ref_bottom))]
            # wider slices where the seam's own last slice is a valley in them too (a wide groove's bevels
            # reach beyond the seam's window): a slice that is no valley at the seam's width may be one at
            # theirs (a ledge beside the bottom over a stretch), its bottom offset as theirs is there
            for wider in WIDER_SLICES:
                tpw = replace(tp, half_width_m=wider * tp.half_width_m)
                wide_bottom = _slice_bottom(q, ref, noise, turn, tpw)
                if wide_bottom is not None:
                    widths.append((tpw, _slice_points(q, ref, tpw), _bias(ref, wide_bottom)))
        frame = _frame(last + along * (misses + 1) * tp.slice_m, along, up)
        bottom = None
        for tpw, own, bias in widths:
            if _slice_points(q, frame, tpw) >= 0.5 * own:
                bottom = _slice_bottom(q, frame, noise, turn, tpw)
            if bottom is not None:
                bottom = bottom + bias[0] * frame.across + bias[1] * frame.up
                break
        travelled += tp.slice_m
        if bottom is None:
            misses += 1
            continue
        misses = 0
        step = bottom - last
        if float(step @ along) <= 0.0:
            break
        # the direction follows the bottoms, smoothed over a few slices (one slice's noise is not a bend)
        along = along + 0.3 * (step / np.linalg.norm(step) - along)
        along -= (along @ up) * up
        along /= np.linalg.norm(along)
        out.append(bottom)
        last = bottom
    return out if len(out) >= MIN_SLICES else []  # a slice or two past an end is as well its blurred edge


def _bias(f: _Frame, bottom: FloatArray) -> tuple[float, float]:
    """Where slice ``f``'s centre lies from the ``bottom`` found in it, across and up."""
    return float((f.centre - bottom) @ f.across), float((f.centre - bottom) @ f.up)


def _reference(q: FloatArray, ref: _Frame, noise: NoiseModel, turn: float,
               tp: TraceParams) -> tuple[FloatArray, TraceParams] | None:  # fmt: skip
    """The hinge's bottom in the seam's own last slice ``ref``, and the parameters with the widest reach
    across (``half_width_m``, down to three sample spacings) at which the hinge fits there: a narrow groove's
    window must not take in the plates' tops beyond its bevels' edges."""
    spacing = float(noise.spacing_m(float(ref.centre[2])))
    for share in (1.0, 0.75, 0.5, 0.375, 0.25):
        width = share * tp.half_width_m
        if width < 3.0 * spacing:
            break
        tpw = replace(tp, half_width_m=width)
        bottom = _slice_bottom(q, ref, noise, turn, tpw)
        if bottom is not None:
            return bottom, tpw
    return None


def _frame(centre: FloatArray, along: FloatArray, up: FloatArray) -> _Frame:
    across = np.cross(up, along)
    across /= np.linalg.norm(across)
    return _Frame(centre, along, across, np.cross(along, across))


def _slice_points(q: FloatArray, f: _Frame, tp: TraceParams) -> int:
    """How many of the points ``q`` lie in the slice ``f``."""
    d = q - f.centre
    return int(((np.abs(d @ f.along) <= 0.5 * tp.slice_m) & (np.abs(d @ f.across) <= tp.half_width_m)).sum())


def _slice_bottom(q: FloatArray, f: _Frame, noise: NoiseModel, turn: float,
                  tp: TraceParams) -> FloatArray | None:  # fmt: skip
    """The bottom of the groove in one slice (a hinge fitted to the points' height against their offset
    across), or None when the slice is not the seam's valley: too few points in a half of it or on a side of
    the bottom, a side not sloping like a bevel of the seam's (each rises at between ``turn_share`` and
    1 / ``turn_share`` times half the seam's ``turn``: a plate's end face beside the table beyond the
    groove's end is a valley too), or a hinge that does not fit within the noise."""
    d = q - f.centre
    t, s, h = d @ f.along, d @ f.across, d @ f.up
    m = (np.abs(t) <= 0.5 * tp.slice_m) & (np.abs(s) <= tp.half_width_m)
    if min(int((m & (t < 0.0)).sum()), int((m & (t >= 0.0)).sum())) < tp.min_side_points:
        return None  # both halves of the slice hold the groove: past its end only the near half would
    s, h = s[m], h[m]
    z = float(median(q[m][:, 2]))
    sig, spacing = float(noise.sigma_m(z)), float(noise.spacing_m(z))
    best = _hinge(s, h, np.arange(-2.0 * spacing, 2.0 * spacing + 1e-12, 0.25 * spacing), tp.min_side_points)
    if best is None:
        return None
    # then finer about the best vertex: a vertex a tenth of a spacing off leaves the residual of a sharp V
    fine = _hinge(s, h, best[1] + np.arange(-0.25, 0.25 + 1e-12, 0.025) * spacing, tp.min_side_points)
    best = fine if fine is not None and fine[0] < best[0] else best
    rms, s0, c, k_left, k_right = best
    half = 0.5 * turn
    lo, hi = tp.turn_share * half, min(half / tp.turn_share, 0.5 * np.pi)

    def valley(rise: tuple[float, float], fit_rms: float) -> bool:
        return all(lo <= r <= hi for r in rise) and sum(rise) >= tp.min_turn_rad and fit_rms <= tp.fit_sigma * sig

    if valley((float(np.arctan(-k_left)), float(np.arctan(k_right))), rms):  # each side rises from the bottom
        return np.asarray(f.centre + s0 * f.across + c * f.up, dtype=np.float64)
    # a rounded or flat-bottomed (U) groove: no hinge fits both its sides, a parabola does, and better than the
    # best hinge (a V whose sides rise too little for this groove's fits the hinge as well: past the groove's
    # end, it is not this groove); its bottom is the parabola's vertex (within the hinge's reach of the
    # prediction), its sides' rise the slopes at the window's edges
    a2, a1, a0 = np.polyfit(s, h, 2)
    if a2 <= 0.0:
        return None
    sv = -a1 / (2.0 * a2)
    if abs(sv) > 2.0 * spacing:
        return None
    w = tp.half_width_m
    rise = (float(np.arctan(2.0 * a2 * w - a1)), float(np.arctan(2.0 * a2 * w + a1)))
    fit = float(np.sqrt(np.mean((np.polyval((a2, a1, a0), s) - h) ** 2)))
    if fit >= rms or not valley(rise, fit):
        return None
    return np.asarray(f.centre + sv * f.across + float(np.polyval((a2, a1, a0), sv)) * f.up, dtype=np.float64)


def _hinge(s: FloatArray, h: FloatArray, vertices: FloatArray,
           min_side: int) -> tuple[float, float, float, float, float] | None:  # fmt: skip
    """The best of the hinges (two lines meeting at ``vertices``) fitted by least squares to heights ``h``
    against offsets ``s``: (RMS residual, vertex, height at the vertex, slope before it, slope after it);
    None when no vertex has ``min_side`` points on each side."""
    best: tuple[float, float, float, float, float] | None = None
    for s0 in vertices:
        left = s < s0
        if left.sum() < min_side or (~left).sum() < min_side:
            continue
        A = np.column_stack([np.ones_like(s), np.where(left, s - s0, 0.0), np.where(left, 0.0, s - s0)])
        coef, *_ = np.linalg.lstsq(A, h, rcond=None)
        rms = float(np.sqrt(np.mean((A @ coef - h) ** 2)))
        if best is None or rms < best[0]:
            best = (rms, float(s0), float(coef[0]), float(coef[1]), float(coef[2]))
    return best


def _as_seam(s: SeamCurve, back: FloatArray, ahead: FloatArray, noise: NoiseModel) -> SeamCurve:
    """Seam ``s`` with the traced bottoms ``back`` (before its start, in order) and ``ahead`` (after its end)
    added; its own stretch, fitted on whole bevels, stays as it is. Straight when every traced bottom lies
    within the noise of its line (the line then runs on to the farthest of them), else curved through them;
    its bevel normals carried along."""
    p0, p1 = s.points[0], s.points[-1]
    (back, r_back), (ahead, r_ahead) = _smoothed(back), _smoothed(ahead)
    pts = np.vstack([back, s.points, ahead])
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    traced = np.vstack([back, ahead])
    t = (traced - p0) @ u
    off = traced - p0 - np.outer(t, u)
    # the smoothed bottoms' own noise: the raw bottoms' scatter about them over the window's count (half the
    # window at the ends); the largest of a hundred such deviates is about three of them
    own = max(r_back, r_ahead) / np.sqrt(0.5 * SMOOTH_SLICES)
    sig = 3.0 * own + float(noise.sigma_m(float(median(pts[:, 2])))) / 3.0
    if float(np.max(np.linalg.norm(off, axis=1))) <= sig:
        t_all = np.concatenate([t, [0.0, float((p1 - p0) @ u)]])
        return replace(s, points=np.array([p0 + t_all.min() * u, p0 + t_all.max() * u]))
    return _curved(s, pts)
