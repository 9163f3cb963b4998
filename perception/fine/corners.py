"""Corners: where two straight seams on one face meet at an angle, both end at their lines' intersection.

Round a bar, a pad or a box every fillet ends at a corner, where the next one begins. Each seam's own end
is placed from where its two faces' points stop, which at a corner is blurred over a pixel or two (mixed
pixels on the vertical edge, the noise): the ends overshoot or fall short by a millimetre or more. The two
seams' lines, each fitted along its whole length, cross at the corner itself; when both ends lie near that
crossing, both are moved onto it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from perception.fine.types import FloatArray, NoiseModel, SeamCurve

MIN_TURN_RAD = np.radians(30.0)  # seams meeting at a smaller angle are not a corner (see merge for collinear)
NEAR_SPACINGS = 4.0  # an end within this many sample spacings (and 3 sigma) of the crossing is at the corner


def join_corners(seams: list[SeamCurve], noise: NoiseModel) -> list[SeamCurve]:
    """``seams`` with the ends of every pair of straight seams that share a face and meet at a corner moved
    onto their lines' crossing."""
    out = list(seams)
    moves: list[tuple[int, int, int, int, FloatArray]] = []
    for i in range(len(out)):
        for j in range(i + 1, len(out)):
            a, b = out[i], out[j]
            if a.kind != "linear" or b.kind != "linear" or len(set(a.surfaces) & set(b.surfaces)) != 1:
                continue
            corner = _crossing(a.points, b.points)
            if corner is None:
                continue
            p, ea, eb = corner
            z = float(p[2])
            near = NEAR_SPACINGS * float(noise.spacing_m(z)) + 3.0 * float(noise.sigma_m(z))
            if np.linalg.norm(a.points[ea] - p) <= near and np.linalg.norm(b.points[eb] - p) <= near:
                moves.append((i, ea, j, eb, p))
    # an end that meets more than one other seam (three faces meeting at a box's inside corner) is left as
    # it is: two seams' crossing is not the three planes' corner
    ends = [(i, ei) for i, ei, _, _, _ in moves] + [(j, ej) for _, _, j, ej, _ in moves]
    for i, ei, j, ej, p in moves:
        if ends.count((i, ei)) == 1 and ends.count((j, ej)) == 1:
            out[i] = _with_end(out[i], ei, p)
            out[j] = _with_end(out[j], ej, p)
    return out


def _crossing(pa: FloatArray, pb: FloatArray) -> tuple[FloatArray, int, int] | None:
    """The midpoint of the closest points of two lines (through each seam's ends), and which end (0 or -1)
    of each is nearer it; None when the lines turn by less than MIN_TURN_RAD."""
    a0, b0 = pa[0], pb[0]
    ua, ub = pa[-1] - pa[0], pb[-1] - pb[0]
    la, lb = float(np.linalg.norm(ua)), float(np.linalg.norm(ub))
    if la < 1e-6 or lb < 1e-6:
        return None
    ua, ub = ua / la, ub / lb
    c = float(ua @ ub)
    if abs(c) > np.cos(MIN_TURN_RAD):
        return None
    w = a0 - b0
    denom = 1.0 - c * c
    s = (c * float(ub @ w) - float(ua @ w)) / denom
    t = (float(ub @ w) - c * float(ua @ w)) / denom
    p = 0.5 * ((a0 + s * ua) + (b0 + t * ub))
    ea = 0 if abs(s) <= abs(s - la) else -1
    eb = 0 if abs(t) <= abs(t - lb) else -1
    return p, ea, eb


def _with_end(s: SeamCurve, end: int, p: FloatArray) -> SeamCurve:
    pts = s.points.copy()
    pts[end] = p
    return replace(s, points=pts)
