"""A fold seam's ends from its faces' full-resolution points near it.

Along the seam's line, the stretch where both faces have points close to it (and clearly off the other face)
is covered; its outermost points, moved in past the few the noise along the rays carries beyond a sharp end
(:func:`noise_ends`), are the seam's first estimate of its ends. Where a face stops at a straight edge (a bar's
or a rib's end, a plate's cut edge), its boundary over the height of its band beside the seam
(:func:`boundary_end`) places the end better: a single point near the corner (a mixed pixel on the depth edge
at the face's end, a point the noise moved) carries the outermost point out by a millimetre or two, while the
edge fitted on the outermost points of every height stands where the face's samples stop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from perception.fine.runs import covered_runs, trim_stray_tails
from perception.fine.types import FloatArray, NoiseModel, Surface
from perception.fits import median, outer_boundary

if TYPE_CHECKING:
    from perception.fine.refine import RefineParams

END_BIN_POINTS = 4.0  # an end bin is widened until it is expected to hold this many points of a face
BOUNDARY_HEIGHT_M = 0.012  # a face's boundary near an end is read on its points up to this far from the seam
BOUNDARY_WINDOW_M = 0.010  # and within this of the end along it
BOUNDARY_MOVE_M = 0.003  # an end is moved in by a face's boundary by this much at most (see boundary_end)
BOUNDARY_SCATTER = 2.0  # a boundary's outermost points scatter within this many (spacing + half a sigma)


def supported_ends(qa: FloatArray, qb: FloatArray, a: Surface, b: Surface, line0: FloatArray, u: FloatArray,
                   t0: float, t1: float, noise: NoiseModel, rp: RefineParams,
                   standing: FloatArray | None = None, boundary: bool = True) -> list[FloatArray]:  # fmt: skip
    """The seam's ends from full-resolution support: along the line, where both faces have points close to
    it but clearly off the other face (bins of ``end_bin_m``, two points each), the covered stretches, the
    longest first and the others from ``min_piece_m`` long, parted from it by something ``standing``; their
    outermost points. Near the corner each face's points are within the noise of the other face too, and where
    one face ends the other's points there would seem to continue it. ``standing``: positions along the line
    of points in front of both faces; a hole where they stand out from the rest of the fold is not bridged.
    ``boundary``: each end moved in onto the boundary of the face that stops there (:func:`boundary_ends`;
    not for a V-groove, whose extent its trace along the groove places)."""
    (ta, spread_a), (tb, spread_b) = (_close_to_line(q, own, other, line0, u, noise, rp)
                                      for q, own, other in ((qa, a, b), (qb, b, a)))  # fmt: skip
    spread = (spread_a, spread_b)
    if len(ta) < 3 or len(tb) < 3:
        return []
    lo, hi = min(t0, t1) - rp.end_slack_m, max(t0, t1) + rp.end_slack_m
    nb = max(1, int(np.ceil((hi - lo) / rp.end_bin_m)))

    # the coarse stretch's bins: it starts end_slack_m into the window, a whole number of bins, which is counted,
    # not divided out of coordinates (int(6.0 - 1 ulp) is 5 for a quarter of the places a seam may start)
    first = round(rp.end_slack_m / rp.end_bin_m)
    inner = slice(first, first + int((max(t0, t1) - min(t0, t1)) / rp.end_bin_m))

    def cover(t: FloatArray) -> NDArray[np.bool_]:
        k = np.floor((t[(t >= lo) & (t < hi)] - lo) / rp.end_bin_m).astype(int)
        count = np.bincount(np.clip(k, 0, nb - 1), minlength=nb)
        # a face seen obliquely has few points near the line: its bins are widened until each is expected
        # to hold END_BIN_POINTS of them where the face is, so that its random holes are not taken for its end
        seen = count[inner][count[inner] > 0]
        per_bin = float(median(seen)) if seen.size else 0.0
        need = END_BIN_POINTS / max(per_bin, 0.5)
        width = min(2 * int(np.ceil((need - 1.0) / 2.0)) + 1, 7)  # the smallest odd width (centred) holding four
        if width > 1:
            count = np.convolve(count, np.ones(width, dtype=np.int64), mode="same")
        return count >= 2

    both = cover(ta) & cover(tb)
    blocked = None
    if standing is not None and len(standing):
        at = np.floor((standing[(standing >= lo) & (standing < hi)] - lo) / rp.end_bin_m).astype(int)
        count = np.bincount(np.clip(at, 0, nb - 1), minlength=nb)
        # an obstacle stands out from the fold's own rounding (a rounded corner's points stand in front of
        # both planes all along it): four times as many such points as a covered bin holds, two at least
        typical = float(median(count[both])) if both.any() else 0.0
        blocked = count >= max(2.0, 4.0 * typical)
    runs = covered_runs(both, int(rp.end_hole_m / rp.end_bin_m), blocked=blocked)
    runs.sort(key=lambda r: r[0] - r[1])  # the longest first
    # fewer points than a bin is widened to hold, past a hole, do not carry the end out (flying pixels, the
    # other face's noise at its 3 sigma); a bin's worth or more past a hole is the face seen again
    tail = int(END_BIN_POINTS) - 1
    out: list[FloatArray] = []
    for k, (r0, r1) in enumerate(runs):
        # another stretch is a seam of its own only where something stands between it and the longest (past
        # a hole in the data alone, the fold is not known to go on)
        if k > 0 and (blocked is None or not blocked[min(r1, runs[0][1]) : max(r0, runs[0][0])].any()):
            continue
        ta_r = ta[(ta >= lo + r0 * rp.end_bin_m) & (ta < lo + r1 * rp.end_bin_m)]
        tb_r = tb[(tb >= lo + r0 * rp.end_bin_m) & (tb < lo + r1 * rp.end_bin_m)]
        if ta_r.size == 0 or tb_r.size == 0:
            if k == 0:
                return []
            continue
        ta_r, tb_r = trim_stray_tails(np.sort(ta_r), max_tail=tail), trim_stray_tails(np.sort(tb_r), max_tail=tail)
        (a0, a1), (b0, b1) = noise_ends(ta_r, spread[0]), noise_ends(tb_r, spread[1])
        s0 = max(a0, b0)
        s1 = min(a1, b1)
        if k == 0 and s1 - s0 < 0.005:
            return []  # the longest stretch is too short: so is every other
        if k == 0 or s1 - s0 >= rp.min_piece_m:
            if boundary:
                s0, s1 = boundary_ends(qa, qb, a, b, line0, u, (s0, s1), noise)
            out.append(np.array([line0 + s0 * u, line0 + s1 * u]))
    return out


def _close_to_line(q: FloatArray, own: Surface, other: Surface, line0: FloatArray, u: FloatArray, noise: NoiseModel,
                   rp: RefineParams) -> tuple[FloatArray, float]:  # fmt: skip
    """The positions along the line of face ``own``'s points ``q`` close to it (within ``end_near_m``, four
    sigmas and three sample spacings) and clearly off the ``other`` face (three sigmas), and how far the noise
    moves them along it (:func:`_along_spread`)."""
    d = q - line0
    t = d @ u
    dist = np.sqrt(np.maximum((d * d).sum(axis=1) - t * t, 0.0))
    z = float(median(q[:, 2]))
    sig = float(noise.sigma_m(z))
    close = (other.residual(q) > 3.0 * sig) & (dist <= rp.end_near_m + 4.0 * sig + 3.0 * float(noise.spacing_m(z)))
    return t[close], _along_spread(q[close], own, u)


def _along_spread(q: FloatArray, S: Surface, u: FloatArray) -> float:
    """How far the noise moves a point of face ``S`` along ``u`` (one sigma): the face's own residual scale
    taken back along the rays (a depth camera's error lies along them) and onto ``u``."""
    if len(q) < 10:
        return 0.0
    r = q / np.linalg.norm(q, axis=1)[:, None]
    res = S.residual(q)
    along_ray = 1.4826 * float(median(np.abs(res - median(res)))) / max(float(median(np.abs(r @ S.normal))), 0.1)
    return along_ray * float(median(np.abs(r @ u)))


def noise_ends(t: FloatArray, spread: float, *, inside_m: float = 0.005) -> tuple[float, float]:
    """The ends of sorted positions ``t`` along a line, each moved in past the points the noise (``spread``,
    one sigma along the line; a depth camera's error lies along the rays, which run partly along the seam when
    it is seen along its length) carried beyond it. Of a face's density rho per metre inside the end (measured
    from three sigmas in, over ``inside_m``), rho spread / sqrt(2 pi) are expected beyond a sharp end: the end
    is the point that many in from the outermost, short of the true end by about a sample spacing along the
    line on average (a seam welded past its end is worse than one stopped a fraction of a millimetre short)."""
    if spread <= 0.0 or len(t) < 10:
        return float(t[0]), float(t[-1])
    out = []
    for end, sign in ((float(t[0]), 1.0), (float(t[-1]), -1.0)):
        depth = sign * (t - end)  # how far in from this end
        lo = 3.0 * spread
        rho = float(np.count_nonzero((depth >= lo) & (depth < lo + inside_m))) / inside_m
        k = min(round(float(rho * spread / np.sqrt(2.0 * np.pi))), len(t) // 4)
        out.append(float(t[k]) if sign > 0 else float(t[-1 - k]))
    return out[0], out[1]


def boundary_ends(qa: FloatArray, qb: FloatArray, a: Surface, b: Surface, line0: FloatArray, u: FloatArray,
                  ends: tuple[float, float], noise: NoiseModel) -> tuple[float, float]:  # fmt: skip
    """The ends ``(s0, s1)`` (positions along the line ``line0 + t u``) each moved in onto the boundary of the
    face that stops there (:func:`boundary_end` of each face; the one nearer the middle), when that lies less
    than BOUNDARY_MOVE_M inside it. An end is never moved out: where a boundary lies beyond the points'
    end, the points say the face stops sooner. Nor further in than that: a face that ends in a rounded or cut
    corner (a gusset's) has no straight edge to carry down to the seam."""
    out = []
    for end, sign in ((ends[0], -1.0), (ends[1], 1.0)):
        found = [e for e in (boundary_end(qa, b, line0, u, end, sign, noise),
                             boundary_end(qb, a, line0, u, end, sign, noise)) if e is not None]  # fmt: skip
        if found:
            e = min(found) if sign > 0 else max(found)
            if 0.0 < sign * (end - e) <= BOUNDARY_MOVE_M:
                end = e
        out.append(end)
    return out[0], out[1]


def boundary_end(q: FloatArray, other: Surface, line0: FloatArray, u: FloatArray, end: float, sign: float,
                 noise: NoiseModel) -> float | None:  # fmt: skip
    """Where a face's boundary meets the seam at its end near ``end`` (``sign`` +1 for the end at larger
    positions along ``u``, -1 for the other): of the face's points ``q`` clear of the ``other`` face (three
    sigmas) up to BOUNDARY_HEIGHT_M from the seam and within BOUNDARY_WINDOW_M of the end, the outermost at
    each height (bins of three sample spacings, a millimetre at least), fitted as a line of height
    (:func:`perception.fits.outer_boundary`) and taken at the seam, half a sample spacing out. None when the
    boundary is not a straight edge (its outermost points scatter by more than BOUNDARY_SCATTER times the
    spacing and half a sigma, or fewer than four heights hold points)."""
    if len(q) < 8:
        return None
    d = q - line0
    t = d @ u
    h = np.sqrt(np.maximum((d * d).sum(axis=1) - t * t, 0.0))
    z = float(median(q[:, 2]))
    sig, spacing = float(noise.sigma_m(z)), float(noise.spacing_m(z))
    near = (other.residual(q) > 3.0 * sig) & (h <= BOUNDARY_HEIGHT_M) & (np.abs(t - end) <= BOUNDARY_WINDOW_M)
    if near.sum() < 8:
        return None
    line = outer_boundary(h[near], sign * t[near], max(3.0 * spacing, 0.001),
                          BOUNDARY_SCATTER * (spacing + 0.5 * sig), min_bins=4, origin=0.0)  # fmt: skip
    if line is None:
        return None
    return sign * (line[0] + 0.5 * spacing)
